"""The box-constrained QP of every linearisation of the racing line,
``min 1/2 x' H x + g' x  s.t.  lo <= x <= hi``: a primal-dual active-set method, with OSQP and
DAQP (through CasADi) as fallbacks."""
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


class BoxQP:
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

