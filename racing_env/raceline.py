"""The paper's single-agent racing line (appendix B): minimum-curvature path + speed library.

Two stages, both on a closed :class:`~racing_env.track.Track`:

1. **Minimum-curvature path.** Lateral offsets ``n_k`` [m] (left positive) along the centre-line
   normals at ``N`` uniformly spaced centre-line stations (about one per
   ``RacelineConfig.point_spacing`` m, never more than the track grid has) minimise
   ``sum_k kappa_k(n)^2`` subject to
   ``-w_right_k + w_veh/2 + margin <= n_k <= w_left_k - w_veh/2 - margin``.
   The curvature ``kappa = (x' y'' - y' x'') / (x'^2 + y'^2)^(3/2)`` of the path
   ``r_k = c_k + n_k N_k`` is linearised in ``n``: the first derivatives ``x', y'`` and the
   denominator are frozen at the current iterate, the second derivatives are linear in ``n``
   through periodic finite-difference matrices. Each linearisation is a box-constrained
   least-squares problem (a convex QP) solved by :func:`scipy.optimize.lsq_linear`; the line is
   re-linearised until the offsets move by less than ``RacelineConfig.tol`` [m] (at most
   ``max_iter`` times; otherwise a :class:`RacelineConvergenceWarning`). The offsets are then
   interpolated back (periodic cubic spline, clipped to the bounds) to every track grid point.

2. **Speed profile** ``vx(s)`` along the line for a friction coefficient ``mu`` (the paper's
   ``mu_eff``; lateral acceleration limit ``mu g``), by forward (acceleration) and backward
   (braking) passes repeated around the closed lap until nothing changes:

   * ``vx <= sqrt(mu g / |kappa|)`` and ``vx <= vehicle.top_speed``;
   * acceleration ``<= min((C1 - C2 v) d_max - C3 - C4 v^2) / m, a_fric)``;
   * deceleration ``<= min(-((C1 - C2 v) d_min - C3 - C4 v^2) / m, a_fric)``;
   * ``a_fric = mu g sqrt(1 - (v^2 |kappa| / (mu g))^2)`` (friction circle, radius ``mu g``).

   The discrete scheme, with ``ds_k = s_{k+1} - s_k`` along the racing line, is exactly
   ``v_{k+1}^2 - v_k^2 <= 2 ds_k a_acc(v_k, kappa_k)`` and
   ``v_k^2 - v_{k+1}^2 <= 2 ds_k a_brk(v_{k+1}, kappa_{k+1})`` (see :func:`accel_limits`).
   A *library* of profiles over ``mu`` in ``[mu_min, mu_max]`` is stored and linearly
   interpolated in ``mu`` (:meth:`Raceline.speed_at`).

Units: SI throughout (m, s, rad, m/s, m/s^2). ``s_track`` is arc length along the *centre line*
(the coordinate the simulator and the controllers use), ``s`` arc length along the racing line.

Use :func:`get_raceline` (cached on disk and in memory); :func:`compute_raceline` always computes.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
from scipy import sparse
from scipy.interpolate import CubicSpline
from scipy.optimize import lsq_linear

from .track import Track
from .vehicle import VehicleParams

G = 9.81
"""Gravitational acceleration [m/s^2]."""

CACHE_VERSION = 1
"""Bumped whenever the algorithm or the file layout changes (invalidates old cache files)."""

CSV_COLUMNS = ("s_m", "x_m", "y_m", "psi_rad", "kappa_radpm", "vx_mps", "ax_mps2", "n_m",
               "s_track_m")
"""Column names (with units) of :meth:`Raceline.to_csv`."""


class RacelineConvergenceWarning(RuntimeWarning):
    """The minimum-curvature iteration stopped at ``max_iter`` before meeting ``tol``."""


def vehicle_grip_mu(vehicle: VehicleParams | None = None) -> float:
    """Steady-state lateral grip ``mu`` [-] of a car: largest ``a_y / g`` both axles can hold.

    In a steady corner the front axle carries ``m a_y lr / (lf + lr)`` of lateral force and the
    rear ``m a_y lf / (lf + lr)``; each is capped by its Pacejka peak ``Df`` / ``Dr``. For the
    default 1:43 car this is 0.897 (front-limited; ``(Df + Dr) / (m g)`` would say 0.909).
    """
    v = vehicle or VehicleParams()
    wb = v.lf + v.lr
    return float(min(v.Df * wb / (v.m * v.lr), v.Dr * wb / (v.m * v.lf)) / G)


# ====================================================================== configuration
@dataclass(frozen=True)
class RacelineConfig:
    """Settings of the racing line (all hashed into the cache key).

    * ``margin`` [m]: clearance kept from each track edge beyond half the car's width
      (the paper uses 0; a little room absorbs tracking errors of the controllers).
    * ``mu_min``, ``mu_max`` [-], ``n_mu``: the speed library covers ``n_mu`` evenly spaced
      friction values in ``[mu_min, mu_max]`` (plus ``mu_nominal``).
    * ``mu_nominal`` [-]: the profile returned when no ``mu`` is given. Default 0.85: the
      default car's steady-state grip is 0.897 (:func:`vehicle_grip_mu`, front-axle limited);
      0.85 keeps about 5% in reserve for what the point-mass profile ignores (combined slip,
      yaw transients, load transfer) so that a controller can actually follow it.
    * ``point_spacing`` [m]: target spacing of the optimisation stations (the result is
      interpolated back to the track grid).
    * ``tol`` [m]: stop re-linearising once no offset moves by more than this.
    * ``max_iter``: most re-linearisations.
    * ``smoothing`` [-]: weight of a tiny regulariser ``sum (dn/ds)^2 / L^2`` that makes the
      QP strictly convex where curvature does not pin the line (long straights).
    """

    margin: float = 0.01
    mu_min: float = 0.5
    mu_max: float = 1.0
    n_mu: int = 11
    mu_nominal: float = 0.85
    point_spacing: float = 0.05
    tol: float = 1e-4
    max_iter: int = 50
    smoothing: float = 1e-6

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"RacelineConfig.{f.name} must be a finite number, got {v!r}")
        for name in ("n_mu", "max_iter"):
            v = getattr(self, name)
            if int(v) != v or v < (2 if name == "n_mu" else 1):
                raise ValueError(f"RacelineConfig.{name} must be an integer >= "
                                 f"{2 if name == 'n_mu' else 1}, got {v!r}")
        for name in ("mu_min", "mu_max", "mu_nominal", "point_spacing", "tol"):
            if getattr(self, name) <= 0:
                raise ValueError(f"RacelineConfig.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("margin", "smoothing"):
            if getattr(self, name) < 0:
                raise ValueError(f"RacelineConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if not self.mu_min < self.mu_max:
            raise ValueError(f"RacelineConfig needs mu_min < mu_max, got mu_min={self.mu_min!r}, "
                             f"mu_max={self.mu_max!r}")
        if not self.mu_min <= self.mu_nominal <= self.mu_max:
            raise ValueError(f"RacelineConfig.mu_nominal={self.mu_nominal!r} is outside "
                             f"[mu_min, mu_max] = [{self.mu_min}, {self.mu_max}]")

    @property
    def mus(self) -> np.ndarray:
        """Friction values of the speed library, sorted, shape (K,) with K in {n_mu, n_mu + 1}."""
        grid = np.linspace(self.mu_min, self.mu_max, int(self.n_mu))
        if np.min(np.abs(grid - self.mu_nominal)) > 1e-12:
            grid = np.sort(np.append(grid, self.mu_nominal))
        return grid


# ====================================================================== minimum curvature
def _periodic_diff_matrices(n: int, h: float):
    """Sparse periodic central-difference matrices D1 (d/du) and D2 (d^2/du^2), shape (n, n)."""
    i = np.arange(n)
    ip, im = (i + 1) % n, (i - 1) % n
    d1 = sparse.csr_matrix((np.r_[np.full(n, 0.5), np.full(n, -0.5)] / h,
                            (np.r_[i, i], np.r_[ip, im])), shape=(n, n))
    d2 = sparse.csr_matrix((np.r_[np.ones(n), -2.0 * np.ones(n), np.ones(n)] / h ** 2,
                            (np.r_[i, i, i], np.r_[ip, i, im])), shape=(n, n))
    return d1, d2


def offset_bounds(track: Track, s_track, vehicle: VehicleParams, margin: float):
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
        raise ValueError(f"track '{track.name}' is too narrow for the racing line at s = {s:.3f} m: "
                         f"width {w_l[k] + w_r[k]:.3f} m < car width {vehicle.width} m + 2 x margin "
                         f"{margin} m")
    return lo, hi


def minimum_curvature_offsets(track: Track, vehicle: VehicleParams | None = None,
                              config: RacelineConfig | None = None):
    """Solve the minimum-curvature problem on ``N`` uniform centre-line stations.

    Returns ``(s_sub, n_sub, info)``: stations [m] shape (N,), offsets [m] shape (N,), and a
    dict with ``iterations``, ``converged``, ``last_change`` [m], ``cost`` and ``cost_center``
    (summed squared curvature [1/m^2] of the line and of the centre line on the stations).
    """
    vehicle = vehicle or VehicleParams()
    config = config or RacelineConfig()
    m_grid = len(track.s_grid)
    n_pts = int(min(m_grid, max(16, math.ceil(track.length / config.point_spacing))))
    h = track.length / n_pts
    s_sub = np.arange(n_pts) * h
    cx, cy = track.position(s_sub)
    psi = track.heading(s_sub)
    nx, ny = -np.sin(psi), np.cos(psi)
    lo, hi = offset_bounds(track, s_sub, vehicle, config.margin)
    d1, d2 = _periodic_diff_matrices(n_pts, h)
    ddx_c, ddy_c = d2 @ cx, d2 @ cy
    d2nx, d2ny = d2 @ sparse.diags(nx), d2 @ sparse.diags(ny)
    reg = math.sqrt(config.smoothing) / track.length * d1 if config.smoothing > 0 else None

    def kappa_of(n):
        px, py = cx + n * nx, cy + n * ny
        dx, dy = d1 @ px, d1 @ py
        return (dx * (d2 @ py) - dy * (d2 @ px)) / np.hypot(dx, dy) ** 3

    n = np.clip(np.zeros(n_pts), lo, hi)
    converged, change, it = False, np.inf, 0
    for it in range(1, int(config.max_iter) + 1):
        px, py = cx + n * nx, cy + n * ny
        dx, dy = d1 @ px, d1 @ py
        den = np.hypot(dx, dy) ** 3
        a = sparse.diags(dx / den) @ d2ny - sparse.diags(dy / den) @ d2nx
        b = (dx * ddy_c - dy * ddx_c) / den
        rhs = -b
        if reg is not None:
            a = sparse.vstack([a, reg])
            rhs = np.r_[rhs, np.zeros(n_pts)]
        sol = lsq_linear(a.tocsr(), rhs, bounds=(lo, hi), method="trf", tol=1e-12,
                         lsmr_tol="auto", max_iter=2000)
        n_new = np.clip(sol.x, lo, hi)
        change = float(np.max(np.abs(n_new - n)))
        n = n_new
        if change < config.tol:
            converged = True
            break
    if not converged:
        warnings.warn(f"minimum-curvature racing line on track '{track.name}' did not converge in "
                      f"max_iter={config.max_iter} iterations (last offset change {change:.2e} m > "
                      f"tol {config.tol:.2e} m); using the last iterate",
                      RacelineConvergenceWarning, stacklevel=2)
    info = dict(iterations=it, converged=converged, last_change=change,
                cost=float(np.sum(kappa_of(n) ** 2)),
                cost_center=float(np.sum(kappa_of(np.zeros(n_pts)) ** 2)))
    return s_sub, n, info
