"""Tests of agents.reference: theta bounds, neighbours, the MPC reference and its wrap-safety."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.reference import (
    THETA_HIGH,
    THETA_LOW,
    THETA_NAMES,
    Theta,
    opponent_neighbours,
    reference_trajectory,
)
from racing_env.raceline import get_raceline
from racing_env.tracks import make_track

HYP = settings(max_examples=40, deadline=None)


TRACK = make_track("default")
RL = get_raceline(TRACK)
L = TRACK.length
DT = 0.1


def th(**kw) -> Theta:
    base = dict(q=50.0, zeta=1.0, s1=0.2, s2=4.0, s3=2.0)
    base.update(kw)
    return Theta(**base)


def car(s, n, v, mu=0.0, vy=0.0):
    return np.array([s, n, mu, v, vy, 0.0])


def ref(theta, ego, opps=None, **kw):
    """The paper's reference, literally (``reachable=False``), unless a test asks for the cap."""
    kw.setdefault("reachable", False)
    return reference_trajectory(theta, ego, opps, RL, TRACK, **kw)


def v_rl(s):
    return float(RL.speed_at(s))


# ====================================================================== theta
def test_theta_roundtrip_and_sample():
    assert THETA_NAMES == ("q", "zeta", "s1", "s2", "s3")
    assert THETA_LOW.shape == THETA_HIGH.shape == (5,)
    assert np.all(THETA_LOW < THETA_HIGH)
    rng = np.random.default_rng(0)
    for _ in range(50):
        t = Theta.sample(rng)
        a = t.as_array()
        assert np.all(a >= THETA_LOW) and np.all(a <= THETA_HIGH)
        assert Theta.from_array(a) == t
    assert Theta.from_array(THETA_LOW).as_array().tolist() == THETA_LOW.tolist()
    assert Theta.from_array(THETA_HIGH).as_array().tolist() == THETA_HIGH.tolist()


@pytest.mark.parametrize("i", range(5))
@pytest.mark.parametrize("side", ["low", "high", "nan"])
def test_theta_out_of_bounds_names_parameter(i, side):
    a = 0.5 * (THETA_LOW + THETA_HIGH)
    a[i] = {"low": THETA_LOW[i] - 1e-3, "high": THETA_HIGH[i] + 1e-3, "nan": np.nan}[side]
    with pytest.raises(ValueError, match=rf"{THETA_NAMES[i]} = .*bounds \[") as ei:
        Theta.from_array(a)
    if side == "nan":
        assert "nan" in str(ei.value)
    else:
        assert repr(float(a[i])) in str(ei.value)
    with pytest.raises(ValueError, match=THETA_NAMES[i]):
        ref(a, car(5.0, 0.0, 3.0))


def test_theta_bad_shape():
    with pytest.raises(ValueError, match="shape"):
        Theta.from_array([1.0, 2.0])


# ====================================================================== neighbours
def test_neighbours_basic():
    assert opponent_neighbours(5.0, np.array([]), L) == (-1, -1)
    assert opponent_neighbours(5.0, [6.0, 4.0, 5.5, 3.0], L) == (2, 1)
    assert opponent_neighbours(5.0, [6.0, 7.0], L) == (0, -1)
    assert opponent_neighbours(5.0, [4.0, 2.0], L) == (-1, 0)
    assert opponent_neighbours(5.0, [5.0], L) == (0, -1)  # level counts as ahead


def test_neighbours_across_line_and_laps():
    # ego just past the line, car 0.2 m behind on the previous lap's end
    assert opponent_neighbours(L + 0.1, [L - 0.1], L) == (-1, 0)
    # ego just before the line, car 0.2 m ahead just past it
    assert opponent_neighbours(L - 0.1, [L + 0.1], L) == (0, -1)
    # a car a lap ahead is not 0.1 m ahead: the nearer car in unwrapped progress wins
    assert opponent_neighbours(5.0, [5.1 + L, 6.0], L) == (1, -1)
    assert opponent_neighbours(5.0, [5.1 + L], L) == (0, -1)
    # a lapped car physically 0.1 m ahead is far behind in race order
    assert opponent_neighbours(5.0 + L, [5.1, 2.0 + L], L) == (-1, 1)


@HYP
@given(
    ego=st.floats(-50, 200),
    d=st.lists(st.floats(-30, 30).filter(lambda x: abs(x) >= 1e-3), min_size=1, max_size=7),
    k=st.integers(-2, 4),
)
def test_neighbours_match_brute_force(ego, d, k):
    opp = [ego + x for x in d]
    a, b = opponent_neighbours(ego, opp, L)
    fwd = [x for x in d if x > 0]
    bwd = [x for x in d if x < 0]
    assert (a == -1) == (not fwd) and (b == -1) == (not bwd)
    if fwd:
        assert d[a] == min(fwd)
    if bwd:
        assert d[b] == max(bwd)
    # shifting everything by whole laps changes nothing
    assert opponent_neighbours(ego + k * L, [o + k * L for o in opp], L) == (a, b)


def test_neighbours_bad_input():
    with pytest.raises(ValueError, match="ego_s"):
        opponent_neighbours(float("nan"), [1.0], L)
    with pytest.raises(ValueError, match=r"opp_s\[1\]"):
        opponent_neighbours(1.0, [1.0, float("inf")], L)
    with pytest.raises(ValueError, match="length"):
        opponent_neighbours(1.0, [1.0], 0.0)


# ====================================================================== perturbed race line
def test_shapes_and_no_opponents():
    r = ref(th(), car(5.0, 0.0, 3.0), None, K=15)
    for f in ("s_ref", "n_ref", "n_pert", "n_ot", "n_bl", "v_pert"):
        assert getattr(r, f).shape == (15,)
    assert r.ahead == r.behind == -1
    assert np.all(r.n_ot == 0) and np.all(r.n_bl == 0)
    assert np.array_equal(r.n_ref, r.n_pert)  # race line is inside the clip bounds
    r0 = ref(th(), car(5.0, 0.0, 3.0), np.zeros((0, 6)))
    assert np.array_equal(r0.n_ref, r.n_ref)
    r7 = ref(
        th(),
        car(5.0, 0.0, 3.0),
        np.array([car(5 + i, 0.0, 3.0) for i in range(-3, 4) if i]).reshape(-1, 6),
    )
    assert r7.n_ref.shape == (15,)


@HYP
@given(s0=st.floats(0, 1).map(lambda u: u * L), lap=st.integers(-1, 5))
def test_zeta_one_follows_raceline(s0, lap):
    s0 += lap * L
    r = ref(th(zeta=1.0), car(s0, 0.05, 3.0))
    # n_pert equals the race-line offset at s_pert
    assert np.allclose(r.n_pert, RL.offset_at(r.s_ref), atol=1e-9)
    # s_pert is the race line sampled in time: a car at the race line's centre-line progress
    # rate s_dot = v cos(mu_rl) / (1 - n_rl kappa) (computed here independently of the module)
    # needs dt for each step, i.e. int ds / s_dot over a step = dt
    pts = np.concatenate([[s0], r.s_ref])
    assert np.all(np.diff(pts) > 0)
    u = np.linspace(0.0, 1.0, 201)
    ss = pts[:-1, None] + np.diff(pts)[:, None] * u[None, :]  # (K, 201)
    mu_rl = np.angle(np.exp(1j * (RL.heading_at(ss) - TRACK.heading(ss))))
    sdot = RL.speed_at(ss) * np.cos(mu_rl) / (1 - RL.offset_at(ss) * TRACK.curvature(ss))
    t_step = np.trapezoid(1.0 / sdot, ss, axis=1)
    assert np.allclose(t_step, DT, rtol=0.02)
    # v_pert is that rate at the sample points
    assert np.allclose(r.v_pert, sdot[:, -1], rtol=0.02)


@HYP
@given(s0=st.floats(1.0, 7.0))
def test_zeta_one_on_the_straight_advances_v_rl_dt(s0):
    r = ref(th(zeta=1.0), car(s0, 0.0, 3.0))
    pts = np.concatenate([[s0], r.s_ref])
    assert np.all(np.abs(TRACK.curvature(pts[pts < 12.0])) < 1e-6)  # main straight
    steps = np.diff(pts)
    # each step is v_rl dt (the speed averaged over the step in time): int ds / v_rl = dt
    u = np.linspace(0.0, 1.0, 101)
    ss = pts[:-1, None] + steps[:, None] * u[None, :]
    on = pts[1:] < 12.0
    assert np.allclose(np.trapezoid(1.0 / RL.speed_at(ss), ss, axis=1)[on], DT, rtol=0.01)
    assert np.allclose(steps[on], RL.speed_at(pts[:-1][on] + 0.5 * steps[on]) * DT, rtol=0.01)


def test_zeta_one_euler_is_the_literal_reading():
    r = ref(th(zeta=1.0), car(5.0, 0.0, 3.0), integration="euler")
    rx = ref(th(zeta=1.0), car(5.0, 0.0, 3.0))
    steps = np.diff(np.concatenate([[5.0], r.s_ref]))
    assert np.allclose(
        steps,
        np.concatenate([[rx.v_pert[0] * 0 + RL.speed_at(5.0)], rx.v_pert[:-1]]) * DT,
        rtol=1e-3,
    )
    assert np.abs(r.n_pert - RL.offset_at(r.s_ref)).max() < 0.25
    with pytest.raises(ValueError, match="integration"):
        ref(th(), car(5.0, 0.0, 3.0), integration="rk4")


@HYP
@given(
    s0=st.floats(0, 1).map(lambda u: u * L),
    z1=st.floats(float(THETA_LOW[1]), float(THETA_HIGH[1])),
    z2=st.floats(float(THETA_LOW[1]), float(THETA_HIGH[1])),
)
def test_higher_zeta_is_further_ahead(s0, z1, z2):
    lo, hi = sorted((z1, z2))
    if hi - lo < 1e-6:
        return
    r_lo = ref(th(zeta=lo), car(s0, 0.0, 3.0))
    r_hi = ref(th(zeta=hi), car(s0, 0.0, 3.0))
    assert r_hi.s_ref[-1] > r_lo.s_ref[-1]
    assert np.all(r_hi.s_ref >= r_lo.s_ref)
    assert np.all(r_hi.v_pert > r_lo.v_pert)
    # displacement scales exactly with zeta
    assert np.allclose((r_hi.s_ref - s0) / hi, (r_lo.s_ref - s0) / lo)


# ====================================================================== overtake
def ot_scene(gap, s0=5.0, dn=0.03, theta=None, v=None):
    """Ego on the race line at s0; one opponent gap ahead, dn to the left of the ego, moving at
    the race-line speed there (so the longitudinal gap stays about constant)."""
    n_e = float(RL.offset_at(s0)) + 0.1
    v = v_rl(s0) if v is None else v
    return ref(theta or th(s3=0.0), car(s0, n_e, v), np.array([car(s0 + gap, n_e + dn, v)]))


def test_overtake_moves_away_from_car_ahead():
    r = ot_scene(0.3)
    assert r.ahead == 0 and r.behind == -1
    assert np.all(r.n_ot < 0)  # opponent slightly left: move right
    assert np.abs(r.n_ot).max() <= 0.2 - 0.03 + 1e-12  # at most s1 - |dn|
    assert np.all(r.n_bl == 0)


def test_overtake_decays_with_distance():
    mags = [np.abs(ot_scene(g).n_ot).max() for g in (0.3, 0.6, 1.0, 2.0, 5.0)]
    assert all(a > b for a, b in zip(mags, mags[1:]))
    assert mags[-1] < 1e-3


def test_overtake_off_when_s1_zero_or_far_apart():
    assert np.all(ot_scene(0.3, theta=th(s1=0.0, s3=0.0)).n_ot == 0)
    assert np.all(ot_scene(0.3, dn=0.25).n_ot == 0)  # already 0.25 m > s1 apart laterally


def test_overtake_sign_zero_takes_roomier_side():
    s0 = 5.0
    # opponent right of centre, ego level with it: more room on the left -> move left
    r = ref(th(s3=0.0), car(s0, -0.1, 4.0), np.array([car(s0 + 0.3, -0.1, 4.0)]))
    assert np.all(r.n_ot > 0)
    r = ref(th(s3=0.0), car(s0, 0.1, 4.0), np.array([car(s0 + 0.3, 0.1, 4.0)]))
    assert np.all(r.n_ot < 0)


def test_overtake_matches_formula():
    s0, n_e, v = 5.0, -0.1, 3.0
    o = np.array([car(s0 + 0.3, -0.05, 2.5), car(s0 - 0.5, -0.2, 4.5)])
    t = th(s1=0.25, s2=3.0)
    r = ref(t, car(s0, n_e, v), o)
    k = np.arange(1, 16)
    expect = np.zeros(15)
    for j in range(2):
        sj_k = o[j, 0] + k * DT * o[j, 3]
        dn = n_e - o[j, 1]
        expect += np.sign(dn) * np.maximum(
            (t.s1 - abs(dn)) * np.exp(-t.s2 * (r.s_ref - sj_k) ** 2), 0
        )
    assert np.allclose(r.n_ot, expect, atol=1e-15)


# ====================================================================== block
def bl_scene(v_opp, theta=None, gap=-0.4, dn=0.15):
    s0 = 5.0
    n_pert0 = float(RL.offset_at(s0))
    ego = car(s0, n_pert0, v_rl(s0))
    return ref(theta or th(s1=0.0), ego, np.array([car(s0 + gap, n_pert0 + dn, v_opp)]))


def test_block_moves_toward_faster_car_behind():
    r = bl_scene(5.5)
    assert r.behind == 0 and r.ahead == -1
    assert np.all(r.n_ot == 0)
    assert np.any(r.n_bl > 0)  # the car behind is to the left
    assert np.all(r.n_bl >= 0)
    assert np.all(r.n_bl < 0.15)  # a fraction of the lateral gap
    # it stops once the faster car's prediction is past the reference
    k = np.arange(1, 16)
    past = (5.0 - 0.4 + k * DT * 5.5) > r.s_ref
    assert np.all(r.n_bl[past] == 0)
    # mirrored: car behind to the right -> shift right
    assert np.any(bl_scene(5.5, dn=-0.15).n_bl < 0)


def test_block_off_for_slower_car_or_s3_zero():
    assert np.all(bl_scene(3.0).n_bl == 0)  # slower than the ego reference
    assert np.all(bl_scene(5.5, theta=th(s1=0.0, s3=0.0)).n_bl == 0)


def test_block_grows_with_s3_and_speed_difference():
    m = [bl_scene(5.5, theta=th(s1=0.0, s3=s3)).n_bl.max() for s3 in (0.5, 2.0, 5.0)]
    assert m[0] < m[1] < m[2]
    m = [bl_scene(v).n_bl[0] for v in (4.3, 4.8, 5.5)]
    assert m[0] < m[1] < m[2]


def test_block_matches_formula_with_sign_fix():
    s0 = 5.0
    o = np.array([car(s0 - 0.3, -0.05, 5.0)])
    t = th(s1=0.0, s2=2.0, s3=1.5)
    r = ref(t, car(s0, -0.2, 4.0), o)
    k = np.arange(1, 16)
    sj_k = o[0, 0] + k * DT * o[0, 3]
    ind = (r.v_pert <= o[0, 3]) & (r.s_ref >= sj_k)
    expect = (
        ind
        * (o[0, 1] - r.n_pert)
        * (1 - np.exp(-t.s3 * (o[0, 3] - r.v_pert)))
        * np.exp(-t.s2 * (r.s_ref - sj_k) ** 2)
    )
    assert np.any(ind)
    assert np.allclose(r.n_bl, expect, atol=1e-15)


# ====================================================================== clip
def test_reference_clipped_to_track():
    r = ref(th(s1=0.3, s2=0.5), car(5.0, -0.2, 4.0), np.array([car(5.2, -0.1, 4.0)]))
    w = 0.03
    assert np.all(r.n_ref >= -0.25 + w - 1e-12) and np.all(r.n_ref <= 0.25 - w + 1e-12)
    raw = r.n_pert + r.n_ot + r.n_bl
    assert np.any(raw < -0.25 + w)  # the clip was active
    assert np.allclose(r.n_ref, np.clip(raw, -0.25 + w, 0.25 - w))


# ====================================================================== wrap-safety
SHIFT_FIELDS = ("n_ot", "n_bl", "n_ref", "n_pert", "v_pert")


@HYP
@given(
    u=st.floats(0, 1),
    gap=st.floats(-1.0, 1.0).filter(lambda g: abs(g) >= 1e-3),
    lap=st.integers(-3, 6),
    dn=st.floats(-0.2, 0.2),
    vo=st.floats(2.0, 5.5),
)
def test_shifts_invariant_under_whole_laps(u, gap, lap, dn, vo):
    s0 = u * L  # includes scenes across the line
    n_e = float(RL.offset_at(s0))
    ego, opp = car(s0, n_e, 3.5), np.array([car(s0 + gap, n_e + dn, vo)])
    a = ref(th(), ego, opp)
    b = ref(th(), ego + [lap * L, 0, 0, 0, 0, 0], opp + [lap * L, 0, 0, 0, 0, 0])
    assert (a.ahead, a.behind) == (b.ahead, b.behind)
    assert np.allclose(b.s_ref - a.s_ref, lap * L, atol=1e-9)
    for f in SHIFT_FIELDS:
        assert np.allclose(getattr(a, f), getattr(b, f), atol=1e-9), f


@pytest.mark.parametrize("lap", [0, 1, 3])
def test_overtake_across_start_finish_line(lap):
    """Ego 0.1 m before the line, car 0.3 m ahead just past it (unwrapped): the same overtake
    as the scene at 5.0 / 5.3, not a car L - 0.3 behind."""
    t = th(s3=0.0)

    def scene(s0):
        v = float(ref(t, car(s0, 0.0, 3.0)).v_pert[0])  # opponent keeps the reference's pace
        return ref(t, car(s0, 0.0, v), np.array([car(s0 + 0.3, 0.03, v)]))

    a = scene(lap * L + L - 0.1)
    b = scene(5.0)
    assert a.ahead == 0 and a.behind == -1
    assert np.all(a.n_ot[:3] < -0.1)
    assert np.allclose(a.n_ot[:3], b.n_ot[:3], atol=5e-3)
    # the wrapped (wrong) coordinates would put the car L - 0.3 behind: no shift
    w = ref(t, car(L - 0.1, 0.0, 3.8), np.array([car(0.2, 0.03, 3.8)]))
    assert w.behind == 0 and np.abs(w.n_ot).max() < 1e-12


def test_block_across_start_finish_line():
    t = th(s1=0.0)
    a = ref(t, car(L + 0.1, -0.15, 3.8), np.array([car(L - 0.3, 0.0, 5.5)]))
    b = ref(t, car(0.1, -0.15, 3.8), np.array([car(-0.3, 0.0, 5.5)]))
    assert a.behind == 0 and np.any(a.n_bl > 0)
    assert np.allclose(a.n_bl, b.n_bl, atol=1e-12)


def test_car_a_lap_ahead_is_not_close():
    r = ref(th(), car(5.0, 0.0, 4.0), np.array([car(5.1 + L, 0.01, 4.0)]))
    assert r.ahead == 0  # nearest ahead in race order...
    assert np.abs(r.n_ot).max() < 1e-12  # ...but L + 0.1 m away, not 0.1 m
    assert np.abs(r.n_bl).max() < 1e-12
    r2 = ref(th(), car(5.0, 0.0, 4.0), np.array([car(5.1 + L, 0.01, 4.0), car(7.0, 0.2, 4.0)]))
    assert r2.ahead == 1


# ====================================================================== bad input
def test_nan_state_raises_naming_value():
    with pytest.raises(ValueError, match=r"ego state n is not finite: nan"):
        ref(th(), car(5.0, float("nan"), 3.0))
    bad = np.array([car(6.0, 0.0, 3.0), car(4.0, 0.0, float("inf"))])
    with pytest.raises(ValueError, match=r"opponents\[1\] state vx is not finite: inf"):
        ref(th(), car(5.0, 0.0, 3.0), bad)


def test_bad_shapes_raise():
    with pytest.raises(ValueError, match=r"ego state must have shape \(6,\)"):
        ref(th(), np.zeros(5))
    with pytest.raises(ValueError, match=r"opponents must have shape \(m, 6\)"):
        ref(th(), car(5.0, 0.0, 3.0), np.zeros((2, 5)))
    with pytest.raises(ValueError, match="K must"):
        ref(th(), car(5.0, 0.0, 3.0), K=0)
    with pytest.raises(ValueError, match="dt must"):
        ref(th(), car(5.0, 0.0, 3.0), dt=-0.1)


def test_long_horizon_wraps():
    r = ref(th(), car(L - 1.0, 0.0, 3.0), None, K=300, dt=0.1)  # 30 s: about 3 laps
    assert np.all(np.diff(r.s_ref) > 0)
    assert np.allclose(r.n_pert, RL.offset_at(r.s_ref), atol=1e-9)


def test_oval_track_runs():
    tr = make_track("oval")
    rl = get_raceline(tr)
    r = reference_trajectory(th(), car(3.0, 0.0, 3.0), np.array([car(3.3, 0.02, 3.0)]), rl, tr)
    assert np.all(np.isfinite(r.n_ref)) and math.isfinite(r.s_ref[-1])


# ====================================================================== reachable progress (1b)
def run_distance(v0, t):
    """Distance [m] of a full-throttle run from v0 [m/s] over t [s] on a straight, integrated
    here independently (explicit Euler, 1 ms) from the envelope's drive limit at zero a_y."""
    from racing_env.envelope import ggv

    env, x, v = ggv(), 0.0, v0
    for _ in range(int(round(t / 1e-3))):
        a = max(float(env.longitudinal_limits(v, 0.0)[0]), 0.0)
        x += v * 1e-3 + 0.5 * a * 1e-6
        v += a * 1e-3
    return x


def test_reachable_cap_from_rest_is_the_run_up_on_the_reference_path():
    """From rest the paper's reference starts at racing speed (0.4 m in the first 0.1 s here);
    the capped one asks for REACH_SLACK times what full throttle covers, along the same path."""
    from agents.reference import REACH_SLACK

    ego = car(3.0, 0.0, 0.0)
    paper = ref(th(), ego)
    capped = ref(th(), ego, reachable=True)
    d = capped.s_ref - 3.0
    assert paper.s_ref[0] - 3.0 > 0.3
    for k in (0, 4, 9, 14):
        assert d[k] == pytest.approx(REACH_SLACK * run_distance(0.0, DT * (k + 1)), rel=0.02)
    assert np.all(np.diff(capped.s_ref) > 0)
    # same path: the capped lateral reference is the paper's n at the capped progress
    path_n = np.interp(
        capped.s_ref, np.append(3.0, paper.s_ref), np.append(RL.offset_at(3.0), paper.n_pert)
    )
    np.testing.assert_allclose(capped.n_pert, path_n, atol=1e-9)


@pytest.mark.parametrize("s0", [1.0, 6.0, 12.0, 20.0])
def test_reachable_cap_idle_at_racing_speed(s0):
    """A car on the racing line at the line's speed is never capped: the reference is the
    paper's."""
    s0 = s0 % L
    ego = car(s0, float(RL.offset_at(s0)), v_rl(s0))
    a, b = ref(th(), ego, reachable=True), ref(th(), ego)
    np.testing.assert_array_equal(a.s_ref, b.s_ref)
    np.testing.assert_array_equal(a.n_ref, b.n_ref)


@HYP
@given(s0=st.floats(0.0, 3 * L), v=st.floats(0.0, 6.0), zeta=st.floats(0.8, 1.05))
def test_reachable_reference_advances_and_never_passes_the_paper(s0, v, zeta):
    ego = car(s0, float(RL.offset_at(s0 % L)), v)
    a, b = ref(th(zeta=zeta), ego, reachable=True), ref(th(zeta=zeta), ego)
    assert np.all(np.diff(np.append(s0, a.s_ref)) > 0)
    assert np.all(a.s_ref <= b.s_ref + 1e-12)
    assert np.all(np.isfinite(a.n_ref)) and np.all(a.v_pert <= b.v_pert + 1e-12)


# ====================================================================== extended space


def lap_time_line():
    from racing_env.raceline import RacelineConfig

    return get_raceline(TRACK, config=RacelineConfig(objective="lap_time"))


def test_policy_spaces():
    from agents.reference import SPACES, policy_space

    paper, ext = policy_space("paper"), policy_space("extended")
    assert paper.names == THETA_NAMES and paper.dim == 5
    assert ext.names == THETA_NAMES + ("b",) and ext.dim == 6
    assert ext.low[:5].tolist() == THETA_LOW.tolist() and (ext.low[5], ext.high[5]) == (0, 1)
    assert set(SPACES) == {"paper", "extended", "wake"} and policy_space(ext) is ext
    with pytest.raises(
        ValueError, match=r"policy space must be one of \['extended', 'paper', 'wake'\], got 'x'"
    ):
        policy_space("x")
    a = ext.sample(3)
    assert ext.array(ext.theta(a)).tolist() == a.tolist()
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        ext.theta(a[:5])


def test_theta_b_bounds_and_paper_array():
    t = th(b=0.4)
    assert t.as_array("extended")[-1] == 0.4
    with pytest.raises(ValueError, match="b = 0.4 is outside the paper's space"):
        t.as_array()
    with pytest.raises(ValueError, match=r"b = 1.5 is outside its bounds \[0, 1\]"):
        th(b=1.5)
    assert th().as_array("extended")[-1] == 0.0 and Theta.from_array(t.as_array("extended")) == t


def test_blend_zero_is_the_paper_reference_bit_for_bit():
    o = np.array([car(5.3, -0.05, 2.5), car(4.5, -0.2, 4.5)])
    a = ref(th(), car(5.0, -0.1, 3.0), o)
    b = ref(th(b=0.0), car(5.0, -0.1, 3.0), o, blend=lap_time_line())
    for name in ("s_ref", "n_ref", "v_pert", "n_ot", "n_bl"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes()


@pytest.mark.parametrize("s0", [0.5, 7.0, 13.5])
def test_blend_one_is_the_lap_time_line_and_half_is_between(s0):
    lt = lap_time_line()
    ego = car(s0, 0.0, 3.0)
    one = ref(th(b=1.0), ego, blend=lt)
    on_lt = reference_trajectory(th(), ego, None, lt, TRACK, reachable=False)
    assert np.array_equal(one.s_ref, on_lt.s_ref) and np.array_equal(one.n_ref, on_lt.n_ref)
    zero = ref(th(), ego)
    half = ref(th(b=0.5), ego, blend=lt)
    np.testing.assert_allclose(half.n_pert, 0.5 * (zero.n_pert + one.n_pert), atol=1e-12)
    np.testing.assert_allclose(half.v_pert, 0.5 * (zero.v_pert + one.v_pert), atol=1e-12)
    assert np.abs(one.n_pert - zero.n_pert).max() > 0.01  # the lines do differ here


def test_blend_needs_the_second_line():
    with pytest.raises(ValueError, match="b = 0.5 blends in a second race line"):
        ref(th(b=0.5), car(5.0, 0.0, 3.0))


def test_side_room_passes_on_the_car_s_side_with_room():
    # the ego 0.02 m left of a car 0.3 m ahead in the middle of the track: pass on the left,
    # to s1 beside it (the paper's rule stops at s1 - |dn| from the line)
    o = np.array([car(5.3, 0.0, 2.5)])
    r = ref(th(s3=0.0), car(5.0, 0.02, 3.0), o, side="room")
    assert r.side == 1.0 and np.all(r.n_ot > 0)
    paper = ref(th(s3=0.0), car(5.0, 0.02, 3.0), o)
    assert r.side == 1.0 and paper.side == 0.0
    assert np.allclose(r.n_ot, paper.n_ot)  # same side, same size while the ego is left


def test_side_room_flips_when_the_edge_leaves_no_room():
    w = float(TRACK.w_left[0])
    o = np.array([car(5.3, w - 0.08, 2.5)])  # car ahead near the left edge
    r = ref(th(s3=0.0), car(5.0, w - 0.06, 3.0), o, side="room")
    assert r.side == -1.0 and r.n_ot.min() < 0  # ego left of it, but no room there
    p = ref(th(s3=0.0), car(5.0, w - 0.06, 3.0), o)
    assert p.n_ot.min() >= 0  # the paper's rule pushes into the edge


def test_held_side_and_bad_side():
    o = np.array([car(5.3, 0.0, 2.5)])
    r = ref(th(s3=0.0), car(5.0, 0.05, 3.0), o, side=-1)
    assert r.side == -1.0 and np.all(r.n_ot < 0)  # held right, although the ego is left
    far = ref(th(s3=0.0), car(5.0, 0.05, 3.0), np.array([car(15.0, 0.0, 2.5)]), side=-1)
    assert far.side == 0.0  # out of the shift's range: nothing to hold
    with pytest.raises(ValueError, match="side must be None, 'room', 1 or -1, got 'up'"):
        ref(th(), car(5.0, 0.05, 3.0), o, side="up")
