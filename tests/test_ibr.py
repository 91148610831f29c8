"""The iterated-best-response agent: overtaking, no contact, track edges, N cars, bad input."""

import warnings

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents import agent_names, make_agent_spec  # noqa: E402
from agents.ibr import IBR, IBRAgent, IBRConfig, _separation_pairs  # noqa: E402
from agents.mpc_agent import MPCAgent  # noqa: E402
from racing_env import RacingParallelEnv, StartConfig, make_track  # noqa: E402


@pytest.fixture(autouse=True)
def quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def place(env, states):
    """Put the cars at ``states`` (N, 6) and return the observations."""
    env.core.state[0] = np.asarray(states, dtype=float)
    obs = env.core.observe()[0]
    return {a: obs[i] for i, a in enumerate(env.possible_agents)}


def drive(env, agents, obs, steps):
    """Step ``steps`` times (or to the end); returns (states (T, N, 6), last infos)."""
    for a, agent_id in zip(agents, env.possible_agents):
        a.reset(env.track, agent_id, 0)
    states, info = [], {}
    for _ in range(steps):
        obs, _, _, _, info = env.step(
            {i: a.act(obs[i]) for a, i in zip(agents, env.possible_agents)}
        )
        states.append(env.core.state[0].copy())
        if not env.agents:
            break
    return np.array(states), info


def two_car_env(steps):
    env = RacingParallelEnv(n_cars=2, max_cycles=steps, start=StartConfig(mode="grid"))
    env.reset(seed=0)
    return env


# --------------------------------------------------------------------------- the scenarios
def test_overtakes_a_slower_car_on_the_straight_without_contact():
    # the default track's main straight runs from about s = 0.7 m to 12.4 m
    env = two_car_env(30)
    obs = place(
        env,
        [
            [1.0, 0.0, 0.0, 2.5, 0.0, 0.0],  # IBR car
            [2.5, 0.0, 0.0, 1.4, 0.0, 0.0],
        ],
    )  # slow car ahead on the same line
    ibr = IBRAgent()
    states, info = drive(env, [ibr, make_agent_spec("constant:throttle=0.25")], obs, 30)
    assert states[-1, 0, 0] > states[-1, 1, 0] + 1.0  # got past
    assert env.core.contacts[0].sum() == 0
    assert info["car_0"]["off_tracks"] == 0
    assert ibr.stats["fallbacks"] == 0 and ibr.stats["solves"] == 30


@pytest.mark.parametrize("n_other", [-0.12])
def test_does_not_cause_contact_with_a_faster_car_behind(n_other):
    # an MPC car closes in from behind at 3.5 m/s on a line beside the IBR car's. (From the
    # left, n = 0.1, the MPC car crosses to the right-hand racing line in front of the IBR car,
    # which gives way toward the right edge: whether they touch depends on how hard the MPC
    # dives (2-3 contact steps for four MPC settings), so that case tests the MPC, not IBR;
    # the next test holds IBR's side-keeping against cars that hold their line.)
    env = two_car_env(40)
    obs = place(
        env,
        [
            [3.0, -0.02, 0.0, 1.0, 0.0, 0.0],  # IBR car, slow
            [2.3, n_other, 0.0, 3.5, 0.0, 0.0],
        ],
    )  # faster car behind
    ibr = IBRAgent()
    states, info = drive(env, [ibr, MPCAgent(zeta=1.0, s1=0.2)], obs, 40)
    assert env.core.contacts[0].sum() == 0
    assert info["car_0"]["off_tracks"] == 0
    assert np.isfinite(states).all()


@pytest.mark.parametrize("v_other, throttle", [(3.0, 0.5), (4.0, 1.0)])
@pytest.mark.parametrize("n_other", [-0.2, -0.1, 0.06, 0.1, 0.2])
def test_does_not_move_into_the_line_of_a_faster_car_behind(n_other, v_other, throttle):
    # a faster car closes in from behind holding its line (no steering) at least a car width
    # beside the slow IBR car's: whenever they are level, the IBR car is no nearer that line
    # than it started (or sep_n), so it never touches the car, and stays on the track
    env = two_car_env(20)
    n0 = -0.02
    obs = place(
        env,
        [
            [3.0, n0, 0.0, 1.0, 0.0, 0.0],  # IBR car, slow
            [2.3, n_other, 0.0, v_other, 0.0, 0.0],
        ],
    )
    ibr = IBRAgent()
    states, info = drive(env, [ibr, make_agent_spec(f"constant:throttle={throttle}")], obs, 20)
    np.testing.assert_allclose(states[:, 1, 1], n_other, atol=1e-9)  # the line held
    level = np.abs(states[:, 0, 0] - states[:, 1, 0]) < env.config.rules.contact_ds
    assert level.any()  # they did come level
    gap = np.abs(states[level, 0, 1] - n_other)
    assert gap.min() >= min(abs(n0 - n_other), ibr.config.sep_n) - 0.005
    assert env.core.contacts[0].sum() == 0
    assert info["car_0"]["off_tracks"] == 0


def test_plans_respect_the_track_edges():
    env = RacingParallelEnv(n_cars=1, max_cycles=110, start=StartConfig(mode="grid", speed=2.0))
    obs, _ = env.reset(seed=0)
    ibr = IBRAgent()
    ibr.reset(env.track, "car_0", 0)
    half = 0.5 * env.config.vehicle.width
    worst = -np.inf
    info = {}
    while env.agents:
        action = ibr.act(obs["car_0"])
        plan = ibr.ibr.last["plans"][0]  # the IBR car's final plan (6, K)
        wl, wr = env.track.widths(plan[0])
        worst = max(worst, float(np.max(np.maximum(plan[1] + half - wl, -wr - (plan[1] - half)))))
        obs, _, _, _, info = env.step({"car_0": action})
    assert worst < 0.0  # the whole car inside the edges
    assert info["car_0"]["off_tracks"] == 0
    assert env.core.state[0, 0, 0] - 3.0 > 0.9 * env.track.length  # and it raced


# --------------------------------------------------------------------------- N cars
@pytest.mark.parametrize("n_cars", [2, 4])
def test_races_with_n_cars(n_cars):
    env = RacingParallelEnv(n_cars=n_cars, max_cycles=25)
    obs, _ = env.reset(seed=3)
    ibr = IBRAgent(rounds=3)
    agents = [ibr] + [MPCAgent(zeta=0.85) for _ in range(n_cars - 1)]
    states, _ = drive(env, agents, obs, 25)
    assert np.isfinite(states).all()
    assert ibr.ibr.last["plans"].shape == (n_cars, 6, 20)
    assert ibr.ibr.last["rounds"] <= 3
    st = ibr.stats
    assert st["solves"] == 25 and st["fallbacks"] == 0 and st["br_failures"] == 0
    assert st["decision_ms_median"] > 0 and st["rounds_max"] <= 3


def test_every_car_separates_from_every_other_cars_plan():
    # separation is lateral OR longitudinal per stage and car, never a mix of s and n
    K = 4
    s, n = np.full(K, 5.0), np.zeros(K)
    S = np.array(
        [
            [5.0] * K,  # car 0: the one deciding (skipped)
            [5.05] * K,  # car 1: just ahead, 0.1 m to the left
            [4.0] * K,  # car 2: 1 m behind on the same line
            [9.0] * K,
        ]
    )  # car 3: out of the window
    N = np.array([[0.0] * K, [0.1] * K, [0.0] * K, [0.0] * K])
    cap = np.full_like(S, np.inf)
    ok = np.ones(4, dtype=bool)
    owner = np.arange(4)
    stage, lat, sign, margin = _separation_pairs(
        s, n, S, N, cap, ok, owner, 0, 0.15, 0.08, 2.0, 40.0, np.zeros(4)
    )
    assert len(stage) == 2 * K  # cars 1 and 2, every stage
    np.testing.assert_allclose(margin[:K], 0.1 - 0.08)  # car 1: lateral, 2 cm to spare
    assert lat[:K].all() and (sign[:K] == -1).all()  # ... stay to its right
    np.testing.assert_allclose(margin[K:], 1.0 - 0.15)  # car 2: longitudinal, in front
    assert not lat[K:].any() and (sign[K:] == 1).all()
    # a car a lap behind on unwrapped progress, physically 0.1 m ahead: near, and ahead
    S[2] = 5.1 - 40.0
    stage, lat, sign, margin = _separation_pairs(
        s, n, S, N, cap, ok, owner, 0, 0.15, 0.08, 2.0, 40.0, np.zeros(4)
    )
    np.testing.assert_allclose(margin[K:], 0.1 - 0.15)  # 0.1 m apart, 0.15 m needed
    assert not lat[K:].any() and (sign[K:] == -1).all()  # ... stay behind it


def test_a_kept_side_holds_while_beside_each_other():
    # car 1 passes car 0 (the one deciding) over four stages, 0.05 m to its left; car 0 keeps
    # to the right of it: laterally, on its right, at every stage where they are level, even
    # where its plan has drifted to the left of car 1
    s = np.array([5.0, 5.0, 5.0, 5.0])
    n = np.array([0.0, 0.0, 0.12, 0.0])
    S = np.array([s, [4.7, 4.9, 5.1, 5.3]])
    N = np.array([n, [0.05] * 4])
    cap = np.full_like(S, np.inf)
    args = (s, n, S, N, cap, np.ones(2, dtype=bool), np.arange(2), 0, 0.15, 0.08, 2.0, 40.0)
    free = _separation_pairs(*args, np.zeros(2))
    assert (free[2][free[1]] == 1.0).any()  # free: stage 2 on the left
    stage, lat, sign, margin = _separation_pairs(*args, np.array([0.0, -1.0]))
    np.testing.assert_array_equal(stage, [0, 1, 2, 3])
    np.testing.assert_array_equal(lat, [False, True, True, False])
    np.testing.assert_array_equal(sign[lat], [-1.0, -1.0])  # kept: on its right
    np.testing.assert_allclose(margin[lat], [0.05 - 0.08, -0.07 - 0.08])
    np.testing.assert_allclose(margin[~lat], [0.3 - 0.15, 0.3 - 0.15])


def test_warm_start_is_the_shifted_previous_plan():
    track = make_track("default")
    ibr = IBR(track)
    states = np.array([[2.0, 0.0, 0.0, 2.5, 0.0, 0.0], [3.0, 0.1, 0.0, 2.0, 0.0, 0.0]])
    ibr.solve(states, np.zeros(2))
    plans, inputs = ibr.last["plans"], ibr.last["inputs"]
    nxt = plans[:, :, 0]  # every car where its plan says
    warm = ibr._warm_start(0, nxt[0].copy())  # what the next decision begins with
    np.testing.assert_array_equal(warm.U[:, :-1], inputs[0][:, 1:])
    np.testing.assert_array_equal(warm.U[:, -1], inputs[0][:, -1])
    # the same prediction, up to curvature looked up at the final plan's own stages
    np.testing.assert_allclose(warm.X[:2, :-1], plans[0][:2, 1:], atol=0.01)
    ibr.solve(nxt, inputs[0, :, 0])
    assert ibr.stats["restarts"] == 0


def test_a_failing_solver_falls_back_without_crashing(monkeypatch):
    import daqp

    env = RacingParallelEnv(n_cars=2, max_cycles=5)
    obs, _ = env.reset(seed=0)
    ibr = IBRAgent(rounds=2)
    ibr.reset(env.track, "car_0", 0)
    ibr.act(obs["car_0"])  # one good decision first
    K = ibr.config.horizon

    def infeasible(H, f, *args, **kwargs):
        return np.full(2 * K, np.nan), np.nan, -1, {"iterations": 0}

    monkeypatch.setattr(daqp, "solve", infeasible)
    for _ in range(3):
        a = ibr.act(obs["car_0"])
        assert a.shape == (2,) and np.isfinite(a).all() and np.all(np.abs(a) <= 1)
    assert ibr.stats["fallbacks"] == 3 and ibr.stats["br_failures"] >= 3 * 2

    def raises(*args, **kwargs):
        raise RuntimeError("solver crashed")

    monkeypatch.setattr(daqp, "solve", raises)
    assert np.isfinite(ibr.act(obs["car_0"])).all()
    assert ibr.stats["fallbacks"] == 4

    def singular(*args, **kwargs):
        raise np.linalg.LinAlgError("singular matrix")

    monkeypatch.setattr(daqp, "solve", singular)
    assert np.isfinite(ibr.act(obs["car_0"])).all()
    assert ibr.stats["fallbacks"] == 5


def test_a_bug_in_a_best_response_is_not_counted_as_a_failed_qp(monkeypatch):
    import daqp

    env = RacingParallelEnv(n_cars=2, max_cycles=5)
    obs, _ = env.reset(seed=0)
    ibr = IBRAgent(rounds=2)
    ibr.reset(env.track, "car_0", 0)

    def typo(*args, **kwargs):
        raise NameError("name 'du_vec' is not defined")

    monkeypatch.setattr(daqp, "solve", typo)
    with pytest.raises(NameError, match="du_vec"):
        ibr.act(obs["car_0"])


def test_a_blown_up_linearisation_is_not_handed_to_the_qp(monkeypatch):
    """Sensitivities of the predicted positions beyond ``max_sensitivity`` (a linearisation
    that has blown up: ill-conditioned QPs that took DAQP up to 10,000 iterations, 1 s per
    decision) skip the QP: the best response fails and the decision falls back in bounded
    time. Below the bound the QP gets the iteration limit."""
    import daqp

    env = RacingParallelEnv(n_cars=2, max_cycles=5)
    obs, _ = env.reset(seed=0)
    calls = []
    real = daqp.solve

    def spy(*args, **kwargs):
        calls.append(kwargs)
        return real(*args, **kwargs)

    monkeypatch.setattr(daqp, "solve", spy)
    ibr = IBRAgent(rounds=2, max_sensitivity=1e-6)  # every real linearisation exceeds it
    ibr.reset(env.track, "car_0", 0)
    a = ibr.act(obs["car_0"])
    assert np.isfinite(a).all() and np.all(np.abs(a) <= 1)
    assert calls == [] and ibr.stats["fallbacks"] == 1 and ibr.stats["br_failures"] >= 2
    ibr = IBRAgent(rounds=2, qp_iter_limit=50)
    ibr.reset(env.track, "car_0", 0)
    ibr.act(obs["car_0"])
    assert calls and all(c["iter_limit"] == 50 for c in calls)
    assert ibr.stats["fallbacks"] == 0


# --------------------------------------------------------------------------- interface and input
def test_registered_and_built_by_spec():
    assert "ibr" in agent_names()
    agent = make_agent_spec("ibr:rounds=3,horizon=10")
    assert isinstance(agent, IBRAgent)
    assert agent.config.rounds == 3 and agent.config.horizon == 10


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"rounds": 0}, "rounds must be an integer in 1..100, got 0"),
        ({"rounds": 2.5}, "rounds"),
        ({"horizon": 0}, "horizon must be an integer number of stages in 2..100, got 0"),
        ({"braking_bound": 1}, "braking_bound must be None, True or False"),
        ({"horizon": 1}, "horizon"),
        ({"tol": -1.0}, "tol must be a positive number, got -1.0"),
        ({"dt": 0.0}, "dt"),
        ({"slip_weight": -1.0}, "slip_weight"),
        ({"track_margin": -0.1}, "track_margin"),
        ({"max_sensitivity": 0.0}, "max_sensitivity must be a positive number, got 0.0"),
        ({"qp_iter_limit": 0}, "qp_iter_limit must be a positive integer, got 0"),
    ],
)
def test_invalid_config_is_a_clear_error(kwargs, match):
    with pytest.raises(ValueError, match=match):
        IBRConfig(**kwargs)
    with pytest.raises(ValueError, match=match.split()[0]):
        IBRAgent(**kwargs)


def test_invalid_agent_arguments():
    with pytest.raises(ValueError, match="unknown IBR parameter.*'round'"):
        IBRAgent(round=3)
    with pytest.raises(ValueError, match="either config or IBRConfig fields"):
        IBRAgent(config=IBRConfig(), rounds=3)
    with pytest.raises(ValueError, match="rounds"):
        make_agent_spec("ibr:rounds=0")
    agent = IBRAgent()
    with pytest.raises(RuntimeError, match="before reset"):
        agent.act(np.zeros(28))
    agent.reset("default", "car_0", 0)
    with pytest.raises(ValueError, match="does not fit 6 N \\+ n_preview"):
        agent.act(np.zeros(27))
    with pytest.raises(ValueError, match="shape \\(N, 6\\)"):
        agent.ibr.solve(np.zeros((2, 5)))


# --------------------------------------------------------------------------- the race command
def test_race_command_runs_ibr_against_mpc(tmp_path, capsys):
    import json

    from experiments.cli import main

    out = tmp_path / "race"
    assert (
        main(
            [
                "race",
                "--agents",
                "ibr",
                "mpc",
                "mpc",
                "--steps",
                "20",
                "--no-animation",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert "ibr" in capsys.readouterr().out
    summary = json.loads((out / "result.json").read_text())
    st = summary["agent_stats"][0]
    assert st["solves"] == 20 and st["fallbacks"] == 0 and 1 <= st["rounds_mean"] <= 6


@pytest.mark.slow
def test_full_three_car_race_runs_cleanly(tmp_path):
    """The issue's done-criterion: ``alpha-racer race --agents ibr mpc mpc`` (50 s)."""
    import json

    from experiments.cli import main

    out = tmp_path / "race"
    assert main(["race", "--agents", "ibr", "mpc", "mpc", "--no-animation", "--out", str(out)]) == 0
    summary = json.loads((out / "result.json").read_text())
    st = summary["agent_stats"][0]
    # every decision made, a rare counted fallback at most, no NaN, over two laps in 50 s,
    # brief excursions and contacts only: at most 3% of the IBR car's steps off track or in
    # contact. The race itself differs between CPU types (BLAS rounding; see the README's
    # "Which machine"): seed 0 gave no contact on one machine and 9 contact steps for the IBR
    # car (18 for all three; the MPC cars do not yield) on another, with no fallback, no
    # failed best response and no off-track step on either
    assert st["solves"] == 500 and st["fallbacks"] <= 2 and st["br_failures"] <= 20
    assert np.isfinite(summary["progress_m"]).all()
    assert summary["progress_m"][0] > 2 * 38.0
    assert summary["off_tracks"][0] <= 15 and summary["contacts"][0] <= 15


def test_the_full_size_ibr_weighs_lengths_and_speeds_in_its_class():
    """At full size the IBR's weights measure positions in car lengths and widths and speeds
    in shares of the top speed (the ORCA car's config unchanged); in a start from the grid
    on Monza its best responses no longer fail (before: 611 failed QPs and 49 fallbacks in
    150 decisions, seed 0)."""
    from agents.ibr_data import ibr_class_weights
    from agents.ibr_solver import IBR as Solver
    from agents.mpc.config import class_scale
    from racing_env.vehicles import FullSizeParams

    base = IBRConfig()
    orca = Solver(make_track("default"))
    assert orca.cfg == base
    monza = make_track("tumftm:Monza", vehicle_class="fullsize")
    full = Solver(monza)
    k_len, k_wid = class_scale(FullSizeParams())
    assert full.cfg.progress_weight == pytest.approx(base.progress_weight / k_len)
    assert full.cfg.trust_weight * k_wid**2 == pytest.approx(base.trust_weight)
    assert full.cfg.soft_rho == pytest.approx(base.soft_rho * k_wid**2)
    assert full.cfg.tol == pytest.approx(base.tol * k_len)
    assert set(ibr_class_weights(base, FullSizeParams())) < set(vars(base))
    env = RacingParallelEnv(
        track=monza, n_cars=1, max_cycles=60, start="grid", vehicle_class="fullsize"
    )
    agent = IBRAgent()
    obs, _ = env.reset(seed=0)
    agent.reset(env.track, "car_0", 0)
    for _ in range(60):  # 6 s of the launch down the main straight
        obs, *_ = env.step({"car_0": agent.act(obs["car_0"])})
    st = agent.stats
    assert st["fallbacks"] == 0 and st["br_failures"] <= 2
    assert env.state()[3] > 20.0  # vx [m/s] after 6 s: launched, not stuck in fallbacks


def test_the_full_size_ibr_plans_under_the_race_lines_braking_limit():
    """At full size a 2 s horizon is shorter than a braking zone from top speed: the IBR's
    braking bound keeps its plan's speed within the race line's braking limit where,
    without it, the plan runs 5 m/s over it (80 m/s, 300 m before Monza's first chicane,
    where the limit is 79.7 m/s); the ORCA car's IBR has no such rows."""
    from agents.ibr_data import _Plan
    from agents.ibr_solver import IBR as Solver

    assert Solver(make_track("default"))._vmax is None
    monza = make_track("tumftm:Monza", vehicle_class="fullsize")
    excess = {}
    for bound in (True, False):
        solver = Solver(monza, config=IBRConfig(braking_bound=bound))
        solver.solve(np.array([[600.0, 2.6, 0.0, 80.0, 0.0, 0.0]]))
        assert not solver.last["fallback"]
        plan = _Plan()
        plan.X = solver.last["plans"][0]
        excess[bound] = Solver(monza)._speed_excess(plan).max()
    assert excess[True] < 0.5 and excess[False] > 3.0
