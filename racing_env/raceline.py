"""The paper's single-agent racing line (appendix B): minimum-curvature path + speed library.

``RacelineConfig(objective="lap_time")`` goes beyond the paper: the same path problem with a
shortest-path term added, its weight searched per track for the shortest lap estimate
(:func:`lap_time_weight_search`).

Two stages, both on a closed :class:`~racing_env.track.Track`:

1. **Minimum-curvature path.** Lateral offsets ``n_k`` [m] (left positive) along the centre-line
   normals at ``N`` uniformly spaced centre-line stations (about one per
   ``RacelineConfig.point_spacing`` m, never more than the track grid has) minimise the
   curvature per metre of path, ``sum_k kappa_k(n)^2 |r_k'| h`` (``|r_k'|`` the path length per
   unit of centre-line ``s``, ``h`` the station spacing; counted per station instead, a line
   running wide would get its longer path for free) subject to
   ``-w_right_k + w_veh/2 + margin <= n_k <= w_left_k - w_veh/2 - margin``.
   The curvature ``kappa = (x' y'' - y' x'') / (x'^2 + y'^2)^(3/2)`` of the path
   ``r_k = c_k + n_k N_k`` is linearised in ``n``: the first derivatives ``x', y'`` and the
   denominator (and the path weight ``|r_k'|``) are frozen at the current iterate, the second derivatives are linear in ``n``
   through periodic finite-difference matrices. Each linearisation is a box-constrained
   least-squares problem (a convex QP) solved by a primal-dual active-set method (sparse
   direct solves; OSQP and DAQP through CasADi as fallbacks).
   (``RacelineConfig.linearization="exact"`` uses the full Jacobian instead, see there.) The
   line is re-linearised until the QP solution moves the offsets by less than
   ``RacelineConfig.tol`` [m] (at most ``max_iter`` times, otherwise a
   :class:`RacelineConvergenceWarning`; the exact scheme also stops once the true cost no
   longer decreases by more than 1e-6 relative); where the frozen iteration stops contracting (it can cycle at
   a tight hairpin) the update is under-relaxed. The offsets are then
   interpolated back (periodic cubic spline, clipped to the bounds) to every track grid point.

2. **Speed profile** ``vx(s)`` along the line for the car's g-g-v envelope scaled by ``mu``
   (:mod:`racing_env.envelope`; ``mu = 1`` is the car's own limit: the steering bound, the
   Pacejka tyres and the speed-dependent motor force), by forward (drive) and backward
   (braking) passes repeated around the closed lap until nothing changes:

   * ``vx <=`` the envelope's quasi-steady corner speed of ``kappa`` (:func:`speed_limit`)
     and ``vx <= vehicle.top_speed``;
   * drive ``<= mu ax_max(v, v^2 |kappa|)``, negative in fast corners where the motor cannot
     hold the speed, and braking ``<= -mu ax_min(v, v^2 |kappa|)`` (:func:`accel_limits`).

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

from numba import njit

from .cache import sources_hash
from .envelope import envelope_at, ggv
from .track import Track
from .vehicle import VehicleParams

G = 9.81
"""Gravitational acceleration [m/s^2]."""

CACHE_VERSION = 4
"""Bumped when the saved file's layout changes (invalidates old cache files). An edit of the
code that computes a line needs no bump: the cache key hashes :data:`SOURCES`."""

CSV_COLUMNS = ("s_m", "x_m", "y_m", "psi_rad", "kappa_radpm", "vx_mps", "ax_mps2", "n_m",
               "s_track_m")
"""Column names (with units) of :meth:`Raceline.to_csv`."""


class RacelineConvergenceWarning(RuntimeWarning):
    """The minimum-curvature iteration stopped at ``max_iter`` before meeting ``tol``."""


# ====================================================================== configuration
TOL_PER_WIDTH = 2e-4
"""Default stopping tolerance of the minimum-curvature iteration, per metre of track width."""

OBJECTIVES = ("curvature", "lap_time")
"""Racing-line objectives of :class:`RacelineConfig` (``objective``)."""

LENGTH_WEIGHTS = (0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
"""Grid of ``length_weight`` values that ``objective="lap_time"`` tries before refining the
best one (:func:`lap_time_weight_search`)."""


@dataclass(frozen=True)
class RacelineConfig:
    """Settings of the racing line (all hashed into the cache key).

    * ``margin`` [m]: clearance kept from each track edge beyond half the car's width
      (the paper uses 0; a little room absorbs tracking errors of the controllers).
    * ``mu_min``, ``mu_max`` [-], ``n_mu``: the speed library covers ``n_mu`` evenly spaced
      scales of the car's g-g-v envelope in ``[mu_min, mu_max]`` (plus ``mu_nominal``).
    * ``mu_nominal`` [-]: the profile returned when no ``mu`` is given. Default 1: the car's
      own envelope (alone, the MPC at zeta = 1 laps within about 2% of its estimate with no
      off-track step; ``benchmarks/solo_laps.py``).
    * ``point_spacing`` [m]: target spacing of the optimisation stations (the result is
      interpolated back to the track grid).
    * ``tol`` [m]: stop re-linearising once no offset moves by more than this; ``None`` (the
      default) scales it with the track: ``TOL_PER_WIDTH`` (2e-4) of its mean width, 1e-4 m on
      the 0.5 m wide built-in tracks, about 2.5 mm on a full-scale 12 m circuit.
    * ``max_iter``: most re-linearisations.
    * ``smoothing`` [-]: weight of a tiny regulariser ``sum (dn/ds)^2 / L^2`` that makes the
      QP strictly convex where curvature does not pin the line (long straights).
    * ``linearization``: ``"frozen"`` (default; the paper's / TUM's scheme: first derivatives
      fixed at the current iterate) or ``"exact"`` (full Jacobian, Gauss-Newton with a line
      search on the true cost). The frozen scheme ignores that moving outwards lengthens the
      path, so its fixed point is biased towards the inside of corners: it is *not* the exact
      minimiser of ``sum kappa^2`` (on a plain circle it hugs the inner edge, whose curvature is
      higher than the centre line's), but the bias shortens the lap, and its lap times are as
      good or better on most tracks we tried (point-mass profile at 0.85 g, before the
      envelope: default 9.98 s vs 10.41 s, Monza 34.19 s vs 34.10 s, Norisring 14.82 s vs
      15.04 s).
      ``"exact"`` gives the true (local) minimum-curvature line.
    * ``objective``: ``"curvature"`` (default; the paper's minimum-curvature line) or
      ``"lap_time"``: the line that adds ``length_weight`` times the path length term (below)
      to the curvature cost, with the weight searched per track for the shortest lap
      estimate at ``mu_nominal`` (:func:`lap_time_weight_search`). A shorter path pays where
      the motor, not the tyres, limits the speed: above about 2.2 m/s this car cannot hold its
      lateral limit, so on tracks of long fast corners the minimum-curvature line is not the
      fastest. Never slower (in estimate) than the minimum-curvature line, which is the
      weight 0 of the search.
    * ``length_weight`` [-]: with ``objective="curvature"``, a fixed weight ``w`` of the
      shortest-path term ``(w / W^2) sum_k |p_{k+1} - p_k|^2 / h`` (``W`` the track's mean
      width, ``h`` the station spacing; ``sum |dp|^2 / h`` is the path length for even
      stations, and ``1 / W^2`` makes ``w`` the same on a 1:43 track and a full-scale one);
      0 (default) is the pure minimum-curvature line. Ignored by ``"lap_time"``, which
      searches it.
    """

    margin: float = 0.01
    mu_min: float = 0.5
    mu_max: float = 1.0
    n_mu: int = 11
    mu_nominal: float = 1.0
    point_spacing: float = 0.05
    tol: float | None = None
    max_iter: int = 100
    smoothing: float = 1e-6
    linearization: str = "frozen"
    objective: str = "curvature"
    length_weight: float = 0.0

    def __post_init__(self):
        if self.linearization not in ("frozen", "exact"):
            raise ValueError(f"RacelineConfig.linearization must be 'frozen' or 'exact', "
                             f"got {self.linearization!r}")
        if self.objective not in OBJECTIVES:
            raise ValueError(f"RacelineConfig.objective must be one of {OBJECTIVES}, "
                             f"got {self.objective!r}")
        for f in fields(self):
            if f.name in ("linearization", "objective") or (f.name == "tol" and self.tol is None):
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"RacelineConfig.{f.name} must be a finite number, got {v!r}")
        for name in ("n_mu", "max_iter"):
            v = getattr(self, name)
            if int(v) != v or v < (2 if name == "n_mu" else 1):
                raise ValueError(f"RacelineConfig.{name} must be an integer >= "
                                 f"{2 if name == 'n_mu' else 1}, got {v!r}")
        for name in ("mu_min", "mu_max", "mu_nominal", "point_spacing", "tol"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise ValueError(f"RacelineConfig.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("margin", "smoothing", "length_weight"):
            if getattr(self, name) < 0:
                raise ValueError(f"RacelineConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if not self.mu_min < self.mu_max:
            raise ValueError(f"RacelineConfig needs mu_min < mu_max, got mu_min={self.mu_min!r}, "
                             f"mu_max={self.mu_max!r}")
        if not self.mu_min <= self.mu_nominal <= self.mu_max:
            raise ValueError(f"RacelineConfig.mu_nominal={self.mu_nominal!r} is outside "
                             f"[mu_min, mu_max] = [{self.mu_min}, {self.mu_max}]")

    def tol_for(self, track: Track) -> float:
        """The stopping tolerance [m] on ``track``: ``tol``, or ``TOL_PER_WIDTH`` times the
        track's mean width when ``tol`` is None."""
        if self.tol is not None:
            return float(self.tol)
        return TOL_PER_WIDTH * float(np.mean(track.width))

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


def _to_casadi(sp_matrix, pattern=None):
    """scipy sparse -> casadi DM, on ``pattern`` (a csc matrix) when given."""
    import casadi
    pat = sparse.csc_matrix(sp_matrix if pattern is None else pattern)
    pat.sort_indices()
    sp = casadi.Sparsity(pat.shape[0], pat.shape[1], pat.indptr.tolist(), pat.indices.tolist())
    if pattern is None:
        vals = pat.data
    else:
        rows = pat.indices
        cols = np.repeat(np.arange(pat.shape[1]), np.diff(pat.indptr))
        vals = np.asarray(sparse.csr_matrix(sp_matrix)[rows, cols]).ravel()
    return casadi.DM(sp, vals)


class _BoxQP:
    """``min 1/2 x' H x + g' x  s.t.  lo <= x <= hi`` for a fixed sparsity pattern of ``H``.

    A primal-dual active-set method (:func:`box_qp_active_set`: sparse direct solves on the
    free offsets, exact to rounding) first; OSQP (through CasADi's ``conic``, polished) if it
    does not settle, DAQP (an exact dual active-set solver) if OSQP does not report success.
    Warm-started (every iteration after the first two or so) the active-set method settles in
    a few sparse solves. The curvature Hessians are banded and very badly conditioned (a
    squared second difference: a condition number growing like ``N^4``); from a cold start
    its active sets can cycle, and OSQP then pays for the conditioning too (at 2,900 stations
    its first solve ends "solved inaccurate" after 20,000 iterations).
    """

    def __init__(self, pattern, lo, hi):
        self.pattern = sparse.csc_matrix(pattern)
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self._osqp = self._daqp = None
        self._lam = None

    def _conic(self, name, plugin, opts):
        import casadi
        nvar = self.pattern.shape[0]
        prob = {"h": _to_casadi(self.pattern).sparsity(), "a": casadi.Sparsity(0, nvar)}
        return casadi.conic(name, plugin, prob, {"error_on_fail": False, **opts})

    def solve(self, h, g, x0=None):
        """Minimiser, shape (n,), clipped to the bounds; raises RuntimeError if every solver fails."""
        g = np.asarray(g, float)
        x = box_qp_active_set(h, g, self.lo, self.hi, x0)
        if x is not None:
            return x
        hdm = _to_casadi(h, self.pattern)
        args = dict(h=hdm, g=g, lbx=self.lo, ubx=self.hi)
        if x0 is not None:
            args["x0"] = x0
        if self._lam is not None:
            args["lam_x0"] = self._lam
        if self._osqp is None:
            self._osqp = self._conic("raceline_osqp", "osqp", {"osqp": {
                "eps_abs": 1e-7, "eps_rel": 1e-7, "max_iter": 20000, "polish": True,
                "verbose": False}})
        res = self._osqp(**args)
        if not self._osqp.stats().get("success", False):
            if self._daqp is None:
                self._daqp = self._conic("raceline_daqp", "daqp", {})
            res = self._daqp(**args)
            if not self._daqp.stats().get("success", False):
                raise RuntimeError("racing-line QP failed in the active-set method, OSQP and DAQP: "
                                   f"{self._osqp.stats().get('return_status')}, "
                                   f"{self._daqp.stats().get('return_status')}")
        x = np.asarray(res["x"], dtype=float).ravel()
        self._lam = np.asarray(res["lam_x"], dtype=float).ravel()
        if not np.all(np.isfinite(x)):
            raise RuntimeError("racing-line QP returned non-finite offsets")
        return np.clip(x, self.lo, self.hi)


def box_qp_active_set(h, g, lo, hi, x0=None, max_iter: int = 30):
    """``argmin 1/2 x' H x + g' x`` over ``lo <= x <= hi`` by the primal-dual active-set
    method (Hintermueller, Ito and Kunisch 2002), ``H`` sparse symmetric positive definite,
    shapes (n, n), (n,), (n,), (n,). Each iteration fixes at a bound every ``x_i`` whose
    projected step ``x_i - c (H x + g)_i`` leaves the box (``c`` scales the gradient to the
    offsets), solves ``H_FF x_F = -(g_F + H_FA x_A)`` on the free set ``F`` (sparse LU) and
    stops once the sets repeat. ``None`` if they do not settle in ``max_iter`` iterations or a
    solve is not finite (the caller falls back to a general QP solver)."""
    from scipy.sparse.linalg import splu
    h = sparse.csc_matrix(h)
    n = len(g)
    x = np.clip(np.zeros(n) if x0 is None else np.asarray(x0, float), lo, hi)
    c = 1.0 / max(float(np.abs(h.diagonal()).max()), 1e-300)
    at_lo = at_hi = None
    for _ in range(int(max_iter)):
        grad = h @ x + g
        step = x - c * grad
        new_lo, new_hi = step < lo, step > hi
        if at_lo is not None and np.array_equal(new_lo, at_lo) and np.array_equal(new_hi, at_hi):
            return np.clip(x, lo, hi)
        at_lo, at_hi = new_lo, new_hi
        free = ~(at_lo | at_hi)
        x = np.where(at_lo, lo, np.where(at_hi, hi, x))
        if free.any():
            fi = np.flatnonzero(free)
            rhs = -(g[fi] + h[fi][:, ~free] @ x[~free])
            try:
                x[fi] = splu(h[fi][:, fi].tocsc()).solve(rhs)
            except RuntimeError:                      # singular: let a general solver try
                return None
            if not np.all(np.isfinite(x)):
                return None
    return None


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
                              config: RacelineConfig | None = None,
                              length_weight: float | None = None, n_init=None):
    """Solve the minimum-curvature problem on ``N`` uniform centre-line stations.

    ``length_weight`` (default ``config.length_weight``) adds the shortest-path term
    ``(w / W^2) sum_k |p_{k+1} - p_k|^2 / h`` (see :class:`RacelineConfig`), which is exactly
    quadratic in the offsets; ``n_init`` (N,) [m] starts the iteration there instead of on
    the centre line.

    Returns ``(s_sub, n_sub, info)``: stations [m] shape (N,), offsets [m] shape (N,), and a
    dict with ``iterations``, ``converged``, ``last_change`` [m], ``tol`` [m], ``cost`` and
    ``cost_center`` (the integral of kappa^2 over the path [1/m], of the line and of the centre
    line, on the stations).
    """
    vehicle = vehicle or VehicleParams()
    config = config or RacelineConfig()
    w_len = config.length_weight if length_weight is None else float(length_weight)
    if not (math.isfinite(w_len) and w_len >= 0):
        raise ValueError(f"length_weight must be a finite number >= 0, got {length_weight!r}")
    m_grid = len(track.s_grid)
    n_pts = int(min(m_grid, max(16, math.ceil(track.length / config.point_spacing))))
    h = track.length / n_pts
    s_sub = np.arange(n_pts) * h
    cx, cy = track.position(s_sub)
    psi = track.heading(s_sub)
    nx, ny = -np.sin(psi), np.cos(psi)
    lo, hi = offset_bounds(track, s_sub, vehicle, config.margin)
    d1, d2 = _periodic_diff_matrices(n_pts, h)
    d2nx, d2ny = d2 @ sparse.diags(nx), d2 @ sparse.diags(ny)

    def kappa_of(n):
        px, py = cx + n * nx, cy + n * ny
        dx, dy = d1 @ px, d1 @ py
        return (dx * (d2 @ py) - dy * (d2 @ px)) / np.hypot(dx, dy) ** 3

    qp = _BoxQP(sparse.csc_matrix(abs(d2).T @ abs(d2) + abs(d1).T @ abs(d1)), lo, hi)
    reg = (config.smoothing / track.length ** 2) * (d1.T @ d1)
    exact = config.linearization == "exact"
    d1nx, d1ny = (d1 @ sparse.diags(nx), d1 @ sparse.diags(ny)) if exact else (None, None)

    def path_weight(n):
        """Path length per unit of centre-line s at each station [-]: ``|dp/ds|``."""
        px, py = cx + n * nx, cy + n * ny
        return np.hypot(d1 @ px, d1 @ py)

    h_len = g_len = None
    if w_len > 0:
        # shortest path: residuals sqrt(w) / (W h) (p_{k+1} - p_k), linear in n: A n + b. The
        # curvature residuals above sum to (1 / h) int kappa^2 dl, so this term sums to
        # (1 / h) (w / W^2) sum |dp|^2 / h: the weight does not depend on the station spacing
        scale = math.sqrt(w_len) / (h * float(np.mean(track.width)))
        fwd = sparse.diags([-np.ones(n_pts), np.ones(n_pts - 1), np.ones(1)],
                           [0, 1, -(n_pts - 1)], format="csr")
        a_len = scale * sparse.vstack([fwd @ sparse.diags(nx), fwd @ sparse.diags(ny)]).tocsr()
        b_len = scale * np.concatenate([fwd @ cx, fwd @ cy])
        h_len, g_len = a_len.T @ a_len, a_len.T @ b_len

    def cost(n):
        extra = 0.0 if h_len is None else float(np.sum((a_len @ n + b_len) ** 2))
        return float(np.sum(kappa_of(n) ** 2 * path_weight(n)) + n @ (reg @ n)) + extra

    tol = config.tol_for(track)
    n = np.clip(np.zeros(n_pts) if n_init is None else np.asarray(n_init, dtype=float), lo, hi)
    converged, change, prev_change, alpha, it = False, np.inf, np.inf, 1.0, 0
    for it in range(1, int(config.max_iter) + 1):
        px, py = cx + n * nx, cy + n * ny
        dx, dy = d1 @ px, d1 @ py
        ddx, ddy = d2 @ px, d2 @ py
        q = dx * dx + dy * dy
        den = q ** 1.5
        kap = (dx * ddy - dy * ddx) / den
        # the objective is sum kappa^2 |dp/ds| h: curvature per metre of *path*, not per station
        # (per station, a wider line's longer path would be free); residual r = sqrt|dp/ds| kappa
        rw = q ** 0.25
        # kappa(n') ~ kap + a (n' - n): second derivatives exact in n', first derivatives frozen
        a = sparse.diags(dx / den) @ d2ny - sparse.diags(dy / den) @ d2nx
        if exact:   # ... plus the first derivatives' terms: the full Jacobian (Gauss-Newton)
            a = a + sparse.diags(ddy / den - 3.0 * kap * dx / q) @ d1nx \
                  - sparse.diags(ddx / den + 3.0 * kap * dy / q) @ d1ny
            # and the path weight's own derivative, d(q^1/4) = q^-3/4 (dx d1nx + dy d1ny) / 2
            jr = sparse.diags(rw) @ a + sparse.diags(0.5 * kap * q ** -0.75) @ (
                sparse.diags(dx) @ d1nx + sparse.diags(dy) @ d1ny)
        else:       # frozen: the path weight too is fixed at the current iterate
            jr = sparse.diags(rw) @ a
        r = rw * kap
        hess, grad = jr.T @ jr + reg, jr.T @ (r - jr @ n)
        if h_len is not None:
            hess, grad = hess + h_len, grad + g_len
        n_new = qp.solve(hess, grad, x0=n)
        change = float(np.max(np.abs(n_new - n)))     # fixed-point residual [m]
        if change < tol:
            n = n_new
            converged = True
            break
        if exact:                                     # backtrack on the true cost
            f0, alpha = cost(n), 1.0
            f1 = cost(n_new)
            while f1 > f0 and alpha > 1e-3:
                alpha *= 0.5
                f1 = cost(n + alpha * (n_new - n))
            if f1 >= f0 - 1e-6 * abs(f0):             # no more progress: a stationary point
                if f1 < f0:                           # (Gauss-Newton creeps along flat valleys)
                    n = np.clip(n + alpha * (n_new - n), lo, hi)
                converged = True
                break
        elif change >= prev_change:                   # not contracting (a limit cycle at a
            alpha = max(0.5 * alpha, 0.1)             # tight hairpin): under-relax the update
        prev_change = change
        n = np.clip(n + alpha * (n_new - n), lo, hi)
    if not converged:
        warnings.warn(f"minimum-curvature racing line on track '{track.name}' did not converge in "
                      f"max_iter={config.max_iter} iterations (last offset change {change:.2e} m > "
                      f"tol {tol:.2e} m); using the last iterate",
                      RacelineConvergenceWarning, stacklevel=2)
    zero = np.zeros(n_pts)
    info = dict(iterations=it, converged=converged, last_change=change, tol=tol,
                cost=float(np.sum(kappa_of(n) ** 2 * path_weight(n)) * h),
                cost_center=float(np.sum(kappa_of(zero) ** 2 * path_weight(zero)) * h))
    return s_sub, n, info


# ====================================================================== speed profile
def accel_limits(v, kappa, mu: float, vehicle: VehicleParams | None = None):
    """Largest acceleration and deceleration [m/s^2] (deceleration >= 0) at speed ``v`` [m/s]
    on a path of curvature ``kappa`` [1/m] for the car's g-g-v envelope scaled by ``mu``
    (:mod:`racing_env.envelope`); arrays broadcast.

    ``a_acc = mu ax_max(v, v^2 |kappa|)`` is the drive acceleration on top of that corner: it is
    *negative* where the motor cannot hold the speed in the corner (the car slows through it).
    ``a_brk = -mu ax_min(v, v^2 |kappa|)``. A lateral demand beyond the envelope counts as at it.
    """
    env = ggv(vehicle or VehicleParams())
    v = np.asarray(v, dtype=float)
    hi, lo = env.longitudinal_limits(v, v * v * np.abs(np.asarray(kappa, dtype=float)), mu)
    return hi, np.maximum(-lo, 0.0)


def speed_limit(kappa, mu: float, vehicle: VehicleParams | None = None):
    """Quasi-steady speed cap [m/s] of curvature ``kappa`` [1/m] (any shape): the highest speed
    at which the envelope scaled by ``mu`` holds ``v^2 |kappa|`` (the steering bound at low
    speed, the tyres above), and never above the top speed (:meth:`GGV.corner_speed`)."""
    return ggv(vehicle or VehicleParams()).corner_speed(kappa, mu)


def speed_profile(kappa, ds, mu: float, vehicle: VehicleParams | None = None, max_sweeps: int = 50):
    """Periodic speed profile ``(vx, ax)`` [m/s], [m/s^2] on a closed path, shapes (M,).

    ``kappa`` [1/m] at the M points, ``ds[k]`` [m] the distance from point k to point k+1
    (the last one closes the lap); ``mu`` scales the car's g-g-v envelope
    (:func:`racing_env.envelope.ggv`; 1 = the car's own limit). Starts from
    :func:`speed_limit` and repeats a forward (drive) and a backward (braking) pass around the
    lap until no speed changes; the result satisfies
    ``v[k+1]^2 - v[k]^2 <= 2 ds[k] a_acc(v[k], kappa[k])`` and
    ``v[k]^2 - v[k+1]^2 <= 2 ds[k] a_brk(v[k+1], kappa[k+1])`` (indices mod M, see
    :func:`accel_limits`; ``a_acc`` may be negative in fast corners, where the car slows).
    ``ax[k] = (v[k+1]^2 - v[k]^2) / (2 ds[k])`` is the acceleration on segment k.
    """
    p = vehicle or VehicleParams()
    kappa = np.asarray(kappa, dtype=float)
    ds = np.asarray(ds, dtype=float)
    if kappa.shape != ds.shape or kappa.ndim != 1 or len(kappa) < 2:
        raise ValueError(f"speed_profile needs kappa and ds of equal 1-D shape, got {kappa.shape}, {ds.shape}")
    if not (np.all(np.isfinite(kappa)) and np.all(np.isfinite(ds)) and np.all(ds > 0)):
        raise ValueError("speed_profile needs finite kappa and finite positive ds")
    if not (math.isfinite(mu) and 0 < mu <= 1.5):
        raise ValueError(f"envelope scale mu must be in (0, 1.5], got {mu!r}")
    env = ggv(p)
    v2 = speed_limit(kappa, mu, p) ** 2
    v_tab, ay_tab, r_tab, axp_tab, axm_tab = env.tables(mu)
    ok = _profile_sweeps(v2, np.abs(kappa), ds, v_tab, ay_tab, r_tab, axp_tab, axm_tab,
                         int(np.argmin(v2)), int(max_sweeps))
    if not ok:
        raise RuntimeError(f"speed profile did not settle in {max_sweeps} sweeps")
    vx = np.sqrt(v2)
    ax = (np.roll(v2, -1) - v2) / (2.0 * ds)
    return vx, ax


@njit(cache=True)
def _profile_sweeps(v2, kab, ds, v_tab, ay_tab, r_tab, axp_tab, axm_tab, start, max_sweeps):
    """Forward/backward passes of :func:`speed_profile` on ``v2`` (squared speeds, in place);
    False if they did not settle in ``max_sweeps``."""
    m = v2.shape[0]
    for _ in range(max_sweeps):
        changed = False
        for j in range(m):                                   # forward: drive
            k = (start + j) % m
            k1 = k + 1 if k + 1 < m else 0
            vk2 = v2[k]
            vk = math.sqrt(vk2)
            a = envelope_at(vk, vk2 * kab[k], v_tab, ay_tab, r_tab, axp_tab)
            cand = max(vk2 + 2.0 * ds[k] * a, 0.0)
            if cand < v2[k1] * (1.0 - 1e-12):
                v2[k1] = cand
                changed = True
        for j in range(m):                                   # backward: braking
            k1 = (start - j) % m
            k = k1 - 1 if k1 > 0 else m - 1
            vk2 = v2[k1]
            vk = math.sqrt(vk2)
            a = -envelope_at(vk, vk2 * kab[k1], v_tab, ay_tab, r_tab, axm_tab)
            cand = vk2 + 2.0 * ds[k] * max(a, 0.0)
            if cand < v2[k] * (1.0 - 1e-12):
                v2[k] = cand
                changed = True
        if not changed:
            return True
    return False


def lap_time_of(vx, ds) -> float:
    """Lap time [s] of a periodic profile: ``sum 2 ds[k] / (v[k] + v[k+1])``."""
    vx = np.asarray(vx, dtype=float)
    return float(np.sum(2.0 * np.asarray(ds) / np.maximum(vx + np.roll(vx, -1), 1e-12)))


# ====================================================================== the result
_ARRAYS = ("s", "x", "y", "psi", "kappa", "vx", "ax", "n", "s_track", "n_lo", "n_hi", "mus",
           "vx_lib", "ax_lib")
_SCALARS = ("length", "track_length", "mu_nominal", "lap_time", "iterations", "converged",
            "last_change", "cost", "cost_center", "compute_time", "length_weight")


@dataclass(eq=False)
class Raceline:
    """A racing line with its speed library. Per-point arrays have shape (M,), one entry per
    grid point of the track (``s_track == track.s_grid``), in driving order:

    * ``s`` [m] arc length along the racing line (``s[0] = 0``), ``length`` [m] its lap length;
    * ``x, y`` [m] position, ``psi`` [rad] heading (unwrapped), ``kappa`` [1/m] curvature
      (left turn positive);
    * ``vx`` [m/s] speed and ``ax`` [m/s^2] acceleration of the nominal profile
      (``mu = mu_nominal``); ``ax[k]`` is the constant acceleration from point k to k+1;
    * ``n`` [m] lateral offset from the centre line (left positive), ``s_track`` [m] centre-line
      arc length of each point, ``n_lo, n_hi`` [m] the target bounds of the offsets (edges minus half the car and the margin; the interpolated line may enter the margin by spline overshoot, well under 1 mm);
    * ``mus`` (K,) envelope scales of the library, ``vx_lib, ax_lib`` (K, M) their profiles.

    Scalars: ``track_length`` [m] (centre line), ``lap_time`` [s] of the nominal profile,
    ``iterations`` / ``converged`` / ``last_change`` [m] of the minimum-curvature iteration,
    ``cost`` / ``cost_center`` the integral of kappa^2 along the path [1/m] of line / centre
    line on the optimisation stations, ``compute_time`` [s]. ``from_cache`` tells whether it was loaded.
    """

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    psi: np.ndarray
    kappa: np.ndarray
    vx: np.ndarray
    ax: np.ndarray
    n: np.ndarray
    s_track: np.ndarray
    n_lo: np.ndarray
    n_hi: np.ndarray
    mus: np.ndarray
    vx_lib: np.ndarray
    ax_lib: np.ndarray
    length: float
    track_length: float
    mu_nominal: float
    lap_time: float
    iterations: int
    converged: bool
    last_change: float
    cost: float
    cost_center: float
    compute_time: float
    length_weight: float = 0.0
    track_name: str = ""
    track_fingerprint: str = ""
    key: str = ""
    from_cache: bool = False
    track: Track | None = field(default=None, repr=False)

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise ``ValueError`` if any array is non-finite or shapes disagree."""
        m = len(self.s)
        for name in _ARRAYS:
            a = getattr(self, name)
            if not np.all(np.isfinite(a)):
                raise ValueError(f"raceline {name} has non-finite values")
            want = (len(self.mus), m) if name in ("vx_lib", "ax_lib") else \
                (len(self.mus),) if name == "mus" else (m,)
            if a.shape != want:
                raise ValueError(f"raceline {name} has shape {a.shape}, expected {want}")
        for name in _SCALARS:
            if not math.isfinite(float(getattr(self, name))):
                raise ValueError(f"raceline {name} is not finite: {getattr(self, name)!r}")
        if m < 2 or np.any(np.diff(self.s) <= 0) or self.length <= self.s[-1]:
            raise ValueError("raceline arc length s is not increasing")
        if np.any(self.vx <= 0) or np.any(self.vx_lib <= 0) or np.any(np.diff(self.mus) <= 0):
            raise ValueError("raceline speeds must be positive and mus increasing")

    # ------------------------------------------------------------------ lookups
    @property
    def ds(self) -> np.ndarray:
        """Segment lengths [m] along the racing line, shape (M,): ``ds[k] = s[k+1] - s[k]``."""
        return np.diff(np.append(self.s, self.length))

    def _interp(self, table: np.ndarray, s_track):
        """Periodic linear interpolation of a per-point table at (unwrapped) centre-line s."""
        m = len(self.s_track)
        f = np.mod(np.asarray(s_track, dtype=float), self.track_length) * (m / self.track_length)
        r = np.rint(f)
        f = np.where(np.abs(f - r) < 1e-9, r, f)          # grid points hit their entry exactly
        fl = np.floor(f)
        i0 = fl.astype(np.int64) % m
        t = f - fl
        return table[..., i0] * (1.0 - t) + table[..., (i0 + 1) % m] * t

    def offset_at(self, s_track):
        """Racing-line offset ``n`` [m] (left positive) at centre-line arc length ``s_track`` [m]
        (any shape, unwrapped allowed); same shape as ``s_track``."""
        return self._interp(self.n, s_track)

    def _check_mu(self, mu) -> float:
        mu_f = float(mu)
        lo, hi = float(self.mus[0]), float(self.mus[-1])
        if not (math.isfinite(mu_f) and lo - 1e-12 <= mu_f <= hi + 1e-12):
            raise ValueError(f"friction mu={mu!r} is outside the speed library range "
                             f"[{lo}, {hi}]")
        return min(max(mu_f, lo), hi)

    def profile(self, mu=None):
        """``(vx, ax)`` per point [m/s], [m/s^2] for envelope scale ``mu`` (default ``mu_nominal``),
        linearly interpolated between the library's neighbouring profiles; shapes (M,)."""
        if mu is None:
            return self.vx, self.ax
        mu = self._check_mu(mu)
        hit = np.flatnonzero(np.abs(self.mus - mu) <= 1e-12)
        if hit.size:                                   # a library entry: exactly its profile
            return self.vx_lib[hit[0]], self.ax_lib[hit[0]]
        j = int(np.clip(np.searchsorted(self.mus, mu, side="right") - 1, 0, len(self.mus) - 2))
        w = (mu - self.mus[j]) / (self.mus[j + 1] - self.mus[j])
        vx = (1.0 - w) * self.vx_lib[j] + w * self.vx_lib[j + 1]
        ax = (1.0 - w) * self.ax_lib[j] + w * self.ax_lib[j + 1]
        return vx, ax

    def speed_at(self, s_track, mu=None):
        """Reference speed ``vx`` [m/s] at centre-line ``s_track`` [m] (any shape, unwrapped
        allowed) for envelope scale ``mu`` (scalar in ``[mus[0], mus[-1]]``, default ``mu_nominal``).
        Raises ``ValueError`` for a ``mu`` outside the library range."""
        return self._interp(self.profile(mu)[0], s_track)

    def accel_at(self, s_track, mu=None):
        """Reference acceleration ``ax`` [m/s^2] at centre-line ``s_track`` (like :meth:`speed_at`)."""
        return self._interp(self.profile(mu)[1], s_track)

    def heading_at(self, s_track):
        """Racing-line heading ``psi`` [rad], wrapped to (-pi, pi], at centre-line ``s_track`` [m]."""
        c = self._interp(np.cos(self.psi), s_track)
        sn = self._interp(np.sin(self.psi), s_track)
        return np.arctan2(sn, c)

    def kappa_at(self, s_track):
        """Racing-line curvature ``kappa`` [1/m] at centre-line ``s_track`` [m]."""
        return self._interp(self.kappa, s_track)

    def s_line_at(self, s_track):
        """Arc length along the racing line [m] at centre-line ``s_track`` [m], unwrapped the
        same way (``s_track + k * track_length`` maps to ``... + k * length``)."""
        s_track = np.asarray(s_track, dtype=float)
        lap = np.floor(s_track / self.track_length)
        s_ext = np.append(self.s, self.length)
        st_ext = np.append(self.s_track, self.track_length)
        return lap * self.length + np.interp(s_track - lap * self.track_length, st_ext, s_ext)

    def lap_time_at(self, mu=None) -> float:
        """Lap time [s] of the profile for ``mu`` (default ``mu_nominal``)."""
        return lap_time_of(self.profile(mu)[0], self.ds)

    # ------------------------------------------------------------------ output
    def to_csv(self, path) -> Path:
        """Write the nominal racing line as CSV (columns :data:`CSV_COLUMNS`, units in the names:
        ``_m`` metres, ``_rad`` radians, ``_radpm`` 1/m, ``_mps`` m/s, ``_mps2`` m/s^2)."""
        path = Path(path)
        data = np.column_stack([self.s, self.x, self.y, self.psi, self.kappa, self.vx, self.ax,
                                self.n, self.s_track])
        if not np.all(np.isfinite(data)):
            raise ValueError("refusing to write a racing line with non-finite values")
        header = (f"racing line of track '{self.track_name}' ({self.track_fingerprint}), "
                  f"mu = {self.mu_nominal}, length {self.length:.4f} m, lap time {self.lap_time:.4f} s\n"
                  + ",".join(CSV_COLUMNS))
        np.savetxt(path, data, delimiter=",", header=header, fmt="%.9g")
        return path

    def plot(self, path, track: Track | None = None, mu=None) -> Path:
        """Write a PNG of the track edges, centre line and racing line coloured by speed."""
        return plot_raceline(track if track is not None else self.track, self, path, mu=mu)

    def to_npz_dict(self) -> dict:
        """Arrays and metadata for :func:`numpy.savez` (no objects, loadable without pickle)."""
        d = {name: np.asarray(getattr(self, name), dtype=float) for name in _ARRAYS}
        for name in _SCALARS:
            d[name] = np.asarray(float(getattr(self, name)))
        meta = dict(track_name=self.track_name, track_fingerprint=self.track_fingerprint,
                    key=self.key, version=CACHE_VERSION)
        d["meta"] = np.asarray(json.dumps(meta))
        return d

    @classmethod
    def from_npz_dict(cls, d) -> "Raceline":
        """Inverse of :meth:`to_npz_dict`; raises ``ValueError``/``KeyError`` on bad content."""
        meta = json.loads(str(d["meta"][()]))
        kw = {name: np.array(d[name], dtype=float) for name in _ARRAYS}
        for name in _SCALARS:
            kw[name] = float(d[name][()])
        kw["iterations"] = int(kw["iterations"])
        kw["converged"] = bool(kw["converged"])
        rl = cls(**kw, track_name=str(meta["track_name"]),
                 track_fingerprint=str(meta["track_fingerprint"]), key=str(meta["key"]))
        rl._meta_version = meta.get("version")
        rl.validate()
        return rl

    def __repr__(self) -> str:
        return (f"Raceline(track={self.track_name!r}, points={len(self.s)}, length={self.length:.3f} m, "
                f"lap_time={self.lap_time:.3f} s at mu={self.mu_nominal}, "
                f"v {self.vx.min():.2f}..{self.vx.max():.2f} m/s, iterations={self.iterations}, "
                f"converged={self.converged})")


# ====================================================================== computation
def _line_geometry(px, py):
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


def _line_on_grid(track: Track, vehicle: VehicleParams, config: RacelineConfig, s_sub, n_sub,
                  with_lap: bool = True):
    """The line through offsets ``n_sub`` [m] at stations ``s_sub`` [m], on the track grid:
    a dict of ``n``, ``n_lo``, ``n_hi`` (the target bounds), ``x``, ``y``, ``s``, ``length``,
    ``psi``, ``kappa``, ``ds`` and (with ``with_lap``) the lap estimate ``lap_time`` [s] of its
    profile at ``mu_nominal``."""
    s_track = np.asarray(track.s_grid, dtype=float)
    n_lo, n_hi = offset_bounds(track, s_track, vehicle, config.margin)
    spn = CubicSpline(np.append(s_sub, track.length), np.append(n_sub, n_sub[0]), bc_type="periodic")
    # Clip only at the physical bounds (edge minus half the car): a cubic spline through the
    # stations overshoots the target bounds by fractions of a millimetre, which the margin
    # absorbs; clipping at the target bounds would put kinks (curvature spikes) in the line.
    n = np.clip(spn(s_track), n_lo - config.margin, n_hi + config.margin)
    px, py = track.to_cartesian(s_track, n)
    s, length, psi, kappa = _line_geometry(np.asarray(px), np.asarray(py))
    ds = np.diff(np.append(s, length))
    line = dict(n=n, n_lo=n_lo, n_hi=n_hi, x=np.asarray(px, float), y=np.asarray(py, float),
                s=s, length=length, psi=psi, kappa=kappa, ds=ds)
    if with_lap:
        line["lap_time"] = lap_time_of(speed_profile(kappa, ds, float(config.mu_nominal), vehicle)[0], ds)
    return line


def lap_time_weight_search(track: Track, vehicle: VehicleParams | None = None,
                           config: RacelineConfig | None = None, refine: int = 6):
    """The ``length_weight`` whose line has the shortest lap estimate at ``mu_nominal``.

    Tries :data:`LENGTH_WEIGHTS` in increasing order (each iteration warm-started from the
    previous weight's offsets), then ``refine`` golden-section steps in ``log w`` between the
    best grid weight's neighbours (none when the best is 0, the minimum-curvature line).
    Returns ``(weight, s_sub, n_sub, info, tried)`` with ``tried`` a list of
    ``(weight, lap estimate [s])`` in the order evaluated.
    """
    vehicle = vehicle or VehicleParams()
    config = config or RacelineConfig()
    tried, best = [], None
    n_prev = None

    def evaluate(w):
        nonlocal best, n_prev
        s_sub, n_sub, info = minimum_curvature_offsets(track, vehicle, config, length_weight=w,
                                                       n_init=n_prev)
        n_prev = n_sub
        lap = _line_on_grid(track, vehicle, config, s_sub, n_sub)["lap_time"]
        tried.append((float(w), lap))
        if best is None or lap < best[0]:
            best = (lap, float(w), s_sub, n_sub, info)
        return lap

    with warnings.catch_warnings():      # a weight's non-converged iterate is only a candidate
        warnings.simplefilter("ignore", RacelineConvergenceWarning)
        laps = [evaluate(w) for w in LENGTH_WEIGHTS]
        i = int(np.argmin(laps))
        if i > 0 and refine > 0:
            lo = math.log(LENGTH_WEIGHTS[i - 1]) if i > 1 else math.log(LENGTH_WEIGHTS[1]) - 1.0
            hi = math.log(LENGTH_WEIGHTS[min(i + 1, len(LENGTH_WEIGHTS) - 1)])
            g = (math.sqrt(5.0) - 1.0) / 2.0
            a, b = hi - g * (hi - lo), lo + g * (hi - lo)
            fa, fb = evaluate(math.exp(a)), evaluate(math.exp(b))
            for _ in range(refine - 2):
                if fa <= fb:
                    hi, b, fb = b, a, fa
                    a = hi - g * (hi - lo)
                    fa = evaluate(math.exp(a))
                else:
                    lo, a, fa = a, b, fb
                    b = lo + g * (hi - lo)
                    fb = evaluate(math.exp(b))
    _, w, s_sub, n_sub, info = best
    if not info["converged"]:
        warnings.warn(f"lap-time racing line on track '{track.name}': the best weight's "
                      f"iteration did not converge (last offset change {info['last_change']:.2e} m "
                      f"> tol {info['tol']:.2e} m); using its last iterate",
                      RacelineConvergenceWarning, stacklevel=2)
    return w, s_sub, n_sub, info, tried


def compute_raceline(track: Track, vehicle: VehicleParams | None = None,
                     config: RacelineConfig | None = None) -> Raceline:
    """Compute (no cache) the racing line of ``config.objective`` and its speed library on
    ``track``."""
    vehicle = vehicle or VehicleParams()
    config = config or RacelineConfig()
    t0 = time.perf_counter()
    if config.objective == "lap_time":
        w, s_sub, n_sub, info, _ = lap_time_weight_search(track, vehicle, config)
    else:
        w = float(config.length_weight)
        s_sub, n_sub, info = minimum_curvature_offsets(track, vehicle, config)
    line = _line_on_grid(track, vehicle, config, s_sub, n_sub, with_lap=False)
    kappa, ds = line["kappa"], line["ds"]
    mus = config.mus
    lib = [speed_profile(kappa, ds, float(mu), vehicle) for mu in mus]
    vx_lib = np.array([v for v, _ in lib])
    ax_lib = np.array([a for _, a in lib])
    j = int(np.argmin(np.abs(mus - config.mu_nominal)))
    rl = Raceline(s=line["s"], x=line["x"], y=line["y"], psi=line["psi"], kappa=kappa,
                  vx=vx_lib[j].copy(), ax=ax_lib[j].copy(), n=line["n"],
                  s_track=np.asarray(track.s_grid, dtype=float), n_lo=line["n_lo"],
                  n_hi=line["n_hi"], mus=mus, vx_lib=vx_lib, ax_lib=ax_lib,
                  length=line["length"], track_length=float(track.length),
                  mu_nominal=float(config.mu_nominal), lap_time=lap_time_of(vx_lib[j], ds),
                  iterations=int(info["iterations"]), converged=bool(info["converged"]),
                  last_change=float(info["last_change"]), cost=info["cost"],
                  cost_center=info["cost_center"], compute_time=time.perf_counter() - t0,
                  length_weight=w, track_name=track.name,
                  track_fingerprint=track.fingerprint(), key=cache_key(track, vehicle, config),
                  track=track)
    rl.validate()
    return rl


# ====================================================================== caching
_MEMO: dict[str, Raceline] = {}


#: the modules whose code computes a racing line (this one, the envelope, the vehicle model and
#: the track geometry): an edit of any of them is a new cache key, so no stale line is loaded
SOURCES = tuple(Path(__file__).with_name(m) for m in ("raceline.py", "envelope.py", "vehicle.py",
                                                      "track.py"))
_SOURCES_HASH = sources_hash(SOURCES)


def cache_key(track: Track, vehicle: VehicleParams, config: RacelineConfig) -> str:
    """Hash [hex, 24 chars] of the track geometry, the vehicle parameters, the config and the
    code that computes the line (:data:`SOURCES`)."""
    blob = json.dumps({"version": CACHE_VERSION, "sources": _SOURCES_HASH,
                       "track": track.fingerprint(), "vehicle": vehicle.to_dict(),
                       "config": asdict(config)}, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:24]


def cache_dir() -> Path:
    """Folder of cached racing lines: ``raceline/`` of the alpha-racer cache folder
    (``$ALPHA_RACER_CACHE``, else the per-user cache; see :mod:`racing_env.cache`)."""
    from .cache import cache_dir as _cache_dir
    return _cache_dir("raceline")


def cache_path(track: Track, vehicle: VehicleParams | None = None,
               config: RacelineConfig | None = None) -> Path:
    """The .npz file :func:`get_raceline` uses for these inputs."""
    key = cache_key(track, vehicle or VehicleParams(), config or RacelineConfig())
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in track.name)[:40]
    return cache_dir() / f"{safe}_{key}.npz"


def _load(path: Path, key: str) -> Raceline | None:
    try:
        with np.load(path, allow_pickle=False) as d:
            rl = Raceline.from_npz_dict(d)
        if rl.key != key or getattr(rl, "_meta_version", None) != CACHE_VERSION:
            return None
        return rl
    except Exception:                # corrupt, truncated, old or foreign file: recompute
        return None


def _save(path: Path, rl: Raceline) -> None:
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.stem + ".", suffix=".tmp.npz", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **rl.to_npz_dict())
        os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        warnings.warn(f"could not write racing-line cache {path}: {exc}", RuntimeWarning, stacklevel=3)
    finally:
        if tmp is not None and os.path.exists(tmp):
            try:
                os.unlink(tmp)
            except OSError:
                pass


def get_raceline(track: "Track | str", vehicle: VehicleParams | None = None,
                 config: RacelineConfig | None = None, use_cache: bool = True) -> Raceline:
    """The racing line of ``track`` (a :class:`Track` or a :func:`~racing_env.tracks.make_track`
    name) for ``vehicle`` and ``config``, from the in-process memo, else the disk cache
    (:func:`cache_path`), else computed by :func:`compute_raceline` and stored (written to a
    temporary file and moved into place, so readers never see half a file). An unreadable,
    corrupt or mismatched cache file is recomputed and overwritten. ``use_cache=False`` skips
    both caches (and writes nothing).
    """
    if not isinstance(track, Track):
        from .tracks import make_track
        track = make_track(track)
    vehicle = vehicle if vehicle is not None else VehicleParams()
    config = config if config is not None else RacelineConfig()
    if not isinstance(vehicle, VehicleParams):
        raise ValueError(f"vehicle must be a VehicleParams, got {type(vehicle).__name__}")
    if not isinstance(config, RacelineConfig):
        raise ValueError(f"config must be a RacelineConfig, got {type(config).__name__}")
    if not use_cache:
        return compute_raceline(track, vehicle, config)
    key = cache_key(track, vehicle, config)
    path = cache_path(track, vehicle, config)
    memo_key = f"{path}"
    rl = _MEMO.get(memo_key)
    if rl is not None and rl.key == key:
        return rl
    rl = _load(path, key) if path.is_file() else None
    if rl is not None:
        rl.from_cache = True
        rl.track = track
    else:
        rl = compute_raceline(track, vehicle, config)
        _save(path, rl)
    _MEMO[memo_key] = rl
    return rl


def clear_memo() -> None:
    """Forget the in-process memo of :func:`get_raceline` (disk files stay)."""
    _MEMO.clear()


# ====================================================================== plotting
def plot_raceline(track: Track, raceline: Raceline, path, mu=None, dpi: int = 150) -> Path:
    """Write a PNG [path] of the track edges, the centre line and the racing line coloured by
    speed [m/s] (profile for ``mu``, default nominal). Uses matplotlib's Agg canvas directly, so
    it never touches the global backend."""
    if track is None:
        raise ValueError("plot_raceline needs the track (raceline.track is not set)")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    path = Path(path)
    vx = raceline.profile(mu)[0]
    fig = Figure(figsize=(8, 6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    (xl, yl), (xr, yr) = track.edges()
    close = lambda a: np.append(a, a[0])
    ax.plot(close(xl), close(yl), color="0.2", lw=1.0)
    ax.plot(close(xr), close(yr), color="0.2", lw=1.0)
    ax.plot(close(track.x), close(track.y), color="0.6", lw=0.8, ls="--", label="centre line")
    pts = np.column_stack([close(raceline.x), close(raceline.y)])
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(segs, cmap="viridis", linewidths=2.0)
    lc.set_array(0.5 * (vx + np.roll(vx, -1)))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed [m/s]")
    ax.plot(raceline.x[0], raceline.y[0], "r>", ms=8, label="start")
    mu_txt = raceline.mu_nominal if mu is None else float(mu)
    ax.set_title(f"{raceline.track_name}: racing line, mu = {mu_txt:g}, "
                 f"lap {lap_time_of(vx, raceline.ds):.2f} s")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return path


__all__ = ["CSV_COLUMNS", "G", "Raceline", "RacelineConfig", "RacelineConvergenceWarning",
           "accel_limits", "cache_dir", "cache_key", "cache_path", "clear_memo", "compute_raceline",
           "get_raceline", "lap_time_of", "minimum_curvature_offsets", "offset_bounds",
           "plot_raceline", "speed_limit", "speed_profile"]
