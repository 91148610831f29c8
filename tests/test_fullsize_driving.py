"""The full-size class's driving aids and rules: the tyre's peak slip angle, the MPC's soft
rows on the slip angles (their linearisation against finite differences of the rollout) and
the off-track rule's rejoin at the edge (full size) beside the paper's rule (ORCA)."""

from __future__ import annotations

import functools
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.mpc import MPC, MPCConfig
from agents.mpc.prediction import kappa_flat
from agents.mpc.qp import condense_states, slip_angles, slip_penalty, slip_rows
from racing_env import RaceConfig
from racing_env.class_config import race_config_for
from racing_env.parallel_env import RacingParallelEnv
from racing_env.tracks import make_track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles.fullsize import FullSizeParams

P = FullSizeParams()


def test_peak_slip_of_the_magic_formula_by_hand():
    # E = 1: sin(C atan(atan(B a))) peaks where C atan(atan(B a)) = pi / 2
    by_hand = math.tan(math.tan(math.pi / (2 * P.C_r))) / P.B_r
    assert P.peak_slip("rear") == pytest.approx(by_hand, abs=1e-4)
    assert by_hand == pytest.approx(0.0889, abs=1e-4)
    p2 = FullSizeParams(C_f=2.0, B_f=8.0)  # the front peaks at tan(tan(pi / 4)) / 8
    assert p2.peak_slip("front") == pytest.approx(math.tan(1.0) / 8.0, abs=1e-4)
    with pytest.raises(ValueError, match="'middle'"):
        P.peak_slip("middle")


MONZA = make_track("tumftm:Monza", vehicle_class="fullsize")


@functools.cache
def mpc_monza() -> MPC:
    """One full-size MPC on Monza, built when a test first needs it (not at collection)."""
    return MPC(MONZA, P, MPCConfig())


@settings(max_examples=15, deadline=None)
@given(
    st.floats(15.0, 60.0),
    st.floats(-2.0, 2.0),
    st.floats(-0.3, 0.3),
    st.floats(-0.3, 0.3),
    # away from throttle 0, where the throttle map has its kink (drive and brake limits)
    st.one_of(st.floats(-0.8, -0.05), st.floats(0.05, 0.8)),
)
def test_slip_rows_are_the_rollouts_slip_angles_linearised(vx, vy, om, steer, throttle):
    mpc = mpc_monza()
    K, m, t = mpc.cfg.horizon, mpc.cfg.substeps, mpc.track
    x0 = np.array([1500.0, 0.5, 0.02, vx, vy, om])
    u_vec = np.ravel(np.column_stack([np.full(K, throttle), np.full(K, steer)]))
    nodes = x0[0] + vx * mpc.cfg.dt * np.arange(K + 1)
    kap = kappa_flat(t.kappa, nodes, m, t.ds, t.length)
    X, A, B = mpc._traj.full(x0, u_vec, kap, K)
    problem = mpc._problem(X[0], X[1], 5.0, None, np.zeros(2))
    assert problem.slip_max == pytest.approx(P.peak_slip("rear"))
    rows, lo, hi = slip_rows(condense_states(A, B, K), X, u_vec, problem)
    a_r, a_f = slip_angles(X, u_vec, problem)
    c = problem.slip_scale
    # the bounds: the room left to +-bound, in metres
    np.testing.assert_allclose(hi[:K] / c, problem.slip_max - a_r, atol=1e-12)
    np.testing.assert_allclose(lo[K:] / c, -problem.slip_max_f - a_f, atol=1e-12)
    # the rows: central differences of the slip angles through the rollout (curvature fixed)
    du = 1e-6 * np.random.default_rng(0).standard_normal(2 * K)
    ends = [
        slip_angles(mpc._traj.states(x0, u_vec + e, kap, K), u_vec + e, problem) for e in (du, -du)
    ]
    predicted = rows @ du / c
    np.testing.assert_allclose(
        predicted[:K], 0.5 * (ends[0][0] - ends[1][0]), rtol=1e-4, atol=1e-12
    )
    np.testing.assert_allclose(
        predicted[K:], 0.5 * (ends[0][1] - ends[1][1]), rtol=1e-4, atol=1e-12
    )
    # the merit counts what the rows bound: zero inside, the squared excess outside
    inside = max(np.abs(a_r).max() - problem.slip_max, np.abs(a_f).max() - problem.slip_max_f)
    assert (slip_penalty(X, u_vec, problem) == 0.0) == (inside <= 0.0)


def test_the_orca_mpc_has_no_slip_rows():
    track = make_track("default")
    mpc = MPC(track, VehicleParams(), MPCConfig())
    p = mpc._problem(np.zeros(15), np.zeros(15), 5.0, None, np.zeros(2))
    assert p.slip_max == 0.0 and p.slip_max_f == 0.0
    with pytest.raises(ValueError, match="Magic Formula"):
        MPC(track, VehicleParams(), MPCConfig(slip=1.0))
    with pytest.raises(ValueError, match=r"MPCConfig.slip .* got -0.5"):
        MPCConfig(slip=-0.5)
    # slip=0 switches the rows off at full size
    off = MPC(MONZA, P, MPCConfig(slip=0.0))
    assert off._problem(np.zeros(15), np.zeros(15), 5.0, None, np.zeros(2)).slip_max == 0.0


def _run_wide(config: RaceConfig, n_beyond: float, vx: float):
    """One period of a car on Monza's main straight, ``n_beyond`` m past the left edge at
    ``vx`` m/s, heading 0.3 rad to the left; its state after it and its off-track flag."""
    env = RacingParallelEnv(track=MONZA, n_cars=1, config=config, max_cycles=100)
    env.reset(seed=0)
    s0 = 1500.0
    edge = float(MONZA.interp(MONZA.w_left, s0))
    env.core.state[0, 0] = [s0, edge + n_beyond, 0.3, vx, 0.0, 0.0]
    env.step({"car_0": np.array([0.0, 0.0])})
    x = env.core.state[0, 0].copy()
    return x, float(MONZA.interp(MONZA.w_left, x[0])), env.core.offtrack[0, 0]


def test_a_full_size_car_beyond_the_edge_rejoins_it():
    cfg = race_config_for("fullsize")
    assert cfg.rules.offtrack_rejoin
    assert not RaceConfig().rules.offtrack_rejoin  # the paper's rule is unchanged
    x, edge, off = _run_wide(cfg, 0.5, 40.0)
    assert off == 1
    assert x[1] == pytest.approx(edge - 0.5 * P.width)  # back on, its body inside the edge
    assert (x[2], x[4], x[5]) == (0.0, 0.0, 0.0)  # re-aligned
    assert 17.0 < x[3] < 20.5  # and slowed to half of its ~40 m/s
    # the same car under the paper's rule stays beyond the edge, as slow
    stay = cfg.with_(rules=replace(cfg.rules, offtrack_rejoin=False))
    x2, edge2, off2 = _run_wide(stay, 0.5, 40.0)
    assert off2 == 1 and x2[1] > edge2 + 0.5
    assert x2[3] == pytest.approx(x[3], rel=1e-12)


def _squeeze(config: RaceConfig, periods: int) -> np.ndarray:
    """Two cars side by side on Monza's main straight at 30 m/s, the left one (car_0) one
    car width and a bit to the left of car_1, steering right into it at every period; the
    cars' speeds after each period, (periods, 2)."""
    env = RacingParallelEnv(track=MONZA, n_cars=2, config=config, max_cycles=100)
    env.reset(seed=0)
    w = config.rules.contact_dn
    env.core.state[0, 0] = [1500.0, 0.5 * w + 0.05, 0.0, 30.0, 0.0, 0.0]
    env.core.state[0, 1] = [1500.0, -0.5 * w, 0.0, 30.0, 0.0, 0.0]
    speeds = []
    for _ in range(periods):
        env.step({"car_0": np.array([0.3, -0.2]), "car_1": np.array([0.3, 0.0])})
        speeds.append(env.core.state[0, :, 3].copy())
    return np.array(speeds)


def test_cars_in_touch_are_slowed_once_at_full_size():
    cfg = race_config_for("fullsize")
    assert not cfg.rules.contact_repeat
    assert RaceConfig().rules.contact_repeat  # the paper's rule is unchanged
    once = _squeeze(cfg, 10)
    # they touch in the second period: both are slowed (the front to 1/2, the rear to 1/3 of
    # ~30 m/s); then they slide along each other and speed up again
    assert once[0].min() > 29.0
    assert once[1, 0] == pytest.approx(30.2 / 3, rel=0.02) and once[1].max() < 16.0
    assert np.all(np.diff(once[1:], axis=0) > 0.0)
    # the paper's rule slows the pair at every period in touch: they crawl
    every = _squeeze(cfg.with_(rules=replace(cfg.rules, contact_repeat=True)), 10)
    assert np.allclose(every[:2], once[:2])
    assert every[-1].max() < 1.0 and once[-1].min() > 10.0


def test_braking_limit_bounds_the_profile_and_follows_the_corners():
    from racing_env.controllers import raceline_config_for
    from racing_env.raceline import get_raceline
    from racing_env.raceline.speed import braking_limit

    line = get_raceline(MONZA, P, raceline_config_for(P))
    ds = np.diff(np.append(line.s, line.length))
    cap = 1.2 * P.top_speed()
    vb = braking_limit(np.asarray(line.kappa), ds, float(line.mu_nominal), P, cap)
    vx = line.profile()[0]
    assert np.all(vb >= vx * (1 - 1e-9)) and np.all(vb <= cap * (1 + 1e-9))
    assert vb.max() == pytest.approx(cap)  # the straights: the tow's cap, not the top speed
    # never above what a corner can be held at (the cap only on the straights)
    from racing_env.raceline.speed import speed_limit

    corner = speed_limit(np.asarray(line.kappa), float(line.mu_nominal), P)
    bent = corner < P.top_speed() * (1 - 1e-9)
    assert np.all(vb[bent] <= corner[bent] * (1 + 1e-9))
    # where the profile brakes (speed falling into a corner) it is the braking limit itself
    braking = np.flatnonzero((np.roll(vx, -1) < vx - 0.5) & (vx < 0.95 * P.top_speed()))
    np.testing.assert_allclose(vb[braking], vx[braking], rtol=1e-6)


def _ref(vx: float, tow: bool, s0: float = 300.0, ahead: float | None = 30.0):
    from agents.reference import Theta, reference_trajectory
    from racing_env.controllers import raceline_config_for
    from racing_env.raceline import get_raceline

    line = get_raceline(MONZA, P, raceline_config_for(P))
    n0 = float(line.offset_at(s0))
    ego = np.array([s0, n0, 0.0, vx, 0.0, 0.0])
    th = Theta(q=5.0, zeta=1.0, s1=0.3, s2=0.5, s3=0.0)
    # a car ahead in the wake's range (or none), far enough not to shift the reference
    opp = None if ahead is None else np.array([[s0 + ahead, n0, 0.0, vx, 0.0, 0.0]])
    th = th if ahead is None else Theta(q=5.0, zeta=1.0, s1=0.0, s2=0.5, s3=0.0)
    return reference_trajectory(th, ego, opp, line, MONZA, vehicle=P, tow=tow), line


def test_the_reference_follows_a_car_in_a_tow_and_brakes_in_time():
    # Monza's main straight at s = 300 m: the line is at 61 m/s there, a towed car at 75
    slow, line = _ref(20.0, tow=True)
    same, _ = _ref(20.0, tow=False)
    np.testing.assert_array_equal(slow.s_ref, same.s_ref)  # not faster than the line: as before
    fast, _ = _ref(75.0, tow=True)
    held, _ = _ref(75.0, tow=False)
    dt = 0.1
    k = np.arange(1, 16)
    # without the tow rule the reference runs at the line's speed (the car would lift) ...
    assert held.s_ref[-1] - 300.0 < 75.0 * 1.5 - 15.0
    # ... with it, the car's own 75 m/s (above the top speed: held), no braking zone near
    v_s = fast.v_pert[0]  # the car's progress rate: 75 m/s along its heading
    assert v_s == pytest.approx(75.0, rel=1e-3)
    np.testing.assert_allclose(fast.s_ref, 300.0 + v_s * dt * k, rtol=1e-12)
    assert np.all(fast.v_pert == v_s)
    # alone (no car within 15 lengths ahead) it is the line's reference, tow rule or not
    alone, _ = _ref(75.0, tow=True, ahead=None)
    np.testing.assert_array_equal(alone.s_ref, _ref(75.0, tow=False, ahead=None)[0].s_ref)
    # 200 m before the first chicane the braking limit takes over: a towed car slows in time
    brake, _ = _ref(75.0, tow=True, s0=700.0)
    assert np.all(np.diff(brake.v_pert) <= 1e-9) and brake.v_pert[-1] < 70.0


def _brake_test(keep_gap):
    """A raceline follower at 60 m/s 40 m behind a car that brakes as hard as the follower
    can (throttle -0.4, about 0.9 g: harder and its front tyres saturate) on Monza's main
    straight, both on the follower's line: the follower's contact steps and the smallest gap
    [m] (progress difference) over 4 s."""
    from racing_env.controllers import RacelineFollower

    env = RacingParallelEnv(track=MONZA, n_cars=2, vehicle_class="fullsize", max_cycles=100)
    env.reset(seed=0)
    follower = RacelineFollower(keep_gap=keep_gap)
    follower.reset(MONZA, "car_1")
    n_line = follower.tables()[0]  # both cars on the follower's line
    env.core.state[0] = [
        [340.0, MONZA.interp(n_line, 340.0), 0.0, 60.0, 0.0, 0.0],
        [300.0, MONZA.interp(n_line, 300.0), 0.0, 60.0, 0.0, 0.0],
    ]
    obs = env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})[0]
    gaps = []
    for _ in range(40):
        brake = np.array([-0.4, 0.0], dtype=np.float32)
        obs = env.step({"car_0": brake, "car_1": follower.act(obs["car_1"])})[0]
        gaps.append(float(env.core.state[0, 0, 0] - env.core.state[0, 1, 0]))
    return int(env.core.contacts[0, 1]), min(gaps)


def test_the_full_size_follower_does_not_run_into_a_braking_car():
    contacts, gap = _brake_test(None)  # the class's default: keep the gap
    assert contacts == 0 and gap > P.length  # never in the contact box (one length)
    contacts_blind, gap_blind = _brake_test(False)  # the ORCA follower's way: blind
    assert contacts_blind > 0 and gap_blind < gap
    with pytest.raises(ValueError, match="keep_gap"):
        from racing_env.controllers import RacelineFollower

        RacelineFollower(keep_gap=1)


def _two_car_env(gap: float):
    """Monza's main straight at s = 400 m: car_0 at 50 m/s, car_1 ``gap`` m ahead on the same
    offset; the env's observations after one period with both coasting."""
    env = RacingParallelEnv(track=MONZA, n_cars=2, vehicle_class="fullsize", max_cycles=100)
    env.reset(seed=0)
    env.core.state[0] = [[400.0, 1.0, 0.0, 50.0, 0.0, 0.0], [400.0 + gap, 1.0, 0.0, 50.0, 0.0, 0.0]]
    return env, env.step({a: np.zeros(2, dtype=np.float32) for a in env.agents})[0]


def test_the_mpc_brakes_for_dirty_air_behind_a_car(monkeypatch):
    import agents.mpc_agent as mod
    from agents.mpc_agent import DIRTY_AIR, MPCAgent

    seen = []
    original = mod.reference_trajectory

    def spy(*args, **kwargs):
        seen.append(kwargs["friction"])
        return original(*args, **kwargs)

    monkeypatch.setattr(mod, "reference_trajectory", spy)
    agent = MPCAgent(zeta=1.0)
    for gap, friction in ((20.0, DIRTY_AIR[2]), (DIRTY_AIR[0] * P.length + 10.0, None)):
        env, obs = _two_car_env(gap)
        agent.reset(MONZA, "car_0", 0)
        agent.act(obs["car_0"])
        assert seen[-1] == friction  # the grip-scaled profile only within the wake's range
    assert DIRTY_AIR[2] in line_grips()  # a profile of the race line's library, not a blend


def line_grips():
    from racing_env.controllers import raceline_config_for
    from racing_env.raceline import get_raceline

    return list(get_raceline(MONZA, P, raceline_config_for(P)).mus)


def test_a_stopped_full_size_mpc_drives_off_from_a_braking_plan():
    from agents.mpc_agent import MPCAgent

    env = RacingParallelEnv(track=MONZA, n_cars=1, vehicle_class="fullsize", max_cycles=100)
    env.reset(seed=0)
    env.core.state[0, 0] = [484.7, 1.3, 0.026, 0.0, 0.0, 0.0]  # where a car stopped (Monza)
    obs = env.step({"car_0": np.array([-1.0, 0.0], dtype=np.float32)})[0]
    agent = MPCAgent(zeta=1.0)
    agent.reset(MONZA, "car_0", 0)
    agent.act(obs["car_0"])
    K = agent.mpc.cfg.horizon
    agent.mpc._U = np.vstack([np.full(K, -0.74), np.zeros(K)])  # the plan it stayed on
    a = agent.act(obs["car_0"])
    assert a[0] > 0.0  # it drives
