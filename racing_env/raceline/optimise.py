"""The line's optimisation: the minimum-curvature offsets (appendix B) by repeated
linearisation, the lap-time line's search over the shortest-path weight, and
:func:`compute_raceline`, which turns the offsets into a :class:`Raceline` with its speed
library."""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..track import Track
from ..vehicle import VehicleParams
from .boxqp import BoxQP
from .config import (
    LENGTH_WEIGHTS,
    AnyVehicle,
    RacelineConfig,
    RacelineConvergenceWarning,
    cache_key,
)
from .path import line_on_grid, offset_bounds
from .result import Raceline
from .speed import lap_time_of, speed_profile


def _periodic_diff_matrices(n: int, h: float):
    """Sparse periodic central-difference matrices D1 (d/du) and D2 (d^2/du^2), shape (n, n)."""
    i = np.arange(n)
    ip, im = (i + 1) % n, (i - 1) % n
    d1 = sparse.csr_matrix(
        (np.r_[np.full(n, 0.5), np.full(n, -0.5)] / h, (np.r_[i, i], np.r_[ip, im])), shape=(n, n)
    )
    d2 = sparse.csr_matrix(
        (
            np.r_[np.ones(n), -2.0 * np.ones(n), np.ones(n)] / h**2,
            (np.r_[i, i, i], np.r_[ip, i, im]),
        ),
        shape=(n, n),
    )
    return d1, d2


@dataclass(frozen=True)
class _Stations:
    """The minimum-curvature problem on ``N`` uniform centre-line stations ``s`` [m] (spacing
    ``h`` [m]): centre-line points ``cx, cy`` [m] and unit normals ``nx, ny`` (N,), the offset
    bounds ``lo, hi`` [m] (N,), the periodic difference matrices ``d1, d2`` (N, N) and their
    products with the normals, the smoothing regulariser ``reg`` (N, N) and, with a
    shortest-path weight, its residuals ``a_len n + b_len`` and their normal equations
    ``h_len = a_len' a_len``, ``g_len = a_len' b_len`` (all None without one)."""

    s: np.ndarray
    h: float
    cx: np.ndarray
    cy: np.ndarray
    nx: np.ndarray
    ny: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    d1: sparse.csr_matrix
    d2: sparse.csr_matrix
    d2nx: sparse.csr_matrix
    d2ny: sparse.csr_matrix
    d1nx: sparse.csr_matrix | None
    d1ny: sparse.csr_matrix | None
    reg: sparse.csr_matrix
    a_len: sparse.csr_matrix | None
    b_len: np.ndarray | None
    h_len: sparse.csr_matrix | None
    g_len: np.ndarray | None

    @classmethod
    def on(
        cls, track: Track, vehicle: AnyVehicle, config: RacelineConfig, w_len: float
    ) -> _Stations:
        """The problem on ``track`` with the shortest-path weight ``w_len`` (0: none)."""
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
        reg = (config.smoothing / track.length**2) * (d1.T @ d1)
        exact = config.linearization == "exact"
        d1nx, d1ny = (d1 @ sparse.diags(nx), d1 @ sparse.diags(ny)) if exact else (None, None)
        a_len = b_len = h_len = g_len = None
        if w_len > 0:
            # shortest path: residuals sqrt(w) / (W h) (p_{k+1} - p_k), linear in n: A n + b. The
            # curvature residuals sum to (1 / h) int kappa^2 dl, so this term sums to
            # (1 / h) (w / W^2) sum |dp|^2 / h: the weight does not depend on the station spacing
            scale = math.sqrt(w_len) / (h * float(np.mean(track.width)))
            fwd = sparse.diags(
                [-np.ones(n_pts), np.ones(n_pts - 1), np.ones(1)],
                [0, 1, -(n_pts - 1)],
                format="csr",
            )
            a_len = scale * sparse.vstack([fwd @ sparse.diags(nx), fwd @ sparse.diags(ny)]).tocsr()
            b_len = scale * np.concatenate([fwd @ cx, fwd @ cy])
            h_len, g_len = a_len.T @ a_len, a_len.T @ b_len
        return cls(
            s_sub,
            h,
            cx,
            cy,
            nx,
            ny,
            lo,
            hi,
            d1,
            d2,
            d2nx,
            d2ny,
            d1nx,
            d1ny,
            reg,
            a_len,
            b_len,
            h_len,
            g_len,
        )

    def kappa(self, n):
        """Curvature [1/m] (N,) of the path through offsets ``n`` [m] (N,)."""
        px, py = self.cx + n * self.nx, self.cy + n * self.ny
        dx, dy = self.d1 @ px, self.d1 @ py
        return (dx * (self.d2 @ py) - dy * (self.d2 @ px)) / np.hypot(dx, dy) ** 3

    def path_weight(self, n):
        """Path length per unit of centre-line s at each station [-]: ``|dp/ds|``."""
        px, py = self.cx + n * self.nx, self.cy + n * self.ny
        return np.hypot(self.d1 @ px, self.d1 @ py)

    def cost(self, n) -> float:
        """The true cost of offsets ``n``: ``sum kappa^2 |dp/ds|``, the regulariser and the
        shortest-path term."""
        extra = 0.0 if self.a_len is None else float(np.sum((self.a_len @ n + self.b_len) ** 2))
        return float(np.sum(self.kappa(n) ** 2 * self.path_weight(n)) + n @ (self.reg @ n)) + extra

    def curvature_integral(self, n) -> float:
        """The integral of kappa^2 over the path [1/m] of offsets ``n``, on the stations."""
        return float(np.sum(self.kappa(n) ** 2 * self.path_weight(n)) * self.h)

    def least_squares(self, n, exact: bool):
        """The linearised problem at offsets ``n``: ``(hess, grad)`` of the box QP in the new
        offsets, ``1/2 n' hess n + grad' n``. ``exact`` uses the full Jacobian of the
        residuals (Gauss-Newton), else the first derivatives and the path weight are frozen
        at ``n``."""
        d1, nx, ny = self.d1, self.nx, self.ny
        px, py = self.cx + n * nx, self.cy + n * ny
        dx, dy = d1 @ px, d1 @ py
        ddx, ddy = self.d2 @ px, self.d2 @ py
        q = dx * dx + dy * dy
        den = q**1.5
        kap = (dx * ddy - dy * ddx) / den
        # the objective is sum kappa^2 |dp/ds| h: curvature per metre of *path*, not per station
        # (per station, a wider line's longer path would be free); residual r = sqrt|dp/ds| kappa
        rw = q**0.25
        # kappa(n') ~ kap + a (n' - n): second derivatives exact in n', first derivatives frozen
        a = sparse.diags(dx / den) @ self.d2ny - sparse.diags(dy / den) @ self.d2nx
        if exact:  # ... plus the first derivatives' terms: the full Jacobian (Gauss-Newton)
            d1nx, d1ny = self.d1nx, self.d1ny
            a = (
                a
                + sparse.diags(ddy / den - 3.0 * kap * dx / q) @ d1nx
                - sparse.diags(ddx / den + 3.0 * kap * dy / q) @ d1ny
            )
            # and the path weight's own derivative, d(q^1/4) = q^-3/4 (dx d1nx + dy d1ny) / 2
            jr = sparse.diags(rw) @ a + sparse.diags(0.5 * kap * q**-0.75) @ (
                sparse.diags(dx) @ d1nx + sparse.diags(dy) @ d1ny
            )
        else:  # frozen: the path weight too is fixed at the current iterate
            jr = sparse.diags(rw) @ a
        r = rw * kap
        hess, grad = jr.T @ jr + self.reg, jr.T @ (r - jr @ n)
        if self.h_len is not None:
            hess, grad = hess + self.h_len, grad + self.g_len
        return hess, grad

    def backtrack(self, n, n_new):
        """Line search on the true cost from ``n`` towards ``n_new``: ``(alpha, lower,
        stalled)``, the step length (halved from 1 while the cost rises, down to 1e-3),
        whether it lowers the cost, and whether the decrease is below 1e-6 relative (a
        stationary point: Gauss-Newton creeps along flat valleys)."""
        f0, alpha = self.cost(n), 1.0
        f1 = self.cost(n_new)
        while f1 > f0 and alpha > 1e-3:
            alpha *= 0.5
            f1 = self.cost(n + alpha * (n_new - n))
        return alpha, f1 < f0, f1 >= f0 - 1e-6 * abs(f0)


def minimum_curvature_offsets(
    track: Track,
    vehicle: AnyVehicle | None = None,
    config: RacelineConfig | None = None,
    length_weight: float | None = None,
    n_init: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, dict]:
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
    st = _Stations.on(track, vehicle, config, w_len)
    qp = BoxQP(
        sparse.csc_matrix(abs(st.d2).T @ abs(st.d2) + abs(st.d1).T @ abs(st.d1)), st.lo, st.hi
    )
    exact = config.linearization == "exact"
    tol = config.tol_for(track)
    n_pts = len(st.s)
    n = np.clip(
        np.zeros(n_pts) if n_init is None else np.asarray(n_init, dtype=float), st.lo, st.hi
    )
    converged, change, prev_change, alpha, it = False, np.inf, np.inf, 1.0, 0
    for it in range(1, int(config.max_iter) + 1):  # noqa: B007
        hess, grad = st.least_squares(n, exact)
        n_new = qp.solve(hess, grad, x0=n)
        change = float(np.max(np.abs(n_new - n)))  # fixed-point residual [m]
        if change < tol:
            n = n_new
            converged = True
            break
        if exact:  # backtrack on the true cost
            alpha, lower, stalled = st.backtrack(n, n_new)
            if stalled:  # no more progress: a stationary point
                if lower:
                    n = np.clip(n + alpha * (n_new - n), st.lo, st.hi)
                converged = True
                break
        elif change >= prev_change:  # not contracting (a limit cycle at a
            alpha = max(0.5 * alpha, 0.1)  # tight hairpin): under-relax the update
        prev_change = change
        n = np.clip(n + alpha * (n_new - n), st.lo, st.hi)
    if not converged:
        warnings.warn(
            f"minimum-curvature racing line on track '{track.name}' did not converge in "
            f"max_iter={config.max_iter} iterations (last offset change {change:.2e} m > "
            f"tol {tol:.2e} m); using the last iterate",
            RacelineConvergenceWarning,
            stacklevel=2,
        )
    info = dict(
        iterations=it,
        converged=converged,
        last_change=change,
        tol=tol,
        cost=st.curvature_integral(n),
        cost_center=st.curvature_integral(np.zeros(n_pts)),
    )
    return st.s, n, info


def lap_time_weight_search(
    track: Track,
    vehicle: AnyVehicle | None = None,
    config: RacelineConfig | None = None,
    refine: int = 6,
) -> tuple[float, np.ndarray, np.ndarray, dict, list]:
    """The ``length_weight`` whose line has the shortest lap estimate at ``mu_nominal``.

    Tries :data:`LENGTH_WEIGHTS` in increasing order (each iteration warm-started from the
    previous weight's offsets), then ``refine`` golden-section steps in ``log w`` between the
    best grid weight's neighbours (none when the best is 0, the minimum-curvature line).
    Returns ``(weight, s_sub, n_sub, info, tried)`` with ``tried`` a list of
    ``(weight, lap estimate [s])`` in the order evaluated.
    """
    vehicle = vehicle or VehicleParams()
    config = config or RacelineConfig()
    tried: list[tuple[float, float]] = []
    # (lap estimate, weight, stations, offsets, info) of the fastest weight so far
    best: tuple[float, float, np.ndarray, np.ndarray, dict] | None = None
    n_prev = None

    def evaluate(w):
        nonlocal best, n_prev
        s_sub, n_sub, info = minimum_curvature_offsets(
            track, vehicle, config, length_weight=w, n_init=n_prev
        )
        n_prev = n_sub
        lap = line_on_grid(track, vehicle, config, s_sub, n_sub)["lap_time"]
        tried.append((float(w), lap))
        if best is None or lap < best[0]:
            best = (lap, float(w), s_sub, n_sub, info)
        return lap

    with warnings.catch_warnings():  # a weight's non-converged iterate is only a candidate
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
    assert best is not None  # LENGTH_WEIGHTS is not empty
    _, w, s_sub, n_sub, info = best
    if not info["converged"]:
        warnings.warn(
            f"lap-time racing line on track '{track.name}': the best weight's "
            f"iteration did not converge (last offset change {info['last_change']:.2e} m "
            f"> tol {info['tol']:.2e} m); using its last iterate",
            RacelineConvergenceWarning,
            stacklevel=2,
        )
    return w, s_sub, n_sub, info, tried


def compute_raceline(
    track: Track, vehicle: AnyVehicle | None = None, config: RacelineConfig | None = None
) -> Raceline:
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
    line = line_on_grid(track, vehicle, config, s_sub, n_sub, with_lap=False)
    kappa, ds = line["kappa"], line["ds"]
    mus = config.mus
    lib = [speed_profile(kappa, ds, float(grip), vehicle) for grip in mus]
    vx_lib = np.array([v for v, _ in lib])
    ax_lib = np.array([a for _, a in lib])
    j = int(np.argmin(np.abs(mus - config.mu_nominal)))
    rl = Raceline(
        s=line["s"],
        x=line["x"],
        y=line["y"],
        psi=line["psi"],
        kappa=kappa,
        vx=vx_lib[j].copy(),
        ax=ax_lib[j].copy(),
        n=line["n"],
        s_track=np.asarray(track.s_grid, dtype=float),
        n_lo=line["n_lo"],
        n_hi=line["n_hi"],
        mus=mus,
        vx_lib=vx_lib,
        ax_lib=ax_lib,
        length=line["length"],
        track_length=float(track.length),
        mu_nominal=float(config.mu_nominal),
        lap_time=lap_time_of(vx_lib[j], ds),
        iterations=int(info["iterations"]),
        converged=bool(info["converged"]),
        last_change=float(info["last_change"]),
        cost=info["cost"],
        cost_center=info["cost_center"],
        compute_time=time.perf_counter() - t0,
        length_weight=w,
        track_name=track.name,
        track_fingerprint=track.fingerprint(),
        key=cache_key(track, vehicle, config),
        track=track,
    )
    rl.validate()
    return rl
