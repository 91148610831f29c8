"""The box-constrained QP of every linearisation of the racing line,
``min 1/2 x' H x + g' x  s.t.  lo <= x <= hi``: a primal-dual active-set method; where its
active sets do not settle, an interior-point method whose solution the active-set method then
polishes; OSQP and DAQP (through CasADi) as last fallbacks."""

from __future__ import annotations

import numpy as np
from scipy import sparse


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


INTERIOR_POINT_FIRST_ABOVE = 1000
"""Offsets above which a QP the active-set method does not settle goes to the interior-point
method before OSQP. Every track at 1:43 has at most 1,000 (the track grid's size), so their
lines keep the solvers they were computed with, bit for bit."""


class BoxQP:
    """``min 1/2 x' H x + g' x  s.t.  lo <= x <= hi`` for a fixed sparsity pattern of ``H``.

    A primal-dual active-set method (:func:`box_qp_active_set`: sparse direct solves on the
    free offsets, exact to rounding) first; warm-started it mostly settles in a few sparse
    solves. The curvature Hessians are banded and very badly conditioned (a squared second
    difference: a condition number growing like ``N^4``), and its active sets can wander
    without settling (a third of the QPs on the 1:43 tracks, most of them at full scale).
    Then, up to :data:`INTERIOR_POINT_FIRST_ABOVE` offsets (every track at 1:43, whose
    cached lines come from this path), OSQP (through CasADi's ``conic``, polished), and DAQP
    (an exact dual active-set solver, dense) if OSQP does not report success. Above it (a
    full-scale circuit: 2,895 stations at Monza, where OSQP ends "solved inaccurate" or at
    its 20,000-iteration limit after about 15 s and DAQP takes about 30 s), a primal-dual
    interior-point method (:func:`box_qp_interior_point`: 20-30 banded sparse solves, no
    active-set combinatorics) first, its solution polished by the active-set method (which,
    started there, settles in one or two solves: exact to rounding again); OSQP and DAQP
    only if it fails.
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

    def solve(self, h: np.ndarray, g: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """Minimiser, shape (n,), clipped to the bounds; raises RuntimeError if every solver fails."""
        g = np.asarray(g, float)
        x = box_qp_active_set(h, g, self.lo, self.hi, x0)
        if x is not None:
            return x
        if len(g) > INTERIOR_POINT_FIRST_ABOVE and np.all(self.hi > self.lo):
            x_ip = box_qp_interior_point(h, g, self.lo, self.hi, x0)
            if x_ip is not None:
                x = box_qp_active_set(h, g, self.lo, self.hi, x_ip)  # polish
                return x if x is not None else np.clip(x_ip, self.lo, self.hi)
        hdm = _to_casadi(h, self.pattern)
        args = dict(h=hdm, g=g, lbx=self.lo, ubx=self.hi)
        if x0 is not None:
            args["x0"] = x0
        if self._lam is not None:
            args["lam_x0"] = self._lam
        if self._osqp is None:
            self._osqp = self._conic(
                "raceline_osqp",
                "osqp",
                {
                    "osqp": {
                        "eps_abs": 1e-7,
                        "eps_rel": 1e-7,
                        "max_iter": 20000,
                        "polish": True,
                        "verbose": False,
                    }
                },
            )
        res = self._osqp(**args)
        if not self._osqp.stats().get("success", False):
            if self._daqp is None:
                self._daqp = self._conic("raceline_daqp", "daqp", {})
            res = self._daqp(**args)
            if not self._daqp.stats().get("success", False):
                raise RuntimeError(
                    "racing-line QP failed in the active-set method, OSQP and DAQP: "
                    f"{self._osqp.stats().get('return_status')}, "
                    f"{self._daqp.stats().get('return_status')}"
                )
        x = np.asarray(res["x"], dtype=float).ravel()
        self._lam = np.asarray(res["lam_x"], dtype=float).ravel()
        if not np.all(np.isfinite(x)):
            raise RuntimeError("racing-line QP returned non-finite offsets")
        return np.clip(x, self.lo, self.hi)


def box_qp_active_set(
    h: np.ndarray,
    g: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    x0: np.ndarray | None = None,
    max_iter: int = 30,
) -> np.ndarray | None:
    """``argmin 1/2 x' H x + g' x`` over ``lo <= x <= hi`` by the primal-dual active-set
    method (Hintermueller, Ito and Kunisch 2002), ``H`` sparse symmetric positive definite,
    shapes (n, n), (n,), (n,), (n,). Each iteration fixes at a bound every ``x_i`` whose
    projected step ``x_i - c (H x + g)_i`` leaves the box (``c`` scales the gradient to the
    offsets), solves ``H_FF x_F = -(g_F + H_FA x_A)`` on the free set ``F`` (sparse LU) and
    stops once the sets repeat. ``None`` if they do not settle in ``max_iter`` iterations or a
    solve is not finite (the caller falls back to a general QP solver)."""
    from scipy.sparse.linalg import splu

    hs = sparse.csc_matrix(h)
    n = len(g)
    x = np.clip(np.zeros(n) if x0 is None else np.asarray(x0, float), lo, hi)
    c = 1.0 / max(float(np.abs(hs.diagonal()).max()), 1e-300)
    at_lo: np.ndarray | None = None
    at_hi: np.ndarray | None = None
    for _ in range(int(max_iter)):
        grad = hs @ x + g
        step = x - c * grad
        new_lo, new_hi = step < lo, step > hi
        if (
            at_lo is not None
            and at_hi is not None
            and np.array_equal(new_lo, at_lo)
            and np.array_equal(new_hi, at_hi)
        ):
            return np.clip(x, lo, hi)
        at_lo, at_hi = new_lo, new_hi
        free = ~(at_lo | at_hi)
        x = np.where(at_lo, lo, np.where(at_hi, hi, x))
        if free.any():
            fi = np.flatnonzero(free)
            rhs = -(g[fi] + hs[fi][:, ~free] @ x[~free])
            try:
                x[fi] = splu(hs[fi][:, fi].tocsc()).solve(rhs)
            except RuntimeError:  # singular: let a general solver try
                return None
            if not np.all(np.isfinite(x)):
                return None
    return None


def box_qp_interior_point(
    h: np.ndarray,
    g: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    x0: np.ndarray | None = None,
    max_iter: int = 100,
    tol: float = 1e-12,
) -> np.ndarray | None:
    """``argmin 1/2 x' H x + g' x`` over ``lo < x < hi`` by a primal-dual interior-point
    method (Mehrotra's predictor-corrector), ``H`` sparse symmetric positive definite, shapes
    (n, n), (n,), (n,), (n,) with ``lo < hi``. With the bound multipliers ``z_lo, z_hi >= 0``
    each iteration solves ``(H + Z_lo / (x - lo) + Z_hi / (hi - x)) dx = r`` twice on one
    sparse LU (predictor, then corrector with the centring ``sigma = (mu_aff / mu)^3``) and
    steps 0.995 of the way to the boundary. ``x0`` only places the strictly interior start
    (clipped to 5% of the width inside the bounds). Stops once the mean complementarity is
    below ``tol`` times the gradient scale times the mean width and the gradient residual
    below ``1e3 tol`` times the gradient scale; returns ``x`` (strictly inside the bounds, so
    not exactly on the active ones: polish with :func:`box_qp_active_set`), or ``None`` if
    it does not converge in ``max_iter`` iterations or a solve is not finite."""
    from scipy.sparse.linalg import splu

    h = sparse.csc_matrix(h)
    g, lo, hi = np.asarray(g, float), np.asarray(lo, float), np.asarray(hi, float)
    if not np.all(hi > lo):
        raise ValueError(
            f"box_qp_interior_point needs lo < hi everywhere, got "
            f"{int(np.sum(hi <= lo))} of {len(lo)} bounds with hi <= lo"
        )
    n, w = len(g), hi - lo
    x = np.zeros(n) if x0 is None else np.asarray(x0, float)
    x = np.clip(x, lo + 0.05 * w, hi - 0.05 * w)
    grad = h @ x + g
    scale = max(float(np.abs(g).max()), float(np.abs(grad).max()), 1e-300)
    z_lo = np.maximum(grad, 0.0) + 0.1 * scale
    z_hi = np.maximum(-grad, 0.0) + 0.1 * scale

    def to_boundary(v, dv):
        neg = dv < 0
        return min(1.0, float(np.min(-v[neg] / dv[neg]))) if neg.any() else 1.0

    # the slacks are carried, not recomputed as x - lo: near an active bound x - lo rounds to
    # exactly 0 at full scale (offsets of metres, slacks of 1e-16 m), a singular system
    d_lo, d_hi = x - lo, hi - x
    for _ in range(int(max_iter)):
        r_d = h @ x + g - z_lo + z_hi
        mu = float(d_lo @ z_lo + d_hi @ z_hi) / (2 * n)
        if mu < tol * scale * float(w.mean()) and float(np.abs(r_d).max()) < 1e3 * tol * scale:
            return x
        try:
            lu = splu((h + sparse.diags(z_lo / d_lo + z_hi / d_hi)).tocsc())
        except RuntimeError:  # singular
            return None

        def newton(c_lo, c_hi):
            dx = lu.solve(-r_d + c_lo / d_lo - c_hi / d_hi)  # noqa: B023
            return dx, (c_lo - z_lo * dx) / d_lo, (c_hi + z_hi * dx) / d_hi  # noqa: B023

        dx, dz_lo, dz_hi = newton(-d_lo * z_lo, -d_hi * z_hi)  # predictor
        ap = min(to_boundary(d_lo, dx), to_boundary(d_hi, -dx))
        ad = min(to_boundary(z_lo, dz_lo), to_boundary(z_hi, dz_hi))
        mu_aff = float(
            (d_lo + ap * dx) @ (z_lo + ad * dz_lo) + (d_hi - ap * dx) @ (z_hi + ad * dz_hi)
        ) / (2 * n)
        sm = (mu_aff / mu) ** 3 * mu
        dx, dz_lo, dz_hi = newton(
            sm - d_lo * z_lo - dx * dz_lo,  # corrector
            sm - d_hi * z_hi + dx * dz_hi,
        )
        if not (
            np.all(np.isfinite(dx)) and np.all(np.isfinite(dz_lo)) and np.all(np.isfinite(dz_hi))
        ):
            return None
        ap = 0.995 * min(to_boundary(d_lo, dx), to_boundary(d_hi, -dx))
        ad = 0.995 * min(to_boundary(z_lo, dz_lo), to_boundary(z_hi, dz_hi))
        x, z_lo, z_hi = x + ap * dx, z_lo + ad * dz_lo, z_hi + ad * dz_hi
        d_lo, d_hi = d_lo + ap * dx, d_hi - ap * dx
    return None
