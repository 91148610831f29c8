"""The MPC's building blocks: prediction, condensing, the QP."""

import warnings

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents.mpc import MPC, MPCConfig, condense, kappa_at_substeps, stage_nodes  # noqa: E402
from racing_env import make_track  # noqa: E402


@pytest.fixture(scope="module")
def mpc():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MPC(make_track("default"))


def test_condensed_sensitivities_match_finite_differences(mpc):
    K = mpc.cfg.horizon
    x0 = np.array([3.0, 0.05, 0.02, 2.0, 0.0, 0.3])
    U = np.tile([[0.5], [0.1]], (1, K))
    kap = kappa_at_substeps(mpc.track, stage_nodes(None, x0, K, mpc.cfg.dt), mpc.cfg.substeps)
    X, A, B = (np.asarray(o) for o in mpc._traj(x0, U, kap))
    G = condense(np.ascontiguousarray(A), np.ascontiguousarray(B), K)
    u = U.T.reshape(-1)
    eps = 1e-6
    for i in range(2 * K):
        up = u.copy()
        up[i] += eps
        Xp = np.asarray(mpc._traj(x0, up.reshape(K, 2).T, kap)[0])
        fd = (Xp[:2].T.reshape(-1) - X[:2].T.reshape(-1)) / eps
        np.testing.assert_allclose(G[:, i], fd, atol=1e-4)
    assert np.all(G[: 2 * (K - 1), 2 * K - 2 :] == 0)  # causality: late inputs move nothing early


def test_steady_tracking_on_a_straight_is_one_cheap_qp(mpc):
    mpc.reset()
    K = mpc.cfg.horizon
    x = np.array([3.0, 0.0, 0.0, 2.5, 0.0, 0.0])
    s_ref = 3.0 + 2.5 * 0.1 * np.arange(1, K + 1)
    n_ref = np.zeros(K)
    for _ in range(3):
        u = mpc.solve(x, s_ref, n_ref, 50.0, None, np.zeros(2))
        mpc._U = np.concatenate([u[:, None], mpc._U[:, :-1]], axis=1)  # same problem again
    assert mpc.last_status == "ok"
    pred = mpc.last_prediction
    np.testing.assert_allclose(pred[0], s_ref, atol=1e-2)  # holds the speed (1 cm)
    np.testing.assert_allclose(pred[1], 0.0, atol=1e-3)  # stays on the line
    assert abs(u[1]) < 1e-3 and -1 <= u[0] <= 1


def test_config_validation():
    with pytest.raises(ValueError, match="horizon"):
        MPCConfig(horizon=1)
    with pytest.raises(ValueError, match="sep_s"):
        MPCConfig(sep_s=0.0)


def test_qp_rows_follow_the_separation_rule_and_the_cost():
    """The compiled QP builder imposes, per opponent and nearby stage, the separation that
    :func:`separation_choice` picks (sign, side and need), and its cost is q||G du + e||^2 +
    ||D(u + du)||^2 up to a constant."""
    from agents.mpc import ProblemConstants, opponent_paths, qp_arrays, separation_choice

    rng = np.random.default_rng(3)
    cfg = MPCConfig()
    K = cfg.horizon
    G = np.tril(rng.normal(size=(2 * K, 2 * K)))
    s_pred = 5.0 + 0.2 * np.arange(1, K + 1)
    n_pred = 0.05 * np.sin(np.arange(K))
    s_ref, n_ref = s_pred + 0.1, n_pred - 0.02
    u = rng.uniform(-1, 1, 2 * K)
    D = np.diff(np.eye(2 * K).reshape(K, 2, 2 * K), axis=0).reshape(-1, 2 * K)
    opps = np.array([[5.9, 0.02, 1.5], [4.8, -0.1, 2.5], [40.0, 0.0, 1.0]])  # last: far away
    paths = opponent_paths(opps, K, cfg.dt)
    paths[0, :, 1] += 0.01 * np.arange(K)  # the first car drifts sideways: a path, not a row
    p = ProblemConstants(
        s_ref=s_ref,
        n_ref=n_ref,
        q=7.0,
        DtD=D.T @ D,
        delta_applied=0.1,
        rate=0.2,
        lo_tab=np.empty(0),  # the edge tables, the weight of the soft rows: not the QP's
        hi_tab=np.empty(0),
        ds=1.0,
        length=1.0,
        opponents=paths,
        dt=cfg.dt,
        sep_s=cfg.sep_s,
        sep_n=cfg.sep_n,
        sep_window=cfg.sep_window,
        w_soft=0.0,
    )
    H, f, A, blo, bhi, sense = qp_arrays(G, s_pred, n_pred, u, np.full(K, -0.2), np.full(K, 0.2), p)
    rows = [A[2 * K :]]
    r = 0
    for path in paths:
        near, lat, sign, s_jk, n_jk = separation_choice(s_pred, n_pred, path, cfg)
        for k in np.flatnonzero(near):
            gap = n_pred[k] - n_jk[k] if lat[k] else s_pred[k] - s_jk[k]
            row = G[2 * k + 1] if lat[k] else G[2 * k]
            np.testing.assert_allclose(rows[0][r], sign[k] * row)
            assert blo[2 * K + 2 * K + r] == pytest.approx(
                (cfg.sep_n if lat[k] else cfg.sep_s) - sign[k] * gap
            )
            r += 1
    assert (
        r == len(rows[0]) > 0 and np.all(sense[4 * K :] == 8) and np.all(sense[2 * K : 3 * K] == 0)
    )
    du = rng.normal(size=2 * K)
    e = np.column_stack([s_pred - s_ref, n_pred - n_ref]).reshape(-1)
    cost = lambda d: 7.0 * np.sum((G @ d + e) ** 2) + np.sum((D @ (u + d)) ** 2)
    quad = lambda d: 0.5 * d @ H @ d + f @ d
    assert quad(du) - quad(0 * du) == pytest.approx(cost(du) - cost(0 * du), rel=1e-6)


def test_config_names_bad_sqp_settings():
    for kw, name in (
        ({"curvature_passes": -1}, "curvature_passes"),
        ({"merit_rtol": -0.1}, "merit_rtol"),
        ({"step_sizes": (1.0, 0.0)}, "step_sizes"),
        ({"step_sizes": ()}, "step_sizes"),
        ({"step_damping": (1.0, -10.0)}, "step_damping"),
        ({"step_damping": (float("nan"),)}, "step_damping"),
        ({"step_damping": 10.0}, "step_damping"),
        ({"step_damping": (True,)}, "step_damping"),
    ):
        with pytest.raises(ValueError, match=name):
            MPCConfig(**kw)


def test_a_plan_is_rolled_out_along_its_own_progress(mpc):
    """The curvature is a parameter of the compiled rollout, looked up at guessed stage
    progress. From a guess on another stretch of track, each pass looks the curvature up
    along the previous pass's progress, and the progress it was looked up at converges to
    the rollout's own: a plan is costed on the corners it drives through."""
    K = mpc.cfg.horizon
    for s0 in (0.0, 9.0):  # a straight into a corner, a corner
        x0 = np.array([s0, 0.0, 0.0, 3.0, 0.0, 0.0])
        U = mpc._follower_warm_start(x0)
        wrong = x0[0] + 0.5 + 0.1 * np.arange(K + 1)  # 0.5 m ahead, at 1 m/s

        def nodes(X):
            return np.concatenate([[x0[0]], X[0]])  # noqa: B023

        rollouts = [mpc._plan(x0, U, s_prev=wrong, jacobians=False, passes=p)[0] for p in range(4)]
        used = [wrong] + [nodes(X) for X in rollouts[:-1]]  # pass p looks up along pass p - 1
        mismatch = [float(np.abs(u - nodes(X)).max()) for u, X in zip(used, rollouts)]
        assert mismatch[0] > 1.0  # [m]: the guess is far off
        for before, after in zip(mismatch[1:], mismatch[2:]):
            assert after < before / 4  # every pass contracts it
        assert mismatch[-1] < 1e-3


def test_predicted_decrease_of_a_hand_made_qp():
    """The QP model's decrease from du = 0 to du: 0.5 du'H du + f'du, plus the soft rows'
    penalty w v^2 before minus after; hard rows (sense 0) cost nothing."""
    from agents.mpc import predicted_decrease

    H = np.diag([2.0, 4.0])
    f = np.array([-2.0, 0.0])
    A = np.array([[1.0, 0.0], [0.0, 1.0]])  # row 0 soft, row 1 hard
    blo = np.array([-1.0, -1.0, 0.5, -1.0])  # 2 simple bounds lead, then the rows
    bhi = np.array([1.0, 1.0, 2.0, 1.0])
    sense = np.array([0, 0, 8, 0], dtype=np.int32)
    du = np.array([1.0, 0.5])
    # model: 0.5 (2 + 4 * 0.25) - 2 = -0.5, so a gain of 0.5; soft row: v = 0.5 before, 0 after
    assert predicted_decrease(H, f, A, blo, bhi, sense, du, 10.0) == pytest.approx(0.5 + 10 * 0.25)
    assert predicted_decrease(H, f, A, blo, bhi, sense, np.zeros(2), 10.0) == 0.0


def test_the_compiled_sqp_step_is_the_python_step_bit_for_bit():
    """The numba kernel that calls the compiled predictions does the Python loop's arithmetic:
    in a 3-car race at the limit every SQP step (trials, the accepted plan, its Jacobians and
    cost) is identical to :meth:`MPC._step_python`'s on the same inputs (the loop that runs
    with an interpreted prediction, here on the same compiled predictions)."""
    from agents.mpc import StepCode, StepResult
    from agents.mpc_agent import MPCAgent
    from racing_env import parallel_env

    env = parallel_env(n_cars=3, max_cycles=40)
    obs, _ = env.reset(seed=3)
    agents = [MPCAgent(zeta=z, q=q) for z, q in ((1.05, 5.0), (1.0, 60.0), (0.9, 20.0))]
    for agent, name in zip(agents, env.possible_agents):
        agent.reset(env.track, name)
    calls = {"steps": 0, "codes": set()}

    def checked(mpc):
        kernel = mpc._step

        def step(*args):
            out = kernel(*args)
            ref = mpc._step_python(*args)
            assert isinstance(out, StepResult) and isinstance(ref, StepResult)
            for a, b in zip(out, ref):
                if b is not None and out.code != StepCode.REJECTED:
                    np.testing.assert_array_equal(a, b)
            assert out.code == ref.code and out.J == ref.J
            calls["steps"] += 1
            calls["codes"].add(StepCode(out.code))
            return out

        return step

    for agent in agents:
        assert agent.mpc._step == agent.mpc._compiled_step  # compiled here (gcc in CI)
        agent.mpc._step = checked(agent.mpc)
    while env.agents:
        obs, *_ = env.step({a: ag.act(obs[a]) for a, ag in zip(env.possible_agents, agents)})
    assert calls["steps"] > 100  # rejected and accepted steps
    assert {StepCode.REJECTED, StepCode.RELINEARISED} <= calls["codes"]


def test_the_public_prediction_is_the_mpcs_own(mpc):
    """``trajectory_function``, the prediction IBR rolls out, gives the MPC's plan, its
    Jacobians and its rollout bit for bit on the same inputs and curvature."""
    from agents.mpc import kappa_at_substeps, trajectory_function

    K, cfg = mpc.cfg.horizon, mpc.cfg
    x0 = np.array([3.0, 0.05, 0.02, 2.5, 0.1, 0.2])
    U = mpc._follower_warm_start(x0)
    nodes = stage_nodes(None, x0, K, cfg.dt)
    kap = kappa_at_substeps(mpc.track, nodes, cfg.substeps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        full = trajectory_function(mpc.vehicle, cfg)(x0, U, kap)
        states = trajectory_function(mpc.vehicle, cfg, jacobians=False)(x0, U, kap)
    plan = mpc._plan(x0, U, s_prev=nodes, passes=0)
    for a, b in zip(full, plan):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(
        states[0], mpc._plan(x0, U, s_prev=nodes, jacobians=False, passes=0)[0]
    )


def _twin_costs(config: MPCConfig, stat: str, n_twins: int, seed: int, **env_kwargs):
    """Race three `mpc` cars at the top of the box; before every solve of the first
    ``n_twins`` cars, a twin :class:`MPC` with ``config`` solves the same problem from the same
    warm start. Returns ``(costs, twins)``: ``costs`` (M, 3) holds, for every solve both ended
    "ok", the car's plan cost, its twin's, and whether the twin's ``stats[stat]`` rose in it."""
    from agents import make_agent_spec
    from racing_env import RacingParallelEnv

    env = RacingParallelEnv(n_cars=3, **env_kwargs)
    obs, _ = env.reset(seed=seed)
    cars = [make_agent_spec("mpc:q=5,zeta=1.05,s1=0.3,s2=0.5,s3=0") for _ in range(3)]
    for car, aid in zip(cars, env.possible_agents):
        car.reset(env.track, aid, 0)
    twins = [MPC(env.track, config=config) for _ in range(n_twins)]
    costs = []

    def twin_solve(mpc, twin):
        plain_solve = mpc.solve

        def solve(*args):
            twin._U = None if mpc._U is None else mpc._U.copy()
            twin._s_nom = None if mpc._s_nom is None else mpc._s_nom.copy()
            before = twin.stats[stat]
            twin.solve(*args)
            u = plain_solve(*args)
            if mpc.last_status == twin.last_status == "ok":
                costs.append((mpc.last_plan[1], twin.last_plan[1], twin.stats[stat] > before))
            return u

        return solve

    for car, twin in zip(cars, twins):
        car.mpc.solve = twin_solve(car.mpc, twin)
    while env.agents:
        obs, *_ = env.step({a: c.act(obs[a]) for a, c in zip(env.possible_agents, cars)})
    return np.array(costs), twins


def test_damped_steps_keep_no_costlier_plan_and_find_cheaper_ones():
    """``MPCConfig(step_damping=...)`` re-solves a QP whose step no step length lets lower the
    cost with a damped Hessian. From the same warm start and problem in a 3-car race at the
    top of the box, its plan is the plain SQP's where no damped step was accepted, never
    costs more (a damped step continues from the plan the plain SQP stops at), and in some
    states costs less."""
    costs, _ = _twin_costs(
        MPCConfig(step_damping=(0.1, 1.0, 10.0, 100.0)),
        "damped_steps",
        n_twins=3,
        seed=0,
        max_cycles=50,
        start="regions",
    )
    plain, damped_cost, damped = costs.T
    damped = damped.astype(bool)
    assert len(costs) >= 100
    # the plain SQP and the damped one differ only after a rejected step
    np.testing.assert_array_equal(plain[~damped], damped_cost[~damped])
    assert np.all(damped_cost <= plain * (1 + 1e-12))
    assert damped.sum() >= 3
    assert np.sum(damped_cost[damped] < 0.99 * plain[damped]) >= 1


@pytest.mark.slow
def test_the_second_start_keeps_no_costlier_plan_and_finds_cheaper_ones():
    """From the same warm start and problem, ``MPCConfig(second_start=True)`` ends with a plan
    that costs at most what the plain SQP's costs, and less in some states of a 3-car race
    at the top of the box (where the plain SQP's plan pays the soft rows' penalty)."""
    costs, (twin,) = _twin_costs(
        MPCConfig(second_start=True), "second_starts", n_twins=1, seed=3, max_cycles=60
    )
    plain, second = costs[:, 0], costs[:, 1]
    assert len(costs) >= 50
    assert np.all(second <= plain * (1 + 1e-12))
    assert np.sum(second < 0.99 * plain) >= 1 and twin.stats["second_starts"] >= 1


def test_opponent_rows_become_constant_velocity_paths_and_paths_pass_through():
    """(M, 3) rows (s, n, s_dot) keep their progress rate and lateral offset over the stages;
    an (M, K, 2) prediction is used as given; any other shape is refused naming it."""
    from agents.mpc import opponent_paths

    K, dt = 4, 0.1
    paths = opponent_paths(np.array([[10.0, 0.05, 2.0]]), K, dt)
    np.testing.assert_allclose(paths[0, :, 0], 10.0 + 2.0 * dt * np.arange(1, K + 1))
    np.testing.assert_array_equal(paths[0, :, 1], 0.05)
    given = np.random.default_rng(0).normal(size=(2, K, 2))
    np.testing.assert_array_equal(opponent_paths(given, K, dt), given)
    assert opponent_paths(None, K, dt).shape == (0, K, 2)
    with pytest.raises(ValueError, match=r"\(2, 5, 2\)"):
        opponent_paths(np.zeros((2, 5, 2)), K, dt)


def test_the_mpc_agent_plans_with_damped_steps_when_asked():
    """``mpc:plan=damped`` (and the alpha agent, which passes it on) solves with
    :data:`agents.mpc.PLANS`' damped settings over the config given; the default keeps the
    config as it is; any other plan is refused naming it and the choices."""
    from agents import make_agent_spec
    from agents.mpc import PLANS
    from agents.mpc_agent import MPCAgent

    assert make_agent_spec("mpc").config == MPCConfig()
    damped = make_agent_spec("mpc:plan=damped").config
    assert damped == MPCConfig(**PLANS["damped"]) and damped.step_damping
    assert make_agent_spec("alpha:plan=damped").config == damped
    assert MPCAgent(config=MPCConfig(sep_s=0.3), plan="damped").config.sep_s == 0.3
    with pytest.raises(ValueError, match=r"plan must be one of \('rti', 'damped'\), got 'ipopt'"):
        make_agent_spec("mpc:plan=ipopt")
