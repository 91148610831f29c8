"""The MPC's compiled SQP step against the same step in Python (the named baseline).

    python benchmarks/sqp_step.py               # 3 races of 3 cars, 300 steps each
    python benchmarks/sqp_step.py --races 1 --steps 50

Races MPC cars with thetas drawn from the box (as ``alpha-racer collect`` does, seeded) twice:
with :func:`agents.mpc.sqp_step`, the numba kernel that calls the compiled predictions itself,
and with :meth:`agents.mpc.MPC._step_python`, the same step in Python (what runs when the
prediction is interpreted). Both use the same fused numba helpers (:func:`trial_step`,
:func:`score_rollout`, :func:`linearised_qp`), so the ratio is what moving the step's loop
and its C calls into one compiled call adds; against the code before those helpers, the
collection A/B in the changelog is the figure. Prints the time per race and per decision of
both, their ratio, and whether the two races' states are identical (they must be: the two do
the same arithmetic). One process, native threads pinned to one.
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np


def race(seed: int, steps: int, python_step: bool) -> tuple[np.ndarray, float, int]:
    """(states (steps + 1, 3, 6), seconds, decisions) of one 3-car race of MPC cars."""
    from agents.mpc_agent import MPCAgent
    from agents.reference import Theta
    from racing_env import RacingParallelEnv, StartConfig

    rng = np.random.default_rng(seed)
    env = RacingParallelEnv(n_cars=3, max_cycles=steps, start=StartConfig(mode="regions"))
    obs, _ = env.reset(seed=seed)
    agents = []
    for name in env.possible_agents:
        agent = MPCAgent()
        agent.theta = Theta.sample(rng)
        agent.reset(env.track, name)
        if python_step:
            agent.mpc._step = agent.mpc._step_python
            agent.mpc._step_buffers = ()
        agents.append(agent)
    states = [env.core.state[0].copy()]
    t0 = time.perf_counter()
    while env.agents:
        obs, *_ = env.step({a: ag.act(obs[a]) for a, ag in zip(env.possible_agents, agents)})
        states.append(env.core.state[0].copy())
    return np.array(states), time.perf_counter() - t0, 3 * steps


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--races", type=int, default=3)
    ap.add_argument("--steps", type=int, default=300)
    args = ap.parse_args(argv)
    from threadpoolctl import threadpool_limits
    threadpool_limits(1)
    warnings.simplefilter("ignore")
    race(0, 5, False)                    # compile / load what the races need, untimed
    race(0, 5, True)
    times = {False: 0.0, True: 0.0}
    same = True
    decisions = 0
    for k in range(args.races):
        runs = {}
        for python_step in (False, True):   # alternate, so that load hits both alike
            states, seconds, n = race(k, args.steps, python_step)
            runs[python_step] = states
            times[python_step] += seconds
        decisions += n
        same &= bool(np.array_equal(runs[False], runs[True]))
    print(f"{args.races} races of 3 MPC cars, {args.steps} steps, thetas from the box (seeded)")
    for python_step, name in ((False, "compiled step (sqp_step)"), (True, "Python step (baseline)")):
        print(f"  {name:26s} {times[python_step] / args.races:7.3f} s per race, "
              f"{1e3 * times[python_step] / decisions:6.3f} ms per decision")
    print(f"  ratio: {times[False] / times[True]:.2f} of the baseline's time "
          f"({times[True] / times[False]:.2f}x faster); races identical: {same}")


if __name__ == "__main__":
    main()
