"""The MPC's solve in one compiled call (:mod:`agents.mpc.compiled_solve`): the plans of the
Python solve bit for bit, alone or in batches of any size on one or two threads, and the
Python solve kept where the compiled one does not apply."""

import os

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents import make_agent_spec  # noqa: E402
from agents.mpc import MPCConfig, compiled_solve, stepwise_solves  # noqa: E402
from agents.mpc.solver import MPC  # noqa: E402
from agents.mpc_agent import MPCAgent  # noqa: E402
from agents.threads import limited_threads  # noqa: E402
from experiments.infra.lockstep import LockstepRace, race_setup, run_lockstep  # noqa: E402
from racing_env import make_track  # noqa: E402

# three cars in traffic from the start regions: restarts, separations and the warm start
SPECS = ["mpc:zeta=0.9", "mpc:zeta=1.0,s1=0.1,q=40", "mpc:zeta=0.95,s2=0.5"]
ENV = {"n_cars": 3, "max_cycles": 40}


def races(seeds, orders, batch_decisions=True):
    track, config = race_setup(**ENV)
    out = []
    for seed, order in zip(seeds, orders):
        agents = [make_agent_spec(s) for s in SPECS]
        for k, agent in enumerate(agents):
            agent.reset(track, f"car_{k}", seed + k)
        out.append(LockstepRace(agents, track, config, seed, order))
    results = run_lockstep(out, batch_decisions=batch_decisions)
    stats = [[a.mpc.stats for a in race.agents] for race in out]
    return results, stats


def counters(stats):
    keys = ("solves", "fallbacks", "restarts", "qp_iterations", "rejected_steps")
    return [[[s[k] for k in keys] for s in race] for race in stats]


def test_the_compiled_solve_makes_the_python_solve_s_races_bit_for_bit():
    seeds, orders = [21, 22], [[0, 1, 2], [2, 1, 0]]
    with stepwise_solves():
        reference, ref_stats = races(seeds, orders, batch_decisions=False)
    alone, alone_stats = races(seeds, orders, batch_decisions=False)
    for a, b in zip(reference, alone):
        assert np.array_equal(a.states, b.states) and np.array_equal(a.rewards, b.rewards)
    # the same SQP: the same iterations, QP iterations, restarts and steps rejected
    assert counters(ref_stats) == counters(alone_stats)
    assert sum(s["restarts"] for race in ref_stats for s in race) > 0  # the restart path ran
    assert sum(s["extra_iterations"] for race in ref_stats for s in race) > 0


@pytest.mark.parametrize("threads", [1, 2])
def test_a_batch_on_any_thread_count_is_the_race_alone(threads):
    seeds, orders = [31, 32, 33], [[0, 1, 2], [1, 2, 0], [2, 0, 1]]
    alone, _ = races(seeds, orders, batch_decisions=False)
    with limited_threads(threads):  # the batch's MPC steps split over `threads` threads
        batched, _ = races(seeds, orders)
        single, _ = races(seeds[1:2], orders[1:2])  # a batch of one, and another place
    for a, b in zip(alone, batched):
        assert np.array_equal(a.states, b.states) and np.array_equal(a.rewards, b.rewards)
    assert np.array_equal(single[0].states, alone[1].states)


def test_solve_many_mixes_compiled_and_python_solvers():
    track = make_track("default")
    paper, damped = MPC(track), MPC(track, config=MPCConfig(step_damping=(1.0,)))
    assert paper.compiled and not damped.compiled
    x0 = np.array([2.0, 0.0, 0.0, 1.5, 0.0, 0.0])
    K = paper.cfg.horizon
    s_ref = x0[0] + 1.6 * 0.1 * np.arange(1, K + 1)
    problem = (x0, s_ref, np.zeros(K), 20.0, np.array([[2.6, 0.05, 1.2]]), np.zeros(2))
    twins = [MPC(track), MPC(track, config=MPCConfig(step_damping=(1.0,)))]
    with stepwise_solves():  # the reference: both solved alone, step by step from Python
        alone = [m.solve(*problem) for m in twins]
    many = compiled_solve.solve_many([paper, damped], [problem, problem])
    assert all(np.array_equal(a, b) for a, b in zip(alone, many))
    assert paper.batch_key() == MPC(track).batch_key() != damped.batch_key()


def test_the_full_size_mpc_keeps_the_python_solve():
    mpc = MPC(make_track("tumftm:Monza", vehicle_class="fullsize"))
    assert not mpc.compiled  # exact soft rows and throttle limits: not in the compiled solve
    agent = MPCAgent()
    with pytest.raises(RuntimeError, match=r"MPCAgent.act\(\) before reset"):
        MPCAgent.act_group([agent], np.zeros((1, 10), np.float32))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_a_forked_child_does_not_inherit_the_solve_threads():
    """A pool worker forked after its parent split a batch over threads builds its own thread
    pool (the parent's threads do not exist in the child: using them would wait for ever)."""
    from agents.mpc import compiled_solve

    compiled_solve._pool(2)
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child reports how many pools it inherited
        os.write(write, str(len(compiled_solve._pools)).encode())
        os._exit(0)
    os.waitpid(pid, 0)
    assert os.read(read, 16) == b"0"


def test_the_race_command_solves_step_by_step_and_leaves_the_setting(tmp_path):
    """`alpha-racer race` races with the Python solve (no compile for one race) and leaves the
    process's setting as it was, so a caller of main() races on with the compiled solve."""
    from experiments.cli import main

    seen = []
    solve = MPC.solve

    def spy(self, *args):
        seen.append(self.compiled)
        return solve(self, *args)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(MPC, "solve", spy)
        args = ["race", "--agents", "mpc", "raceline", "--steps", "3", "--no-animation"]
        assert main(args + ["--out", str(tmp_path)]) == 0
    assert seen and not any(seen)
    assert MPC.compiled_solves and MPC(make_track("default")).compiled
