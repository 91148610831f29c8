"""The MPC's problem at a plan: the cost of a rollout (tracking, input rates, the soft rows'
penalty), the track-edge bounds and separation choices, and the condensed QP in the input
corrections that one SQP iteration solves with DAQP."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from racing_env.interp import periodic_lookup as _lookup
from racing_env.track import Track
from racing_env.vehicle import VehicleParams

from .config import MPCConfig


class ProblemConstants(NamedTuple):
    """What the QP and the cost of every SQP iteration of one :meth:`~agents.mpc.MPC.solve`
    share: the references, the weights, the steering-rate rows, the track-edge tables and the
    separation rule against the opponents (an argument of the compiled kernels below)."""

    s_ref: np.ndarray  # (K,) reference progress of the predicted states 1..K [m]
    n_ref: np.ndarray  # (K,) reference lateral offsets [m]
    q: float  # tracking weight
    DtD: np.ndarray  # (2K, 2K) input-rate cost (:func:`input_rate_matrix`)
    delta_applied: float  # the steering input applied last (the first steering-rate row's)
    rate: float  # bound on the steering change per stage (normalised)
    lo_tab: np.ndarray  # lower bound on n per grid station [m] (EdgeBounds)
    hi_tab: np.ndarray  # upper bound on n per grid station [m]
    ds: float  # track grid spacing [m]
    length: float  # track length [m]
    opponents: np.ndarray  # (M, K, 2) predicted (s, n) of the nearby cars at stages 1..K
    dt: float  # stage length [s]
    sep_s: float  # longitudinal separation [m]
    sep_n: float  # lateral separation [m]
    sep_window: float  # progress distance within which an opponent constrains [m]
    w_soft: float  # weight of a soft row's squared violation, 1 / (2 rho)
    slip_max: float = 0.0  # bound on the rear slip angle [rad] (soft rows); 0: no rows
    slip_max_f: float = 0.0  # bound on the front slip angle [rad] (soft rows)
    slip_scale: float = 0.0  # [m/rad] a slip-angle violation's weight, as a track-edge one
    l_f: float = 0.0  # c.g. to front axle [m]
    l_r: float = 0.0  # c.g. to rear axle [m]
    delta_max: float = 0.0  # steering angle of a normalised steering input of 1 [rad]
    v_low: float = 0.0  # the slip angles' low-speed regularisation [m/s]


@njit(cache=True)
def condense_states(A, B, K):
    """Sensitivities (K, 6, 2K) of every predicted state to the inputs:
    ``G[k, r, 2j + c] = d x_r^{k+1} / d u_c^j`` (zero for j > k), from the column-major stage
    Jacobians ``A`` (36, K), ``B`` (12, K) of the CasADi function."""
    G = np.zeros((K, 6, 2 * K))
    M = np.empty((6, 2))
    T = np.empty((6, 2))
    for j in range(K):
        for r in range(6):
            for c in range(2):
                M[r, c] = B[r + 6 * c, j]
        for k in range(j, K):
            for r in range(6):
                for c in range(2):
                    G[k, r, 2 * j + c] = M[r, c]
            if k + 1 < K:
                for r in range(6):
                    for c in range(2):
                        acc = 0.0
                        for q in range(6):
                            acc += A[r + 6 * q, k + 1] * M[q, c]
                        T[r, c] = acc
                for r in range(6):  # element copies: no slice assignment in kernels
                    for c in range(2):
                        M[r, c] = T[r, c]
    return G


@njit(cache=True)
def condense(A, B, n_steps):
    """Sensitivities of (s, n) at stages 1..K to the inputs: (2K, 2K) rows [s^1, n^1, ...],
    ``G[2k + r, 2j + c] = d x_r^{k+1} / d u_c^j`` (rows r = 0, 1 of :func:`condense_states`)."""
    return _position_rows(condense_states(A, B, n_steps))


@njit(cache=True)
def _position_rows(Gs):
    """The (s, n) rows (2K, 2K) of the state sensitivities ``Gs`` (K, 6, 2K)."""
    K = Gs.shape[0]
    return np.ascontiguousarray(Gs[:, :2, :]).reshape(2 * K, 2 * K)


@njit(cache=True)
def _grid_interp(table, s, ds, length):
    """The simulator's periodic grid interpolation (``_lookup``) at every element of ``s``."""
    out = np.empty_like(s)
    flat_s, flat_o = s.ravel(), out.ravel()
    for i in range(flat_s.size):
        flat_o[i] = _lookup(table, flat_s[i], ds, length)
    return out


class EdgeBounds:
    """Bounds on the car centre's lateral offset: the track edges minus half the car width and
    the MPC's ``track_margin``; ``(lo, hi) = bounds(s)`` for any array of (unwrapped) s."""

    def __init__(self, track: Track, vehicle: VehicleParams, cfg: MPCConfig):
        half = 0.5 * vehicle.width + cfg.track_margin
        self.track = track
        self.lo_table = np.ascontiguousarray(-track.w_right + half)  # per track station
        self.hi_table = np.ascontiguousarray(track.w_left - half)

    def __call__(self, s):
        t = self.track
        s = np.ascontiguousarray(s, dtype=float)
        return (
            _grid_interp(self.lo_table, s, t.ds, t.length),
            _grid_interp(self.hi_table, s, t.ds, t.length),
        )


def opponent_paths(opponents: np.ndarray | None, K: int, dt: float) -> np.ndarray:
    """The nearby cars' predicted positions, ``(M, K, 2)``: ``(s, n)`` [m] of each at stages
    1..K (``dt`` [s] apart). ``opponents`` is either ``(M, 3)`` rows ``(s, n, s_dot)``, which
    move at constant progress rate and lateral offset (the paper's prediction), or already
    an ``(M, K, 2)`` prediction (returned as a contiguous float array); ``None`` is no car."""
    if opponents is None:
        return np.zeros((0, K, 2))
    o = np.asarray(opponents, dtype=float)
    if o.ndim == 3 and o.shape[1:] == (K, 2):
        return np.ascontiguousarray(o)
    if not (o.size % 3 == 0 and o.ndim <= 2):
        raise ValueError(
            f"opponents must be (M, 3) rows (s, n, s_dot) or an (M, {K}, 2) prediction, "
            f"got shape {np.shape(opponents)}"
        )
    o = o.reshape(-1, 3)
    paths = np.empty((o.shape[0], K, 2))
    # s_j + (v_j dt) (k + 1), in the order the compiled kernels computed it before paths
    paths[:, :, 0] = o[:, :1] + o[:, 2:] * dt * np.arange(1.0, K + 1.0)
    paths[:, :, 1] = o[:, 1:2]
    return paths


def separation_choice(
    s_pred: np.ndarray, n_pred: np.ndarray, path: np.ndarray, cfg: MPCConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which separation to impose against one opponent at each predicted stage k = 1..K.

    ``path`` (K, 2) is the opponent's predicted ``(s, n)`` at the stages (a row of
    :func:`opponent_paths`). Returns ``(near, lateral, sign, s_jk, n_jk)`` (K,) each: constrain
    only ``near`` stages (``|s - s_j^k| < sep_window``); there impose
    ``sign * (n - n_j^k) >= sep_n`` where ``lateral`` else ``sign * (s - s_j^k) >= sep_s``: the
    separation the nominal prediction satisfies with the larger margin, on the side where the
    nominal is.
    """
    s_jk, n_jk = path[:, 0], path[:, 1]
    ds, dn = s_pred - s_jk, n_pred - n_jk
    near = np.abs(ds) < cfg.sep_window
    lateral = np.abs(dn) / cfg.sep_n >= np.abs(ds) / cfg.sep_s
    sign = np.where(np.where(lateral, dn, ds) >= 0.0, 1.0, -1.0)
    return near, lateral, sign, s_jk, n_jk


def input_rate_matrix(K: int) -> np.ndarray:
    """``DtD`` (2K, 2K) on the stacked inputs ``[d0, delta0, d1, ...]``:
    ``u^T DtD u = sum_{k=1..K-1} ||u^k - u^{k-1}||^2``."""
    D = np.zeros((2 * (K - 1), 2 * K))
    for k in range(1, K):
        D[2 * (k - 1) : 2 * k, 2 * k : 2 * k + 2] = np.eye(2)
        D[2 * (k - 1) : 2 * k, 2 * (k - 1) : 2 * k] = -np.eye(2)
    return D.T @ D


@njit(cache=True)
def qp_arrays(G, s_pred, n_pred, u_vec, nlo, nhi, p):
    """The condensed QP in the input corrections ``du`` (2K,) for DAQP, built in one pass, at
    the prediction ``(s_pred, n_pred)`` (K,) of the inputs ``u_vec`` (2K,) with the bounds
    ``nlo, nhi`` (K,) on n along it, under the solve's :class:`ProblemConstants` ``p``.

    Cost ``0.5 du' H du + f' du`` of ``q ||(s, n) - ref||^2 + ||D u||^2``; constraint rows
    ``blo <= Acon du <= bhi`` after the 2K simple input bounds (which lead ``blo``/``bhi``):
    K steering-rate rows (hard), K track-edge rows on n (soft), and one separation row per
    opponent and nearby stage (soft), chosen exactly as :func:`separation_choice` does;
    ``sense`` is DAQP's (0 hard, 8 soft).
    """
    s_ref, n_ref, q, DtD, opponents = p.s_ref, p.n_ref, p.q, p.DtD, p.opponents
    rate, sep_s, sep_n, sep_window = p.rate, p.sep_s, p.sep_n, p.sep_window
    K = s_pred.shape[0]
    nv = 2 * K
    sn_err = np.empty(nv)
    for k in range(K):
        sn_err[2 * k] = s_pred[k] - s_ref[k]
        sn_err[2 * k + 1] = n_pred[k] - n_ref[k]
    H = 2.0 * (q * (G.T @ G) + DtD)
    for i in range(nv):
        H[i, i] += 1e-8
    f = 2.0 * (q * (G.T @ sn_err) + DtD @ u_vec)
    M = opponents.shape[0]
    rows = np.zeros((2 * K + M * K, nv))
    lo = np.empty(2 * K + M * K)
    hi = np.empty(2 * K + M * K)
    soft = np.zeros(2 * K + M * K, dtype=np.int32)
    # steering rate: delta^k - delta^{k-1} within +-rate (normalised), delta^{-1} applied
    for k in range(K):
        rows[k, 2 * k + 1] = 1.0
        d_now = u_vec[2 * k + 1] - (u_vec[2 * k - 1] if k else p.delta_applied)
        if k:
            rows[k, 2 * k - 1] = -1.0
        lo[k] = -rate - d_now
        hi[k] = rate - d_now
    # track edges on n (soft)
    for k in range(K):
        for c in range(nv):
            rows[K + k, c] = G[2 * k + 1, c]
        lo[K + k] = nlo[k] - n_pred[k]
        hi[K + k] = nhi[k] - n_pred[k]
        soft[K + k] = 8
    r = 2 * K
    for m in range(M):
        for k in range(K):
            ds = s_pred[k] - opponents[m, k, 0]
            dn = n_pred[k] - opponents[m, k, 1]
            if not abs(ds) < sep_window:
                continue
            lateral = abs(dn) / sep_n >= abs(ds) / sep_s
            gap = dn if lateral else ds
            sign = 1.0 if gap >= 0.0 else -1.0
            row = 2 * k + 1 if lateral else 2 * k
            for c in range(nv):
                rows[r, c] = sign * G[row, c]
            lo[r] = (sep_n if lateral else sep_s) - sign * gap
            hi[r] = 1e30
            soft[r] = 8
            r += 1
    blo = np.empty(nv + r)
    bhi = np.empty(nv + r)
    sense = np.zeros(nv + r, dtype=np.int32)
    for i in range(nv):
        blo[i] = -1.0 - u_vec[i]
        bhi[i] = 1.0 - u_vec[i]
    for i in range(r):
        blo[nv + i] = lo[i]
        bhi[nv + i] = hi[i]
        sense[nv + i] = soft[i]
    return H, f, rows[:r].copy(), blo, bhi, sense


#: the smallest ``rho_soft`` of :func:`exact_soft_qp` handed to DAQP: it divides rho by the
#: largest soft row's squared norm, and a blown-up linearisation (slip rows of norm 1e10
#: near rest) gave 8e-23, where DAQP broke its heap and the process aborted ("free():
#: invalid next size"); below the floor the MPC lets DAQP weigh the rows itself
EXACT_RHO_FLOOR = 1e-15


def exact_soft_qp(
    H: np.ndarray,
    f: np.ndarray,
    Acon: np.ndarray,
    blo: np.ndarray,
    bhi: np.ndarray,
    sense: np.ndarray,
    rho: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """The QP ``(H, f, Acon, blo, bhi, sense)`` (DAQP's form, :func:`qp_arrays`) rewritten so
    that DAQP charges each soft row's violation ``v`` exactly ``v^2 / (2 rho)``, the penalty
    of :func:`predicted_decrease` and :func:`score_rollout`: ``(H, f, Acon, blo, bhi, sense,
    rho)`` of a QP with one more variable, fixed at 0 (its simple bound), whose first
    ``len(f)`` entries are the step.

    DAQP normalises every constraint row to unit length before it relaxes a soft row, so it
    charges ``(v / |a|)^2 / (2 rho)``: a row of norm 100 (a slip-angle row late in the
    horizon) is violated 10^4 times more cheaply than the cost says, and its step can raise
    the cost it should lower (full size, Monza: the QP's step cost 567 where no step cost 49,
    and the SQP kept a plan that left the track). Each soft row here gains the coefficient
    ``sqrt(N^2 - |a|^2)`` on the fixed variable, so every soft row has norm ``N`` and
    ``rho / N^2`` gives every row the intended weight; the fixed variable leaves every row's
    value unchanged."""
    nv = f.shape[0]
    soft = sense[nv:] == 8
    norms = np.sqrt(np.einsum("ij,ij->i", Acon, Acon))
    big = 2.0 * float(norms[soft].max()) if soft.any() else 1.0
    big = big if big > 0.0 else 1.0
    column = np.where(soft, np.sqrt(np.maximum(big * big - norms * norms, 0.0)), 0.0)
    H2 = np.zeros((nv + 1, nv + 1))
    H2[:nv, :nv] = H
    H2[nv, nv] = 1.0
    return (
        H2,
        np.append(f, 0.0),
        np.hstack([Acon, column[:, None]]),
        np.concatenate([blo[:nv], [0.0], blo[nv:]]),
        np.concatenate([bhi[:nv], [0.0], bhi[nv:]]),
        np.concatenate([sense[:nv], [0], sense[nv:]]).astype(np.int32),
        rho / (big * big),
    )


@njit(cache=True)
def plan_cost(s_pred, n_pred, u_vec, nlo, nhi, p):
    """The MPC's objective at a plan's rollout (:func:`qp_arrays`' cost before linearisation,
    same arguments but ``G``):
    ``q ||(s, n) - ref||^2 + ||D u||^2 + w_soft * (sum of squared violations of the track
    edges and of the separations, chosen per stage as in qp_arrays)``."""
    s_ref, n_ref, q, opponents, w_soft = p.s_ref, p.n_ref, p.q, p.opponents, p.w_soft
    sep_s, sep_n, sep_window = p.sep_s, p.sep_n, p.sep_window
    K = s_pred.shape[0]
    J = 0.0
    for k in range(K):
        J += q * ((s_pred[k] - s_ref[k]) ** 2 + (n_pred[k] - n_ref[k]) ** 2)
        v = max(n_pred[k] - nhi[k], nlo[k] - n_pred[k], 0.0)
        J += w_soft * v * v
    for k in range(1, K):
        J += (u_vec[2 * k] - u_vec[2 * k - 2]) ** 2 + (u_vec[2 * k + 1] - u_vec[2 * k - 1]) ** 2
    for m in range(opponents.shape[0]):
        for k in range(K):
            ds = s_pred[k] - opponents[m, k, 0]
            dn = n_pred[k] - opponents[m, k, 1]
            if not abs(ds) < sep_window:
                continue
            if abs(dn) / sep_n >= abs(ds) / sep_s:
                v = max(sep_n - abs(dn), 0.0)
            else:
                v = max(sep_s - abs(ds), 0.0)
            J += w_soft * v * v
    return J


@njit(cache=True)
def predicted_decrease(H, f, Acon, blo, bhi, sense, du, w_soft):
    """Decrease of the QP's model of the cost (:func:`qp_arrays`' quadratic plus the soft rows'
    penalty ``w_soft v^2``) from ``du = 0`` to the step ``du``: what the linearisation
    promises, in the units of :func:`plan_cost`."""
    nv = du.shape[0]
    gain = -(0.5 * du @ (H @ du) + f @ du)
    a = Acon @ du
    for r in range(a.shape[0]):
        if sense[nv + r] == 8:
            lo, hi = blo[nv + r], bhi[nv + r]
            v_old = max(lo, -hi, 0.0)
            v_new = max(lo - a[r], a[r] - hi, 0.0)
            gain += w_soft * (v_old * v_old - v_new * v_new)
    return gain


@njit(cache=True)
def _all_finite(a):
    for v in a.ravel():
        if not np.isfinite(v):
            return False
    return True


@njit(cache=True)
def linearised_qp(X, A, B, u_vec, nlo, nhi, p):
    """One SQP iteration's QP at the plan ``X`` (6, K) of the inputs ``u_vec`` (2K,) with stage
    Jacobians ``A`` (36, K), ``B`` (12, K) and bounds ``nlo, nhi`` (K,) on n, in one call:
    ``(ok, G, H, f, Acon, blo, bhi, sense)`` with ``G`` from :func:`condense` and the rest from
    :func:`qp_arrays` (under the solve's :class:`ProblemConstants` ``p``); ``ok`` False (and
    the arrays empty) when the prediction is not finite."""
    K = X.shape[1]
    if not (_all_finite(X) and _all_finite(A) and _all_finite(B)):
        e = np.empty((0, 0))
        return False, e, e, np.empty(0), e, np.empty(0), np.empty(0), np.empty(0, np.int32)
    Gs = condense_states(A, B, K)  # all six rows: the slip rows read vx, vy, omega
    G = _position_rows(Gs)
    H, f, Acon, blo, bhi, sense = qp_arrays(G, X[0], X[1], u_vec, nlo, nhi, p)
    if p.slip_max > 0.0:
        rows, lo, hi = slip_rows(Gs, X, u_vec, p)
        Acon = np.concatenate((Acon, rows))
        blo = np.concatenate((blo, lo))
        bhi = np.concatenate((bhi, hi))
        sense = np.concatenate((sense, np.full(2 * K, 8, dtype=np.int32)))
    return True, G, H, f, Acon, blo, bhi, sense


@njit(cache=True)
def slip_angles(X, u_vec, p):
    """The rear and front slip angles [rad] ``(K,), (K,)`` of the predicted states ``X``
    (6, K), as the force law has them (``w = sqrt(vx^2 + v_low^2)``):
    ``a_r = atan((omega l_r - vy) / w)``, ``a_f = delta - atan((omega l_f + vy) / w)`` with
    stage k's steering ``delta = delta_max u_vec[2k + 1]`` (the state at the end of the stage
    it steers)."""
    K = X.shape[1]
    a_r = np.empty(K)
    a_f = np.empty(K)
    for k in range(K):
        w = np.sqrt(X[3, k] ** 2 + p.v_low**2)
        a_r[k] = np.arctan((X[5, k] * p.l_r - X[4, k]) / w)
        a_f[k] = p.delta_max * u_vec[2 * k + 1] - np.arctan((X[5, k] * p.l_f + X[4, k]) / w)
    return a_r, a_f


@njit(cache=True)
def slip_rows(Gs, X, u_vec, p):
    """Soft rows ``(rows (2K, 2K), lo (2K,), hi (2K,))`` keeping the rear slip angle of the
    predicted states within ``+-p.slip_max`` (rows 0..K-1) and the front one within
    ``+-p.slip_max_f`` (rows K..2K-1), linearised through the state sensitivities ``Gs``
    (K, 6, 2K) of :func:`condense_states` (and the stage's steering, for the front); rows
    and bounds in metres (``p.slip_scale`` per radian), so that DAQP's one soft weight prices
    them like a track-edge violation."""
    K = X.shape[1]
    nv = Gs.shape[2]
    rows = np.zeros((2 * K, nv))
    lo = np.empty(2 * K)
    hi = np.empty(2 * K)
    c = p.slip_scale
    a_r, a_f = slip_angles(X, u_vec, p)
    for k in range(K):
        vx, vy, om = X[3, k], X[4, k], X[5, k]
        w = np.sqrt(vx * vx + p.v_low * p.v_low)
        dw = vx / w  # d w / d vx
        for axle in range(2):
            # a = sgn * atan(num / w) (+ delta for the front): d a / d(vx, vy, omega)
            if axle == 0:
                num, d_num_vy, d_num_om, sgn = om * p.l_r - vy, -1.0, p.l_r, 1.0
            else:
                num, d_num_vy, d_num_om, sgn = om * p.l_f + vy, 1.0, p.l_f, -1.0
            z = num / w
            g = sgn / (1.0 + z * z)
            d_vx = -g * num * dw / (w * w)
            d_vy = g * d_num_vy / w
            d_om = g * d_num_om / w
            r = axle * K + k
            for j in range(nv):
                rows[r, j] = c * (d_vx * Gs[k, 3, j] + d_vy * Gs[k, 4, j] + d_om * Gs[k, 5, j])
            if axle == 1:
                rows[r, 2 * k + 1] += c * p.delta_max
            a = a_r[k] if axle == 0 else a_f[k]
            bound = p.slip_max if axle == 0 else p.slip_max_f
            lo[r] = c * (-bound - a)
            hi[r] = c * (bound - a)
    return rows, lo, hi


@njit(cache=True)
def slip_penalty(X, u_vec, p):
    """The slip rows' squared violations summed (m^2, :func:`slip_rows`' units) along ``X``."""
    a_r, a_f = slip_angles(X, u_vec, p)
    total = 0.0
    for k in range(a_r.shape[0]):
        v = p.slip_scale * max(abs(a_r[k]) - p.slip_max, 0.0)
        w = p.slip_scale * max(abs(a_f[k]) - p.slip_max_f, 0.0)
        total += v * v + w * w
    return total


@njit(cache=True)
def score_rollout(X, u_vec, p):
    """``(cost, lo, hi)`` of a plan's rollout ``X`` (6, K) of the inputs ``u_vec`` (2K,) in one
    pass, under the solve's :class:`ProblemConstants` ``p``: the bounds (K,) on n along
    ``X[0]`` (:class:`EdgeBounds`' tables) and :func:`plan_cost` on them; ``inf`` cost (and
    bounds not filled) for a non-finite rollout."""
    K = X.shape[1]
    lo = np.empty(K)
    hi = np.empty(K)
    if not _all_finite(X):
        return np.inf, lo, hi
    for k in range(K):
        lo[k] = _lookup(p.lo_tab, X[0, k], p.ds, p.length)
        hi[k] = _lookup(p.hi_tab, X[0, k], p.ds, p.length)
    J = plan_cost(X[0], X[1], u_vec, lo, hi, p)
    if p.slip_max > 0.0:
        J += p.w_soft * slip_penalty(X, u_vec, p)
    return J, lo, hi
