"""Tests of racing_env.raceline: minimum-curvature path, speed profile/library, lookups, cache."""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from racing_env import raceline as R
from racing_env.raceline import (
    CSV_COLUMNS,
    G,
    Raceline,
    RacelineConfig,
    RacelineConvergenceWarning,
    accel_limits,
    compute_raceline,
    get_raceline,
    speed_profile,
)
from racing_env.track import Track
from racing_env.tracks import make_track, random_track, tumftm_dir
from racing_env.vehicle import VehicleParams

VEH = VehicleParams()


# ---------------------------------------------------------------------- fixtures / helpers
@pytest.fixture(scope="module")
def default_rl() -> Raceline:
    return compute_raceline(make_track("default"))


@pytest.fixture(scope="module")
def oval_rl() -> Raceline:
    return compute_raceline(make_track("oval"))


def circle_track(radius=1.5, half_width=0.25, n=200) -> Track:
    th = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    w = np.full(n, half_width)
    return Track.from_centerline(radius * np.cos(th), radius * np.sin(th), w, w, name="circle")


def check_profile(kappa, ds, vx, mu, tol=1e-9):
    """v <= the envelope's corner speed, v <= top speed, and the per-segment drive and brake
    limits of the envelope scaled by mu (drive may be negative: slowing through a fast corner)."""
    assert np.all(vx <= R.speed_limit(kappa, mu) * (1 + 1e-9) + tol)
    assert np.all(vx <= VEH.top_speed + tol)
    assert np.all(vx > 0)
    v1 = np.roll(vx, -1)  # includes the wrap from the last point to the first
    k1 = np.roll(kappa, -1)
    a_acc, _ = accel_limits(vx, kappa, mu)
    _, a_brk = accel_limits(v1, k1, mu)
    assert np.all(v1**2 - vx**2 <= 2 * a_acc * ds + 1e-6)
    assert np.all(vx**2 - v1**2 <= 2 * a_brk * ds + 1e-6)


def steady_speed_by_hand(kappa, mu):
    """Fastest speed a car holds on a circle of curvature kappa with the envelope scaled by mu:
    the largest v with the corner feasible and the motor able to hold v (ax_max >= 0), by a
    fine scan of racing_env.envelope.steady_corner (no tables)."""
    from racing_env.envelope import steady_corner

    v = np.linspace(0.05, VEH.top_speed, 4000)
    c = steady_corner(v, v * v * kappa / mu)
    ok = c["feasible"] & (c["ax_max"] >= 0)
    first_bad = np.argmin(ok) if not ok.all() else len(v)
    return float(v[max(first_bad - 1, 0)])


def check_line(rl: Raceline, track: Track, config=RacelineConfig(), curvature=True):
    rl.validate()
    for name in ("s", "x", "y", "psi", "kappa", "vx", "ax", "n", "s_track", "vx_lib", "ax_lib"):
        assert np.all(np.isfinite(getattr(rl, name))), name
    # inside the track minus half the car; at most a millimetre into the margin (spline overshoot)
    half = VEH.width / 2
    assert np.all(rl.n <= track.w_left - half + 1e-9)
    assert np.all(rl.n >= -track.w_right + half - 1e-9)
    assert np.all(rl.n <= rl.n_hi + 1e-3) and np.all(rl.n >= rl.n_lo - 1e-3)
    np.testing.assert_allclose(rl.s_track, track.s_grid)
    # positions really are the centre-line points moved by n along the normal
    x, y = track.to_cartesian(rl.s_track, rl.n)
    np.testing.assert_allclose(rl.x, x, atol=1e-9)
    np.testing.assert_allclose(rl.y, y, atol=1e-9)
    # lower summed squared curvature than the centre line (at the same points and as an integral)
    if curvature:
        assert rl.cost < rl.cost_center
        assert np.sum(rl.kappa**2) < np.sum(track.kappa**2)
        assert np.sum(rl.kappa**2 * rl.ds) < np.sum(track.kappa**2 * track.ds)
    for j, mu in enumerate(rl.mus):
        check_profile(rl.kappa, rl.ds, rl.vx_lib[j], mu)
    assert rl.converged


# ---------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "kw, word",
    [
        (dict(margin=-0.01), "margin"),
        (dict(mu_min=0.0), "mu_min"),
        (dict(mu_min=1.0, mu_max=0.5), "mu_min"),
        (dict(mu_nominal=1.2), "mu_nominal"),
        (dict(n_mu=1), "n_mu"),
        (dict(n_mu=2.5), "n_mu"),
        (dict(point_spacing=0), "point_spacing"),
        (dict(tol=float("nan")), "tol"),
        (dict(max_iter=0), "max_iter"),
        (dict(smoothing=-1.0), "smoothing"),
        (dict(margin="x"), "margin"),
        (dict(linearization="newton"), "linearization"),
        (dict(n_mu=True), "n_mu"),
        (dict(objective="fastest"), "objective"),
        (dict(length_weight=-0.1), "length_weight"),
        (dict(length_weight=float("inf")), "length_weight"),
    ],
)
def test_config_rejects_bad_values(kw, word):
    with pytest.raises(ValueError, match=word):
        RacelineConfig(**kw)


def test_config_mus_include_nominal():
    c = RacelineConfig(mu_min=0.5, mu_max=1.0, n_mu=6, mu_nominal=0.85)
    assert np.all(np.diff(c.mus) > 0) and 0.85 in c.mus and c.mus[0] == 0.5 and c.mus[-1] == 1.0
    assert len(RacelineConfig(n_mu=6, mu_nominal=0.9).mus) == 6  # already on the grid
    assert RacelineConfig().mu_nominal == 1.0  # the car's own envelope


def test_too_narrow_track_raises():
    with pytest.raises(ValueError, match="too narrow"):
        compute_raceline(make_track("oval"), config=RacelineConfig(margin=0.3))


# ---------------------------------------------------------------------- the path
def test_default_track_line(default_rl):
    check_line(default_rl, make_track("default"))


def test_oval_uses_the_width(oval_rl):
    track = make_track("oval")
    check_line(oval_rl, track)
    n, lo, hi = oval_rl.n, oval_rl.n_lo, oval_rl.n_hi
    corner = track.kappa > 0.5 * track.kappa.max()
    # label the two corners and the two straights as contiguous runs
    edges = np.flatnonzero(np.diff(np.r_[corner, corner[0]].astype(int)))
    runs = np.split(np.roll(np.arange(len(n)), -(edges[0] + 1)), np.cumsum(np.diff(edges)))
    corners = [r for r in runs if corner[r[0]]]
    straights = [r for r in runs if not corner[r[0]]]
    assert len(corners) == 2 and len(straights) == 2
    for r in corners:  # apex at the inside (left: the oval turns left)
        assert n[r].max() >= hi[r].max() - 1e-3
        mid = r[len(r) // 2]
        assert n[mid] > 0.5 * hi[mid]
    for r in straights:  # wide on the straight, i.e. outside at entry/exit
        assert n[r].min() <= lo[r].min() + 1e-3
    # the car swings out: offsets span (almost) the whole usable width
    assert n.max() - n.min() > 0.95 * (hi.max() - lo.min())


@pytest.mark.parametrize("linearization", ["frozen", "exact"])
def test_circle_cornering_speed_by_hand(linearization):
    """On a circle the line is a concentric circle of radius r_line = R - n (n left = inwards),
    so kappa_line = 1 / r_line and the speed is sqrt(mu g / kappa_line) all round. The exact
    minimiser is the outer edge; the paper's frozen-derivative scheme ends on the inner edge
    (its known inward bias, see RacelineConfig.linearization)."""
    radius, half_width = 1.5, 0.25
    cfg = RacelineConfig(linearization=linearization)
    rl = compute_raceline(circle_track(radius, half_width), config=cfg)
    edge = half_width - VEH.width / 2 - cfg.margin
    n_expect = -edge if linearization == "exact" else edge
    np.testing.assert_allclose(rl.n, n_expect, atol=2e-3)
    r_line = radius - n_expect
    np.testing.assert_allclose(rl.kappa, 1.0 / r_line, rtol=5e-3)
    np.testing.assert_allclose(rl.length, 2 * np.pi * r_line, rtol=1e-3)
    for mu in (0.5, 0.7, 1.0):
        v_hand = steady_speed_by_hand(1.0 / r_line, mu)
        np.testing.assert_allclose(rl.speed_at(rl.s_track, mu), v_hand, rtol=1e-2)
    np.testing.assert_allclose(rl.ax, 0.0, atol=0.02 * G)  # spline ripple only
    v_nom = steady_speed_by_hand(1.0 / r_line, cfg.mu_nominal)
    np.testing.assert_allclose(rl.lap_time, 2 * np.pi * r_line / v_nom, rtol=1e-2)
    if linearization == "exact":
        assert rl.cost < rl.cost_center
    # the objective is curvature per metre of path: a circle of radius r costs 2 pi / r
    np.testing.assert_allclose(rl.cost, 2 * np.pi / r_line, rtol=1e-2)
    np.testing.assert_allclose(rl.cost_center, 2 * np.pi / radius, rtol=1e-2)


@pytest.mark.parametrize("weight", [0.04, 0.06, 0.08])
def test_shortest_path_term_on_a_circle_by_hand(weight):
    """On a circle of centre radius R and width W, a concentric line of radius r costs
    2 pi / r in curvature and (w / W^2) (2 pi r)^2 / (2 pi R) in the shortest-path term
    (sum |dp|^2 / h with stations a centre-line spacing h apart). The sum is least at
    r^3 = R W^2 / (2 w): with the exact linearization the line settles there."""
    radius, half_width = 1.5, 0.25
    cfg = RacelineConfig(linearization="exact", length_weight=weight)
    rl = compute_raceline(circle_track(radius, half_width), config=cfg)
    r_hand = (radius * (2 * half_width) ** 2 / (2 * weight)) ** (1.0 / 3.0)
    edge = half_width - VEH.width / 2 - cfg.margin
    assert radius - edge < r_hand < radius + edge  # an interior optimum, not a bound
    np.testing.assert_allclose(radius - rl.n, r_hand, rtol=5e-3)
    np.testing.assert_allclose(rl.length, 2 * np.pi * r_hand, rtol=5e-3)
    assert rl.length_weight == weight


def test_lap_time_line_is_no_slower_than_minimum_curvature_and_shorter_where_it_gains():
    track = make_track("random:202")
    curv = compute_raceline(track)
    fast = compute_raceline(track, config=RacelineConfig(objective="lap_time"))
    check_line(fast, track, curvature=False)
    assert curv.length_weight == 0.0
    assert fast.lap_time < curv.lap_time  # random:202 gains (7.66 -> 7.63 s) ...
    assert fast.length_weight > 0 and fast.length < curv.length  # ... by a shorter path
    assert fast.key != curv.key


def test_lap_time_search_tries_the_minimum_curvature_line_and_keeps_the_fastest():
    track = make_track("oval")
    w, s_sub, n_sub, info, tried = R.lap_time_weight_search(track, refine=3)
    weights = [t[0] for t in tried]
    assert weights[: len(R.LENGTH_WEIGHTS)] == list(R.LENGTH_WEIGHTS)
    laps = dict(tried)
    assert laps[w] == min(lap for _, lap in tried)
    assert np.all(np.isfinite(n_sub)) and n_sub.shape == s_sub.shape


def test_the_mpc_and_follower_race_the_line_they_are_given():
    from agents import make_agent_spec

    mpc = make_agent_spec("mpc:zeta=1.0,line=lap_time")
    mpc.reset("random:202", "car_0", 0)
    want = get_raceline("random:202", config=RacelineConfig(objective="lap_time"))
    assert mpc.raceline.key == want.key and mpc.mpc.line == "lap_time"
    follower = make_agent_spec("raceline:line=lap_time")
    follower.reset("random:202")
    assert follower.raceline.key == want.key
    assert make_agent_spec("mpc").line == "curvature"
    with pytest.raises(ValueError, match="objective must be one of"):
        make_agent_spec("mpc:line=fastest")


def test_exact_linearization_minimises_curvature(default_rl):
    track = make_track("default")
    rl = compute_raceline(track, config=RacelineConfig(linearization="exact"))
    check_line(rl, track)
    assert rl.cost < default_rl.cost  # the true minimiser beats the frozen fixed point


def test_exact_line_is_a_stationary_point_of_curvature_per_metre():
    """No small feasible move of the exact line's offsets lowers the integral of kappa^2 over
    the path (the objective weighs curvature per metre of path, not per station)."""
    from racing_env.raceline import minimum_curvature_offsets

    track = make_track("oval")
    s, n, info = minimum_curvature_offsets(track, config=RacelineConfig(linearization="exact"))
    lo, hi = R.offset_bounds(track, s, VEH, RacelineConfig().margin)

    def integral(n):
        px, py = track.to_cartesian(s, n)
        p = np.c_[px, py]
        d1 = (np.roll(p, -1, 0) - np.roll(p, 1, 0)) / 2
        d2 = np.roll(p, -1, 0) - 2 * p + np.roll(p, 1, 0)
        ds = np.hypot(*d1.T)
        return float(np.sum(((d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / ds**3) ** 2 * ds))

    f0 = integral(n)
    rng = np.random.default_rng(0)
    for _ in range(20):
        bump = np.exp(-0.5 * ((s - rng.uniform(0, track.length)) / 0.3) ** 2)  # smooth, 0.3 m
        for step in (-2e-3, 2e-3):
            m = np.clip(n + step * bump, lo, hi)
            assert integral(m) >= f0 * (1 - 1e-4)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 40))
def test_box_qp_active_set_meets_the_kkt_conditions(seed, n):
    """The active-set solution is feasible and optimal: the gradient vanishes on free offsets,
    points into the box at the bounds (checked against the KKT conditions by hand)."""
    from scipy import sparse

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n))
    h = sparse.csc_matrix(a.T @ a + 0.1 * np.eye(n))
    g = rng.normal(size=n) * 3
    lo, hi = -rng.uniform(0.1, 1, n), rng.uniform(0.1, 1, n)
    x = R.box_qp_active_set(h, g, lo, hi)
    assume(x is not None)  # cycling falls back to OSQP / DAQP
    grad = h @ x + g
    tol = 1e-8 * (1 + np.abs(g).max())
    assert np.all(x >= lo) and np.all(x <= hi)
    free = (x > lo + 1e-12) & (x < hi - 1e-12)
    assert np.all(np.abs(grad[free]) < tol)
    assert np.all(grad[x <= lo + 1e-12] > -tol) and np.all(grad[x >= hi - 1e-12] < tol)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 40))
def test_box_qp_interior_point_meets_the_kkt_conditions(seed, n):
    """The interior-point solution, polished by the active-set method, meets the KKT
    conditions; unpolished it is within 1e-6 of them (strictly inside the bounds)."""
    from scipy import sparse

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n))
    h = sparse.csc_matrix(a.T @ a + 0.1 * np.eye(n))
    g = rng.normal(size=n) * 3
    lo, hi = -rng.uniform(0.1, 1, n), rng.uniform(0.1, 1, n)
    x_ip = R.box_qp_interior_point(h, g, lo, hi)
    assert x_ip is not None and np.all(x_ip > lo) and np.all(x_ip < hi)
    x = R.box_qp_active_set(h, g, lo, hi, x_ip)
    assert x is not None  # started at the solution, it settles
    assert np.abs(x - x_ip).max() < 1e-6
    grad = h @ x + g
    tol = 1e-8 * (1 + np.abs(g).max())
    free = (x > lo + 1e-12) & (x < hi - 1e-12)
    assert np.all(np.abs(grad[free]) < tol)
    assert np.all(grad[x <= lo + 1e-12] > -tol) and np.all(grad[x >= hi - 1e-12] < tol)


def test_box_qp_interior_point_needs_room_between_the_bounds():
    from scipy import sparse

    with pytest.raises(ValueError, match="lo < hi everywhere, got 1 of 2 bounds with hi <= lo"):
        R.box_qp_interior_point(
            sparse.eye(2, format="csc"), np.ones(2), np.zeros(2), np.array([1.0, 0.0])
        )


def test_a_full_scale_qp_the_active_set_method_cannot_settle_goes_to_the_interior_point():
    """Above INTERIOR_POINT_FIRST_ABOVE offsets, a QP whose active sets do not settle is
    solved by the interior-point method and polished (not by OSQP, which takes seconds)."""
    from scipy import sparse

    from racing_env.raceline import boxqp

    n = boxqp.INTERIOR_POINT_FIRST_ABOVE + 1
    i = np.arange(n)
    d2 = sparse.csr_matrix(
        (
            np.r_[np.ones(n), -2 * np.ones(n), np.ones(n)],
            (np.r_[i, i, i], np.r_[(i + 1) % n, i, (i - 1) % n]),
        ),
        shape=(n, n),
    )
    h = sparse.csc_matrix(d2.T @ d2 + 1e-6 * sparse.eye(n))
    g = np.sin(np.linspace(0, 40 * np.pi, n)) * 1e-3
    lo, hi = -np.ones(n), np.ones(n)
    calls = []
    real = boxqp.box_qp_active_set

    def never_settles_cold(h_, g_, lo_, hi_, x0=None, **kw):
        calls.append(x0 is None)
        return None if x0 is None else real(h_, g_, lo_, hi_, x0, **kw)

    qp = boxqp.BoxQP(h, lo, hi)
    mp = pytest.MonkeyPatch()
    mp.setattr(boxqp, "box_qp_active_set", never_settles_cold)
    mp.setattr(boxqp.BoxQP, "_conic", lambda *a, **k: pytest.fail("OSQP or DAQP was called"))
    try:
        x = qp.solve(h, g)
    finally:
        mp.undo()
    assert calls == [True, False]  # the cold attempt, then the polish
    grad = h @ x + g
    free = (x > lo) & (x < hi)
    assert np.abs(grad[free]).max() < 1e-9 * np.abs(g).max()


def test_tolerance_scales_with_the_track():
    """``tol=None`` is TOL_PER_WIDTH of the mean width: 1e-4 m on the 0.5 m wide built-in
    tracks, 43 times that on a track 43 times larger."""
    from racing_env.raceline import TOL_PER_WIDTH

    cfg = RacelineConfig()
    small, big = circle_track(1.5, 0.25), circle_track(64.5, 10.75)
    assert cfg.tol_for(make_track("default")) == pytest.approx(TOL_PER_WIDTH * 0.5)
    assert cfg.tol_for(big) == pytest.approx(43 * cfg.tol_for(small), rel=1e-2)
    assert RacelineConfig(tol=3e-4).tol_for(big) == 3e-4


def test_convergence_warning():
    with pytest.warns(RacelineConvergenceWarning, match="did not converge"):
        rl = compute_raceline(make_track("default"), config=RacelineConfig(max_iter=1))
    assert not rl.converged and rl.iterations == 1
    assert np.all(np.isfinite(rl.vx))


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000))
@example(seed=140)  # clipping the spline at the target bounds once made curvature spikes here
def test_random_tracks_valid_line(seed):
    try:
        track = random_track(seed)
    except ValueError:
        assume(False)
    exact = RacelineConfig(linearization="exact")
    with warnings.catch_warnings():
        warnings.simplefilter("error", RacelineConvergenceWarning)
        rl = compute_raceline(track)
        rl_exact = compute_raceline(track, config=exact)
    # the paper's frozen scheme is biased inwards and can end slightly *above* the centre line's
    # curvature on near-circular tracks (e.g. seed 231); the exact minimiser never does
    check_line(rl, track, curvature=False)
    check_line(rl_exact, track, config=exact)
    assert rl.cost < 1.05 * rl.cost_center


@pytest.mark.skipif(tumftm_dir() is None, reason="TUMFTM track folder not present")
def test_tumftm_monza_valid_line():
    if not (tumftm_dir() / "Monza.csv").is_file():
        pytest.skip("Monza.csv not in the TUMFTM folder")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # track loader notes (not ours)
        track = make_track("tumftm:Monza")
    rl = compute_raceline(track)
    check_line(rl, track)  # its time: benchmarks/raceline_speed.py
    assert 20.0 < rl.lap_time < 60.0


# ---------------------------------------------------------------------- speed profile
def test_speed_profile_constraints_and_periodicity(default_rl):
    rl = default_rl
    for mu in (0.5, 0.85, 1.0):
        vx, ax = speed_profile(rl.kappa, rl.ds, mu)
        check_profile(rl.kappa, rl.ds, vx, mu)
        np.testing.assert_allclose(ax, (np.roll(vx, -1) ** 2 - vx**2) / (2 * rl.ds), atol=1e-9)
        # periodic: starting the lap elsewhere gives the same (rotated) profile
        for shift in (1, 137, len(vx) // 2):
            v2, _ = speed_profile(np.roll(rl.kappa, shift), np.roll(rl.ds, shift), mu)
            np.testing.assert_allclose(v2, np.roll(vx, shift), rtol=1e-9, atol=1e-9)
    # the nominal profile both accelerates and brakes and reaches top speed on the main straight
    assert rl.ax.max() > 0.5 and rl.ax.min() < -0.5
    assert rl.vx.max() > 0.95 * VEH.top_speed


def test_accel_limits_match_steady_corner():
    """The tabulated envelope agrees with the quasi-steady corner solved point by point."""
    from racing_env.envelope import steady_corner

    v = np.linspace(0.5, 0.95 * VEH.top_speed, 7)[:, None]
    k = np.array([0.0, 0.3, 1.0, 1.5])[None, :]
    for mu in (0.5, 1.0):
        c = steady_corner(v, v * v * k / mu)
        inside = c["feasible"]
        a1, b1 = accel_limits(v, k, mu, VEH)
        np.testing.assert_allclose(
            a1[inside], mu * c["ax_max"][inside], atol=0.05
        )  # table: 41 x 240
        np.testing.assert_allclose(b1[inside], -mu * c["ax_min"][inside], atol=0.05)
    # at a standing start on a straight: the drive force less the (smoothed, nearly zero)
    # rolling resistance, the envelope's lowest speed being 0.02 m/s
    a, b = accel_limits(0.0, 0.0, 1.0, VEH)
    v0 = 0.02
    by_hand = (VEH.C1 - VEH.C2 * v0 - VEH.C3 * math.tanh(v0 / VEH.v_low) - VEH.C4 * v0**2) / VEH.m
    assert a == pytest.approx(by_hand, rel=1e-6)


def test_speed_profile_straight_runs_at_top_speed():
    vx, ax = speed_profile(np.zeros(50), np.full(50, 0.1), 0.8)
    np.testing.assert_allclose(vx, VEH.top_speed, rtol=1e-6)
    np.testing.assert_allclose(ax, 0.0, atol=1e-9)
    with pytest.raises(ValueError):
        speed_profile(np.zeros(5), np.zeros(5), 0.8)


# ---------------------------------------------------------------------- library
def test_library_exact_at_grid_and_monotone(default_rl):
    rl = default_rl
    s = rl.s_track
    for j, mu in enumerate(rl.mus):
        np.testing.assert_array_equal(rl.speed_at(s, mu), rl.vx_lib[j])
    np.testing.assert_array_equal(rl.speed_at(s), rl.vx)
    np.testing.assert_array_equal(rl.speed_at(s, rl.mu_nominal), rl.vx)
    # profiles themselves are ordered in mu, hence so is their interpolation
    assert np.all(np.diff(rl.vx_lib, axis=0) >= -1e-9)
    mus = np.linspace(rl.mus[0], rl.mus[-1], 37)
    v = np.array([rl.speed_at(s, mu) for mu in mus])
    assert np.all(np.diff(v, axis=0) >= -1e-9)
    lap = [rl.lap_time_at(mu) for mu in mus]
    assert np.all(np.diff(lap) <= 1e-9)
    # halfway between two grid mus is the mean of their profiles
    np.testing.assert_allclose(
        rl.speed_at(s, 0.5 * (rl.mus[0] + rl.mus[1])), 0.5 * (rl.vx_lib[0] + rl.vx_lib[1])
    )


@pytest.mark.parametrize("mu", [0.3, 1.2, -1.0, float("nan"), float("inf")])
def test_mu_out_of_range_raises(default_rl, mu):
    with pytest.raises(ValueError, match=r"outside the speed library range \[0.5, 1.0\]") as exc:
        default_rl.speed_at(1.0, mu)
    assert str(mu) in str(exc.value)


# ---------------------------------------------------------------------- lookups and output
def test_lookups_vectorised_and_unwrapped(default_rl):
    rl = default_rl
    L = rl.track_length
    np.testing.assert_allclose(rl.offset_at(rl.s_track), rl.n, atol=1e-12)
    np.testing.assert_allclose(
        rl.heading_at(rl.s_track), np.arctan2(np.sin(rl.psi), np.cos(rl.psi)), atol=1e-9
    )
    s = np.linspace(-L, 3 * L, 200).reshape(20, 10)
    for f in (rl.offset_at, rl.speed_at, rl.heading_at, rl.kappa_at):
        out = f(s)
        assert out.shape == s.shape and np.all(np.isfinite(out))
        np.testing.assert_allclose(f(s + 2 * L), out, atol=1e-9)
    assert np.ndim(rl.speed_at(3.0)) == 0 and float(rl.speed_at(3.0)) > 0
    sl = rl.s_line_at(np.linspace(0, 2 * L, 500))
    assert np.all(np.diff(sl) > 0)
    assert rl.s_line_at(L) == pytest.approx(rl.length)
    # the heading really is the direction of travel along the line
    d = np.arctan2(np.diff(rl.y), np.diff(rl.x)) - 0.5 * (rl.psi[1:] + rl.psi[:-1])
    assert np.max(np.abs(np.arctan2(np.sin(d), np.cos(d)))) < 0.02


def test_csv_and_plot(default_rl, tmp_path):
    p = default_rl.to_csv(tmp_path / "line.csv")
    lines = p.read_text().splitlines()
    assert lines[1] == "# " + ",".join(CSV_COLUMNS)
    data = np.loadtxt(p, delimiter=",", comments="#")
    assert data.shape == (len(default_rl.s), len(CSV_COLUMNS))
    np.testing.assert_allclose(data[:, 5], default_rl.vx, rtol=1e-8)
    np.testing.assert_allclose(data[:, 7], default_rl.n, atol=1e-9)
    png = R.plot_raceline(make_track("default"), default_rl, tmp_path / "line.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert default_rl.plot(tmp_path / "line2.png").stat().st_size > 10_000


# ---------------------------------------------------------------------- caching
@pytest.fixture
def counting_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path))
    R.clear_memo()
    calls = []
    real = R.compute_raceline

    def counted(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(R.cache, "compute_raceline", counted)
    yield calls
    R.clear_memo()


def test_cache_round_trip(counting_cache, tmp_path):
    track = make_track("oval")
    rl1 = get_raceline(track)
    assert len(counting_cache) == 1 and not rl1.from_cache
    path = R.cache_path(track)
    assert path.is_file() and path.parent == tmp_path / "raceline"
    assert get_raceline(track) is rl1  # in-process memo
    R.clear_memo()
    rl2 = get_raceline(track)
    assert len(counting_cache) == 1 and rl2.from_cache  # from disk, not recomputed
    arrays = [f.name for f in fields(rl1) if isinstance(getattr(rl1, f.name), np.ndarray)]
    assert len(arrays) == 14  # every per-point array and the speed library
    for name in arrays:
        np.testing.assert_array_equal(getattr(rl2, name), getattr(rl1, name))
    assert rl2.lap_time == rl1.lap_time and rl2.key == rl1.key and rl2.track is track
    assert not [p for p in path.parent.iterdir() if p.suffix != ".npz" or ".tmp" in p.name]
    # a different config or vehicle is a different entry
    get_raceline(track, config=RacelineConfig(margin=0.02))
    assert len(counting_cache) == 2
    assert R.cache_path(track, VehicleParams(width=0.05)) != path


def test_an_edit_of_the_racing_line_code_is_a_new_cache_entry(counting_cache, monkeypatch):
    """A line cached by other code is never loaded: the key covers the sources that compute it."""
    package = set(Path(R.__file__).parent.glob("*.py"))
    assert package and set(R.SOURCES) >= package
    assert {p.name for p in R.SOURCES} >= {"envelope.py", "vehicle.py", "track.py"}
    track = make_track("oval")
    get_raceline(track)
    old_path = R.cache_path(track)
    monkeypatch.setattr(R.config, "_SOURCES_HASH", "edited-sources")
    R.clear_memo()
    assert R.cache_path(track) != old_path
    rl = get_raceline(track)
    assert len(counting_cache) == 2 and not rl.from_cache


@pytest.mark.parametrize("damage", ["garbage", "truncated", "empty", "foreign", "nan"])
def test_corrupt_cache_is_recomputed(counting_cache, damage):
    track = make_track("oval")
    rl1 = get_raceline(track)
    path = R.cache_path(track)
    raw = path.read_bytes()
    if damage == "garbage":
        path.write_bytes(b"not an npz file at all")
    elif damage == "truncated":
        path.write_bytes(raw[: len(raw) // 2])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "foreign":  # a valid file for another config under this name
        other = compute_raceline(track, config=RacelineConfig(margin=0.02))
        np.savez(path, **other.to_npz_dict())
    elif damage == "nan":
        d = rl1.to_npz_dict()
        d["vx"] = d["vx"].copy()
        d["vx"][3] = np.nan
        np.savez(path, **d)
    R.clear_memo()
    n_before = len(counting_cache)
    rl2 = get_raceline(track)
    assert len(counting_cache) == n_before + 1 and not rl2.from_cache
    np.testing.assert_allclose(rl2.vx, rl1.vx)
    R.clear_memo()
    assert get_raceline(track).from_cache  # the file was rewritten and is good


def test_the_line_is_its_offsets_on_the_grid():
    """compute_raceline is minimum_curvature_offsets' offsets put on the track grid by
    path.line_on_grid, and get_raceline without a cache is compute_raceline, bit for bit."""
    from racing_env.raceline.path import line_on_grid

    track, cfg = make_track("oval"), RacelineConfig()
    rl = compute_raceline(track, VEH, cfg)
    s_sub, n_sub, info = R.minimum_curvature_offsets(track, VEH, cfg)
    line = line_on_grid(track, VEH, cfg, s_sub, n_sub)
    for name in ("n", "n_lo", "n_hi", "x", "y", "s", "psi", "kappa"):
        np.testing.assert_array_equal(line[name], getattr(rl, name))
    assert line["length"] == rl.length and line["lap_time"] == rl.lap_time
    assert info["cost"] == rl.cost and info["iterations"] == rl.iterations
    again = get_raceline(track, VEH, cfg, use_cache=False)
    for name in ("n", "vx", "vx_lib", "ax_lib"):
        np.testing.assert_array_equal(getattr(again, name), getattr(rl, name))


def test_get_raceline_accepts_names_and_skips_cache(counting_cache, tmp_path):
    rl = get_raceline("oval", use_cache=False)
    assert isinstance(rl, Raceline) and not os.path.exists(tmp_path / "raceline")
    with pytest.raises(ValueError, match="config"):
        get_raceline("oval", config={"margin": 0.1})
