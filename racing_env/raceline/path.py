"""The geometry of a racing line: the bounds of its offsets on the track, and the closed line
through offsets at stations, on the track grid (arc length, heading, curvature)."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from ..track import Track
from .config import AnyVehicle, RacelineConfig
from .speed import lap_time_of, speed_profile


def offset_bounds(
    track: Track, s_track: np.ndarray, vehicle: AnyVehicle, margin: float
) -> tuple[np.ndarray, np.ndarray]:
    """Lower / upper bounds ``(n_lo, n_hi)`` [m] on the racing-line offset at centre-line ``s_track``.

    ``n_lo = -w_right + width/2 + margin``, ``n_hi = w_left - width/2 - margin``; raises
    ``ValueError`` naming the place where the track is too narrow for the car plus margins.
    """
    w_l, w_r = track.widths(s_track)
    half = 0.5 * vehicle.width + margin
    lo, hi = -w_r + half, w_l - half
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        k = int(bad[0])
        s = float(np.ravel(s_track)[k])
        raise ValueError(
            f"track '{track.name}' is too narrow for the racing line at s = {s:.3f} m: "
            f"width {w_l[k] + w_r[k]:.3f} m < car width {vehicle.width} m + 2 x margin "
            f"{margin} m"
        )
    return lo, hi


def line_geometry(
    px: np.ndarray, py: np.ndarray
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """Arc length, lap length, heading and curvature of the closed polyline (px, py), shape (M,)."""
    chord = np.hypot(np.diff(np.append(px, px[0])), np.diff(np.append(py, py[0])))
    if np.any(chord <= 1e-12):
        raise ValueError("racing line has repeated points")
    u = np.concatenate([[0.0], np.cumsum(chord)])
    spx = CubicSpline(u, np.append(px, px[0]), bc_type="periodic")
    spy = CubicSpline(u, np.append(py, py[0]), bc_type="periodic")
    # arc length of the spline (Gauss-Legendre, 3 nodes per segment)
    nodes, weights = np.polynomial.legendre.leggauss(3)
    a, b = u[:-1], u[1:]
    uu = 0.5 * (a + b)[:, None] + 0.5 * (b - a)[:, None] * nodes[None, :]
    speed = np.hypot(spx(uu, 1), spy(uu, 1))
    seg = 0.5 * (b - a) * (speed @ weights)
    s = np.concatenate([[0.0], np.cumsum(seg)[:-1]])
    length = float(np.sum(seg))
    dx, dy = spx(u[:-1], 1), spy(u[:-1], 1)
    ddx, ddy = spx(u[:-1], 2), spy(u[:-1], 2)
    psi = np.unwrap(np.arctan2(dy, dx))
    kappa = (dx * ddy - dy * ddx) / np.hypot(dx, dy) ** 3
    return s, length, psi, kappa


def line_on_grid(
    track: Track,
    vehicle: AnyVehicle,
    config: RacelineConfig,
    s_sub: np.ndarray,
    n_sub: np.ndarray,
    with_lap: bool = True,
) -> dict:
    """The line through offsets ``n_sub`` [m] at stations ``s_sub`` [m], on the track grid:
    a dict of ``n``, ``n_lo``, ``n_hi`` (the target bounds), ``x``, ``y``, ``s``, ``length``,
    ``psi``, ``kappa``, ``ds`` and (with ``with_lap``) the lap estimate ``lap_time`` [s] of its
    profile at ``mu_nominal``."""
    s_track = np.asarray(track.s_grid, dtype=float)
    n_lo, n_hi = offset_bounds(track, s_track, vehicle, config.margin)
    spn = CubicSpline(
        np.append(s_sub, track.length), np.append(n_sub, n_sub[0]), bc_type="periodic"
    )
    # Clip only at the physical bounds (edge minus half the car): a cubic spline through the
    # stations overshoots the target bounds by fractions of a millimetre, which the margin
    # absorbs; clipping at the target bounds would put kinks (curvature spikes) in the line.
    n = np.clip(spn(s_track), n_lo - config.margin, n_hi + config.margin)
    px, py = track.to_cartesian(s_track, n)
    s, length, psi, kappa = line_geometry(np.asarray(px), np.asarray(py))
    ds = np.diff(np.append(s, length))
    line = dict(
        n=n,
        n_lo=n_lo,
        n_hi=n_hi,
        x=np.asarray(px, float),
        y=np.asarray(py, float),
        s=s,
        length=length,
        psi=psi,
        kappa=kappa,
        ds=ds,
    )
    if with_lap:
        line["lap_time"] = lap_time_of(
            speed_profile(kappa, ds, float(config.mu_nominal), vehicle)[0], ds
        )
    return line
