"""The fixed-parameter MPC agent in closed loop: track edges, separation, a short race."""

import warnings

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents import make_agent_spec  # noqa: E402
from agents.mpc import MPCConfig  # noqa: E402
from agents.mpc_agent import MPCAgent, joint_state_from_observation  # noqa: E402
from racing_env import RacingParallelEnv, RulesConfig, StartConfig  # noqa: E402


def drive(env, agents, steps):
    obs, _ = env.reset(seed=0)
    for a, agent_id in zip(agents, env.possible_agents):
        a.reset(env.track, agent_id, 0)
    states = []
    for _ in range(steps):
        obs, _, _, _, info = env.step(
            {i: a.act(obs[i]) for a, i in zip(agents, env.possible_agents)}
        )
        states.append(env.core.state[0].copy())
        if not env.agents:
            break
    return np.array(states), info


@pytest.fixture(autouse=True)
def quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def test_joint_state_reconstruction_keeps_unwrapped_differences():
    obs = np.zeros(6 * 3 + 10)
    obs[:6] = [1.0, 0.1, 0.0, 2.0, 0.0, 0.0]
    obs[6:12] = [-0.5, 0.1, 0.0, 0.5, 0.0, 0.0]
    obs[12:18] = [40.0, -0.2, 0.0, -1.0, 0.0, 0.0]
    ego, others = joint_state_from_observation(obs, 3)
    np.testing.assert_allclose(others[:, 0], [0.5, 41.0])
    np.testing.assert_allclose(others[:, 1], [0.2, -0.1])
    np.testing.assert_allclose(others[:, 3], [2.5, 1.0])


def test_standing_start_laps_within_the_track():
    env = RacingParallelEnv(n_cars=1, max_cycles=150, start="grid")
    states, info = drive(env, [MPCAgent()], 150)
    assert info["car_0"]["off_tracks"] == 0
    assert states[-1, 0, 0] - states[0, 0, 0] > 35.0  # about a lap in 15 s
    wl, wr = env.track.widths(states[:, 0, 0])
    assert np.all(states[:, 0, 1] <= wl) and np.all(states[:, 0, 1] >= -wr)


def test_soft_rows_weigh_more_for_tight_trackers():
    cfg = MPCConfig()
    assert cfg.soft_rho_at(5.0) == cfg.soft_rho_at(20.0) == pytest.approx(1e-4)
    assert cfg.soft_rho_at(500.0) == pytest.approx(1e-4 * 20.0 / 500.0)  # 25x the weight
    with pytest.raises(ValueError, match="soft_q_ref"):
        MPCConfig(soft_q_ref=0.0)


# Sobol thetas of a 64-theta policy map that left ``default`` on 12, 12, 4 and 14 of 300 steps
# while the soft rows' weight did not grow with q (``MPCConfig(soft_q_ref=1e9)``: 42 steps)
TIGHT_TRACKERS = [
    (455.7109, 0.8333, 0.0237, 5.9953, 2.759),
    (287.8734, 1.0182, 0.2171, 15.484, 4.7131),
    (361.4085, 0.9196, 0.2859, 17.8878, 3.9061),
    (266.4905, 0.8658, 0.1264, 15.1021, 0.5553),
]


def test_tight_trackers_stay_on_the_track():
    off = 0
    for q, zeta, s1, s2, s3 in TIGHT_TRACKERS:
        env = RacingParallelEnv(n_cars=1, max_cycles=300, start="grid")
        _, info = drive(env, [MPCAgent(q=q, zeta=zeta, s1=s1, s2=s2, s3=s3)], 300)
        off += info["car_0"]["off_tracks"]
    assert off <= 4  # at most 1% of 4 x 300 steps


def test_keeps_separation_from_a_parked_car():
    # car_1 parked on the racing line ahead; the MPC car must not run into it
    env = RacingParallelEnv(
        n_cars=2,
        max_cycles=60,
        start=StartConfig(mode="grid", grid_gap=0.3, speed=0.0),
        rules=RulesConfig(),
    )
    parked = make_agent_spec("constant:throttle=-1.0")
    obs, _ = env.reset(seed=0)
    env.core.state[0, 1, :] = [env.core.state[0, 0, 0] + 3.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    mpc = MPCAgent(s1=0.2)
    mpc.reset(env.track, "car_0", 0)
    parked.reset(env.track, "car_1", 0)
    obs = {a: env.core.observe()[0, i] for i, a in enumerate(env.possible_agents)}
    for _ in range(60):
        obs, _, _, _, info = env.step(
            {"car_0": mpc.act(obs["car_0"]), "car_1": parked.act(obs["car_1"])}
        )
    assert info["car_0"]["contacts"] == 0
    assert env.core.state[0, 0, 0] > env.core.state[0, 1, 0] + 1.0  # and got past it


def test_three_mpc_cars_race_from_the_start_regions():
    env = RacingParallelEnv(n_cars=3, max_cycles=150)
    agents = [MPCAgent(), MPCAgent(zeta=0.85), MPCAgent(zeta=0.8)]
    states, info = drive(env, agents, 150)
    assert np.isfinite(states).all()
    for a in agents:
        assert a.stats["fallbacks"] <= 3  # no fallback storms
        assert a.stats["solves"] == 150


@pytest.mark.slow
def test_rti_lap_time_within_two_percent_of_converged_ipopt():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from mpc_speed import closed_loop

    from agents.mpc import MPC
    from agents.mpc_ipopt import IpoptMPC

    track = RacingParallelEnv(n_cars=1).track
    laps = {}
    for name, solver in (("rti", MPC(track)), ("ipopt", IpoptMPC(track))):
        env, _, info = closed_loop([solver], 1, 240, StartConfig(mode="grid", speed=2.0))
        assert info["car_0"]["off_tracks"] == 0 and solver.stats["fallbacks"] == 0
        laps[name] = np.diff([0.0] + env.core.lap_times[0][0])
    assert len(laps["rti"]) >= 2 and len(laps["ipopt"]) >= 2
    assert abs(laps["rti"][1] / laps["ipopt"][1] - 1.0) < 0.02


def test_mpc_speed_config_pairs_set_numeric_fields_and_name_bad_ones():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from mpc_speed import parse_config

    from agents.mpc import MPCConfig

    cfg = parse_config(["sqp_iterations=4", "merit_rtol=0", "restart_offtrack=-1"])
    assert cfg == MPCConfig(sqp_iterations=4, merit_rtol=0.0, restart_offtrack=-1.0)
    assert isinstance(cfg.sqp_iterations, int)
    assert parse_config([]) == MPCConfig()
    # tuple fields: comma-separated numbers
    cfg = parse_config(["step_damping=1,10,100", "step_sizes=1,0.5"])
    assert cfg == MPCConfig(step_damping=(1.0, 10.0, 100.0), step_sizes=(1.0, 0.5))
    for bad in ("foo=1", "sqp_iterations"):
        with pytest.raises(SystemExit, match="KEY=VALUE"):
            parse_config([bad])
    with pytest.raises(SystemExit, match="step_sizes takes comma-separated numbers, got 'a'"):
        parse_config(["step_sizes=a"])
    with pytest.raises(
        SystemExit, match=r"step_damping must be positive finite factors, got \(-1.0,\)"
    ):
        parse_config(["step_damping=-1"])


@pytest.mark.slow
def test_rti_plans_cost_within_five_percent_of_ipopt_at_the_limit():
    """The issue's measure of the RTI's plans: in a solo race at zeta = 1, the cost of the
    RTI's plan against IPOPT's optimum of the same problem, both costed on the same rollout
    (``benchmarks/mpc_speed.py``, its quick run: 29 states). Before plans were rolled out
    along their own progress and the SQP iterated to convergence, 24% of these states were
    within 5%."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from mpc_speed import THETA, plan_quality

    from agents.reference import Theta

    track = RacingParallelEnv(n_cars=1).track
    gaps, _, failed = plan_quality(
        track, 150, 5, [Theta(q=THETA.q, zeta=1.0, s1=THETA.s1, s2=THETA.s2, s3=THETA.s3)]
    )
    assert gaps.size >= 25 and failed == 0
    assert np.mean(gaps <= 0.05) >= 0.8


def test_a_zeta_ceiling_drives_the_capped_theta_and_names_bad_values():
    """``zeta_max`` caps the zeta the MPC drives with: ``zeta=1.02,zeta_max=0.95`` races as
    ``zeta=0.95`` bit for bit; a ceiling above the zeta leaves the agent as it was."""
    from agents import make_agent_spec
    from experiments.evaluation.race import run_race

    a, _ = run_race(
        ["mpc:zeta=1.02,zeta_max=0.95", "raceline"], seed=3, max_cycles=25, progress_bar=False
    )
    b, _ = run_race(["mpc:zeta=0.95", "raceline"], seed=3, max_cycles=25, progress_bar=False)
    assert a.states.tobytes() == b.states.tobytes()
    # the race records the theta each car drove: the capped one; none for the follower
    assert a.thetas[0].shape == (25, 5) and a.thetas[1] is None
    assert a.theta_names[0] == ["q", "zeta", "s1", "s2", "s3"] and a.theta_names[1] is None
    assert np.all(a.thetas[0][:, 1] == 0.95) and np.array_equal(a.thetas[0], b.thetas[0])
    agent = make_agent_spec("mpc:zeta=0.9,zeta_max=1.0")
    assert agent.driven_theta is agent.theta
    for bad, shown in (("0.5", "0.5"), ("1.1", "1.1"), ("true", "True")):
        with pytest.raises(
            ValueError,
            match=rf"zeta_max must be a number in .*\[0.8, 1.05\], "
            rf"got {shown}",
        ):
            make_agent_spec(f"mpc:zeta_max={bad}")


def test_extended_space_agent_checks_and_chooses_the_pass_side_by_room():
    """``space='extended'`` takes ``b``; ``b`` needs that space and the curvature base line;
    with ``b = 0`` and no car near, the extended agent races as the paper's bit for bit; its
    pass side is the room rule's at every step, the paper's agent keeps the paper's rule."""
    from experiments.evaluation.race import run_race

    with pytest.raises(ValueError, match="b = 0.5 is a parameter of the extended policy space"):
        make_agent_spec("mpc:b=0.5")
    with pytest.raises(ValueError, match="it needs line='curvature', got 'lap_time'"):
        make_agent_spec("mpc:space=extended,b=0.5,line=lap_time")
    with pytest.raises(ValueError, match="policy space must be one of"):
        make_agent_spec("mpc:space=huge")
    assert make_agent_spec("alpha:space=extended").space == "extended"  # the shipped model
    a, _ = run_race(["mpc:space=extended,b=0"], seed=3, max_cycles=20, progress_bar=False)
    b, _ = run_race(["mpc"], seed=3, max_cycles=20, progress_bar=False)
    assert a.states.tobytes() == b.states.tobytes()
    agent = make_agent_spec("mpc:space=extended,s1=0.3,s2=1,b=1")
    env = RacingParallelEnv(n_cars=2, max_cycles=5, start=StartConfig(mode="regions"))
    obs, _ = env.reset(seed=1, options={"order": [1, 0]})
    agent.reset(env.track, "car_0", 0)
    assert np.all(np.isfinite(agent.act(obs["car_0"])))
    assert agent._pass_side() == "room"
    assert make_agent_spec("mpc:s1=0.3")._pass_side() is None  # paper: its rule


@pytest.mark.slow
def test_the_extended_space_passes_racing_line_followers_more_often_than_the_paper_s_best():
    """From R2 behind two ``raceline`` followers on ``default`` (8 races of 30 s, seeds
    7000-7007), a fixed theta of the extended space passes in several races, mostly through
    free space, and in more races than the track's best fixed theta of the paper's space
    (which, since the control's compass search moved it to s1 0.3 and s2 0.5, passes in some:
    3 of 8 against 6 of 8 on the AVX-512 machine; before, none; docs: "The extended policy
    space"). Counted over races, not asserted of one: a race at the limit differs from machine
    to machine in its last bits (docs "Which machine")."""
    from experiments.evaluation.metrics import race_metrics
    from experiments.evaluation.race import run_race

    ext = "mpc:space=extended,q=5,zeta=1.05,s1=0.3,s2=0.5,s3=0,b=1"
    counts = {}
    for spec in (ext, "mpc:theta=best"):
        races_with_a_pass = clean = through_contact = 0
        for seed in range(7000, 7008):
            r, _ = run_race(
                [spec, "raceline", "raceline"],
                track="default",
                seed=seed,
                max_cycles=300,
                order=[1, 0, 2],
                progress_bar=False,
            )
            m = race_metrics(r.states)
            races_with_a_pass += m["passes"][0] > 0
            clean += m["passes"][0]
            through_contact += m["passes_contact"][0]
        counts[spec] = (races_with_a_pass, clean, through_contact)
    assert counts[ext][0] >= 3 and counts[ext][1] > counts[ext][2], counts
    assert counts[ext][0] > counts["mpc:theta=best"][0], counts
