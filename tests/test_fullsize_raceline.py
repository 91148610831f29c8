"""The full-size class's g-g-v envelope (racing_env.vehicles.fullsize_envelope) against hand
computations from its published parameters, and its racing lines on the shipped full-scale
circuits against an independent point-mass lap simulation written here."""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from dataclasses import asdict

import numpy as np
import pytest

from racing_env.envelope import ggv
from racing_env.raceline import RacelineConfig, cache_key, get_raceline
from racing_env.raceline import config as raceline_config
from racing_env.scaling import scaled_configs
from racing_env.tracks import make_track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams
from racing_env.vehicles.fullsize import frenet_ode_fullsize_numpy
from racing_env.vehicles.fullsize_envelope import steady_corner_fullsize

P = FullSizeParams()
L = P.lf + P.lr
CIRCUITS = ("Monza", "Spa", "Silverstone", "Catalunya", "Spielberg")


# ---------------------------------------------------------------- hand computations
def tyre_peak(fz_axle: float) -> float:
    """Peak force [N] of an axle under ``fz_axle`` [N]: two tyres of half the load, each
    ``mu Fz (1 + eps Fz / Fz0)`` (TUM's load sensitivity, eps = -0.1, Fz0 = 3 kN)."""
    fz = 0.5 * fz_axle
    return 2.0 * 1.0 * fz * (1.0 - 0.1 * fz / 3000.0)


def axle_peaks(v: float) -> tuple[float, float]:
    """(front, rear) peaks [N] at ``v`` [m/s]: static share of 1200 kg plus 0.45 / 0.75 v^2."""
    w = 1200.0 * 9.81 / 3.0
    return tyre_peak(w * 1.4 + 0.45 * v * v), tyre_peak(w * 1.6 + 0.75 * v * v)


def resistance(v: float) -> float:
    """Drag and rolling resistance [N] at ``v`` [m/s] (the force law's smooth sign)."""
    return 0.75 * v * v + 0.013 * 1200.0 * 9.81 * math.tanh(v / 0.5)


def hand_lateral_limit(v: float) -> float:
    """Quasi-steady lateral limit [m/s^2]: each axle carries the share of m a_y that balances
    the yaw moment (front lr / L, rear lf / L); the first to reach its peak limits."""
    d_f, d_r = axle_peaks(v)
    return min(d_f * L / (P.m * P.lr), d_r * L / (P.m * P.lf))


@pytest.fixture(scope="module")
def env():
    return ggv(P)


# ---------------------------------------------------------------- the envelope
@pytest.mark.parametrize("v", [20.0, 30.0, 45.0, 60.0])
def test_lateral_limit_rises_with_downforce_as_the_grip_formula_gives(env, v):
    """Above the steering-bound range the lateral limit is the limiting axle's peak: within
    0.2% of the hand value (the rest is the body slip and cos(delta), a few 1e-4), and it
    rises with v^2 through the downforce."""
    got = float(env.lateral_limit(v))
    assert got == pytest.approx(hand_lateral_limit(v), rel=2e-3)
    c = steady_corner_fullsize(v, 0.999999 * got, P)
    assert bool(c["feasible"])
    # the limiting axle is at its peak: the front at speed (more rear downforce)
    assert max(float(c["f_front"]), float(c["f_rear"])) == pytest.approx(1.0, abs=2e-4)
    if v >= 30.0:
        assert float(c["f_front"]) > float(c["f_rear"])


def test_downforce_gain_between_20_and_60_mps(env):
    """The lateral limit grows by the hand ratio (the front axle's peak at 60 vs 20 m/s, the
    rear's at 20: the limiting axle switches near 20 m/s): about +22%."""
    ratio = float(env.lateral_limit(60.0)) / float(env.lateral_limit(20.0))
    hand = hand_lateral_limit(60.0) / hand_lateral_limit(20.0)
    assert ratio == pytest.approx(hand, rel=2e-3)
    assert 1.18 < ratio < 1.26


def test_top_speed_is_the_class_top_speed(env):
    assert env.top_speed == P.top_speed()
    assert env.v[-1] == pytest.approx(1.05 * P.top_speed())
    hi, _ = env.longitudinal_limits(P.top_speed(), 0.0)
    assert abs(float(hi)) < 2e-3  # drive balances drag and rolling resistance there


@pytest.mark.parametrize("v", [2.0, 10.0, 25.0])
def test_drive_limit_at_low_speed_is_the_rear_grip(env, v):
    """Below about 36 m/s the rear tyres (5.6-6.4 kN) bind, under the 7 kN cap and P / v."""
    _, d_r = axle_peaks(v)
    assert d_r < min(P.F_drive_max, P.P_max / v)
    c = steady_corner_fullsize(v, 0.0, P)
    assert float(c["ax_max"]) == pytest.approx((d_r - resistance(v)) / P.m, rel=1e-9)
    assert float(env.longitudinal_limits(v, 0.0)[0]) == pytest.approx(
        (d_r - resistance(v)) / P.m, rel=2e-3
    )


@pytest.mark.parametrize("v", [40.0, 55.0, 65.0])
def test_drive_limit_at_speed_is_power_over_speed_minus_drag(env, v):
    vx_eff = math.hypot(v, P.v_low)
    assert P.P_max / vx_eff < axle_peaks(v)[1]
    c = steady_corner_fullsize(v, 0.0, P)
    want = (P.P_max / vx_eff - resistance(v)) / P.m
    assert float(c["ax_max"]) == pytest.approx(want, rel=1e-9)
    assert float(env.longitudinal_limits(v, 0.0)[0]) == pytest.approx(want, abs=5e-3)


@pytest.mark.parametrize("v", [5.0, 30.0, 60.0])
def test_braking_limit_is_the_front_grip_over_the_brake_split(env, v):
    """60% of the brake force on the front axle, which has 47% of the static load and no load
    transfer: the front reaches its peak first, at F_b = D_f / 0.6 (under the 20 kN cap and
    the rear's D_r / 0.4)."""
    d_f, d_r = axle_peaks(v)
    f_b = d_f / 0.6
    assert f_b < min(P.F_brake_max, d_r / 0.4)
    c = steady_corner_fullsize(v, 0.0, P)
    assert float(c["ax_min"]) == pytest.approx(-(f_b + resistance(v)) / P.m, rel=1e-9)


def test_corner_points_are_equilibria_of_the_force_law(env):
    """At 40 m/s and 70% of the lateral limit, with the steering and velocities of the corner
    and a throttle that keeps the rear's longitudinal force small, the force law's lateral
    and yaw derivatives vanish (the envelope is quasi-steady cornering of that law)."""
    v = 40.0
    c = steady_corner_fullsize(v, 0.7 * float(env.lateral_limit(v)), P)
    vx, vy, om, de = (float(c[k]) for k in ("vx", "vy", "omega", "delta"))
    _, _, _, _, vy_dot, om_dot = frenet_ode_fullsize_numpy(
        0.0, 0.0, vx, vy, om, 0.0, de, 0.0, P.pack()
    )
    assert abs(vy_dot) < 1e-6 and abs(om_dot) < 1e-6
    assert math.hypot(vx, vy) == pytest.approx(v, rel=1e-9)


def test_envelope_tables_are_finite_and_ordered(env):
    assert np.all(np.isfinite(env.ax_max)) and np.all(np.isfinite(env.ax_min))
    assert np.all(env.ax_min < 0) and np.all(env.ax_max > env.ax_min)
    # above 20 m/s more lateral demand leaves less longitudinal room (below, the front
    # tyre's drag at large steering angles and vy omega help the brake, up to 17 m/s)
    fast = env.v >= 20.0
    assert np.all(np.diff(env.ax_max[fast], axis=1) <= 1e-9)
    assert np.all(np.diff(env.ax_min[fast], axis=1) >= -1e-9)


def test_orca_envelope_and_key_fields_are_unchanged():
    """ORCA's envelope still comes from its own model, and its cache key is made of the same
    fields as before the full-size class (so its cached lines stay valid); the full-size key
    names the class and differs."""
    orca = ggv(VehicleParams())
    assert orca.top_speed == VehicleParams().top_speed and orca.v[-1] < 5.0
    track = make_track("oval")
    cfg = RacelineConfig()
    blob = json.dumps(
        {
            "version": raceline_config.CACHE_VERSION,
            "sources": raceline_config._SOURCES_HASH,
            "track": track.fingerprint(),
            "vehicle": VehicleParams().to_dict(),
            "config": asdict(cfg),
        },
        sort_keys=True,
    )
    assert cache_key(track, VehicleParams(), cfg) == hashlib.sha1(blob.encode()).hexdigest()[:24]
    assert cache_key(track, P, cfg) != cache_key(track, VehicleParams(), cfg)
    with pytest.raises(ValueError, match="FullSizeParams"):
        cache_key(track, object(), cfg)  # type: ignore[arg-type]


# ---------------------------------------------------------------- racing lines
@pytest.fixture(scope="module")
def lines():
    """The racing line of every shipped circuit at full scale, with the class's scaled
    settings (computed once per cache, about 1-2 s each)."""
    cfg = scaled_configs(P).raceline
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # inner widths narrowed at hairpins
        return {name: get_raceline(f"tumftm:{name}", P, cfg) for name in CIRCUITS}


def point_mass_lap(kappa: np.ndarray, ds: np.ndarray) -> float:
    """An independent lap estimate: a point mass with the class's published figures only,
    its grip the *sum* of both axles' peaks (a friction circle on the total force: no axle
    balance), the drive min(7 kN, P / v, rear peak), the brake the front peak / 0.6, drag and
    rolling resistance; forward/backward passes of a plain Euler scheme in Python."""
    n = len(kappa)
    v_grid = np.linspace(0.0, 80.0, 801)
    peaks = np.array([axle_peaks(v) for v in v_grid])
    grip = peaks.sum(axis=1) / P.m
    # corner speeds: largest v with v^2 |kappa| <= grip(v) (grip rises slower than v^2)
    k = np.abs(kappa)[:, None]
    ok = v_grid[None, :] ** 2 * k <= grip[None, :]
    v_cap = np.minimum(
        v_grid[np.where(ok.all(axis=1), len(v_grid) - 1, ok.argmin(axis=1) - 1)], 66.4
    )
    v = v_cap.copy()

    def room(vk, kk):
        ay = vk * vk * abs(kk)
        g = np.interp(vk, v_grid, grip)
        return math.sqrt(max(1.0 - (ay / g) ** 2, 0.0))

    start = int(np.argmin(v))
    for _ in range(3):
        for j in range(n):  # drive
            i = (start + j) % n
            i1 = (i + 1) % n
            d_f, d_r = axle_peaks(v[i])
            f = min(P.F_drive_max, P.P_max / max(v[i], 0.5), d_r) * room(v[i], kappa[i])
            a = (f - resistance(v[i])) / P.m
            v[i1] = min(v[i1], math.sqrt(max(v[i] ** 2 + 2.0 * ds[i] * a, 0.0)))
        for j in range(n):  # brake
            i1 = (start - j) % n
            i = (i1 - 1) % n
            d_f, _ = axle_peaks(v[i1])
            a = (d_f / 0.6 * room(v[i1], kappa[i1]) + resistance(v[i1])) / P.m
            v[i] = min(v[i], math.sqrt(v[i1] ** 2 + 2.0 * ds[i] * a))
    return float(np.sum(2.0 * ds / (v + np.roll(v, -1))))


def test_raceline_at_full_scale(lines):
    for name, rl in lines.items():
        rl.validate()
        assert rl.converged, name
        assert rl.track_length > 4000.0, name  # built at full scale from the string name
        assert np.all(rl.vx <= P.top_speed() + 1e-9), name


def test_monza_speed_profile(lines):
    """The main straight approaches the top speed (239 km/h) without exceeding it; the
    chicanes' minimum speeds are those of their radii on the line (km/h)."""
    rl = lines["Monza"]
    kmh = rl.vx * 3.6
    top = P.top_speed() * 3.6
    i = int(np.argmax(kmh))
    assert 0.93 * top < kmh[i] <= top
    assert rl.s_track[i] < 936.0  # on the main straight, before the first chicane

    def slowest(lo, hi):
        m = (rl.s_track >= lo) & (rl.s_track <= hi)
        return float(kmh[m].min())

    assert 35.0 < slowest(800, 1100) < 60.0  # Variante del Rettifilo (about 41 km/h)
    assert 45.0 < slowest(2050, 2300) < 75.0  # Variante della Roggia (about 56 km/h)
    assert 65.0 < slowest(3850, 4100) < 100.0  # Variante Ascari (about 78 km/h)


def test_lap_estimates_agree_with_a_point_mass(lines):
    """Every shipped circuit's lap estimate is within 3% of the point-mass lap on the same
    path (they agree to about 0.1-1%: see docs/fullsize.md), at an average
    speed of 110-180 km/h."""
    for name, rl in lines.items():
        pm = point_mass_lap(rl.kappa, rl.ds)
        print(f"{name}: lap estimate {rl.lap_time:.2f} s, point mass {pm:.2f} s")
        assert abs(rl.lap_time / pm - 1.0) < 0.03, (name, rl.lap_time, pm)
        avg = rl.length / rl.lap_time * 3.6
        assert 110.0 < avg < 180.0, (name, avg)
