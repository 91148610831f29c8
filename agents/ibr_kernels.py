"""The compiled (numba) kernels of an IBR best response
(:meth:`agents.ibr_solver.IBR._best_response`): a plan's separation pairs against the other
cars' trajectories, the QP in DAQP's form, a plan's cost on its nonlinear prediction (the
merit check) and the cars a decision must solve."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _separation_pairs(s, n, S, N, cap, ok, owner, c, sep_s, sep_n, window, length, side):
    """Near (stage, obstacle) pairs of car ``c``'s plan ``s, n`` (K,) [m] against the
    trajectories ``S, N`` (rows, K) of other cars (rows with ``owner != c`` and ``ok``), their
    progress capped at ``cap`` (rows, K): ``(stage (p,), lateral (p,), sign (p,), margin (p,))``.
    Progress differences are unwrapped differences shifted by whole laps ``length`` [m] to the
    nearest image at the first stage (a lapped car beside this one is near, as in the env's
    contact rule; nothing jumps at the start/finish line). Per pair the lateral
    separation ``sign * (n - n_j) >= sep_n`` where ``lateral``, else the longitudinal one
    ``sign * (s - s_j) >= sep_s`` (the rule of :func:`agents.mpc.separation_choice`: never a
    mix of progress and offset); ``margin = sign * gap - need`` is negative where violated.
    ``side`` (rows,): where nonzero, car ``c`` keeps to that side of the row (``+1`` left):
    the pair is lateral, with that sign, whenever ``|s - s_j| < sep_s`` (beside each other)
    or the plan is on that side and the usual rule picks lateral; otherwise longitudinal."""
    cars, K = S.shape
    stage = np.empty(cars * K, np.int64)
    lateral = np.empty(cars * K, np.bool_)
    sign = np.empty(cars * K)
    margin = np.empty(cars * K)
    p = 0
    for j in range(cars):
        if owner[j] == c or not ok[j]:
            continue
        lap = length * np.floor((s[0] - min(S[j, 0], cap[j, 0])) / length + 0.5)
        for k in range(K):
            ds = s[k] - min(S[j, k], cap[j, k]) - lap
            if abs(ds) >= window:
                continue
            dn = n[k] - N[j, k]
            if side[j] != 0.0:
                # a kept side: beside each other (|ds| < sep_s) always laterally, on that side
                lat = abs(ds) < sep_s or (
                    side[j] * dn >= 0.0 and abs(dn) / sep_n >= abs(ds) / sep_s
                )
                gap = dn if lat else ds
                sg = side[j] if lat else (1.0 if gap >= 0.0 else -1.0)
            else:
                lat = abs(dn) / sep_n >= abs(ds) / sep_s
                gap = dn if lat else ds
                sg = 1.0 if gap >= 0.0 else -1.0
            stage[p] = k
            lateral[p] = lat
            sign[p] = sg
            margin[p] = sg * gap - (sep_n if lat else sep_s)
            p += 1
    return stage[:p], lateral[:p], sign[:p], margin[:p]


@njit(cache=True)
def _assemble(
    X,
    x0,
    u,
    Gx,
    lo,
    hi,
    stage,
    lateral,
    sign,
    margin,
    H0,
    DtD,
    w_p,
    w_r,
    w_n,
    w_vy,
    trust,
    rate,
    u_prev,
    has_prev,
):
    """The best-response QP of :meth:`agents.ibr_solver.IBR._best_response` in DAQP's form:
    ``(H, f, A, bu, bl, sense, w_lat)``: the first 2K bounds are the input box, then K hard
    steering-rate rows, K soft edge rows and one soft row per separation pair."""
    K = X.shape[1]
    nv = 2 * K
    m = stage.shape[0]
    # quadratic terms as one stacked least-squares block ||r + M du||^2
    w_lat = np.empty(K)
    M = np.zeros((4 * K, nv))
    r = np.zeros(4 * K)
    st = np.sqrt(2.0 * trust)
    sv = np.sqrt(2.0 * w_vy)
    s_prev, n_prev = x0[0], x0[1]
    for k in range(K):
        w_lat[k] = w_n * w_p / (2.0 * max(X[0, k] - s_prev, 0.05))
        sl = np.sqrt(2.0 * w_lat[k])
        for i in range(nv):
            M[k, i] = st * Gx[k, 0, i]
            M[K + k, i] = st * Gx[k, 1, i]
            M[2 * K + k, i] = sv * Gx[k, 4, i]
            M[3 * K + k, i] = sl * (Gx[k, 1, i] - (Gx[k - 1, 1, i] if k > 0 else 0.0))
        r[2 * K + k] = sv * X[4, k]
        r[3 * K + k] = sl * (X[1, k] - n_prev)
        s_prev, n_prev = X[0, k], X[1, k]
    H = H0 + M.T @ M
    f = M.T @ r + 2.0 * w_r * (DtD @ u)
    for i in range(nv):
        f[i] -= w_p * Gx[K - 1, 0, i]
    if has_prev:  # the rate cost includes u^0 - u_applied
        for i in range(2):
            H[i, i] += 2.0 * w_r
            f[i] += 2.0 * w_r * (u[i] - u_prev[i])
    # constraints
    A = np.zeros((2 * K + m, nv))
    bu = np.empty(nv + 2 * K + m)
    bl = np.empty(nv + 2 * K + m)
    sense = np.zeros(nv + 2 * K + m, np.int32)
    for i in range(nv):
        bu[i] = 1.0 - u[i]
        bl[i] = -1.0 - u[i]
    for k in range(K):  # steering rate (hard)
        A[k, 2 * k + 1] = 1.0
        if k > 0:
            A[k, 2 * k - 1] = -1.0
            d = u[2 * k + 1] - u[2 * k - 1]
        elif has_prev:
            d = u[1] - u_prev[1]
        else:
            d = 0.0
        free = k == 0 and not has_prev
        bu[nv + k] = 1e30 if free else rate - d
        bl[nv + k] = -1e30 if free else -rate - d
    for k in range(K):  # track edges (soft)
        for i in range(nv):
            A[K + k, i] = Gx[k, 1, i]
        bu[nv + K + k] = hi[k] - X[1, k]
        bl[nv + K + k] = lo[k] - X[1, k]
        sense[nv + K + k] = 8
    for q in range(m):  # separation (soft)
        k = stage[q]
        row = 1 if lateral[q] else 0
        for i in range(nv):
            A[2 * K + q, i] = sign[q] * Gx[k, row, i]
        bu[nv + 2 * K + q] = 1e30
        bl[nv + 2 * K + q] = -margin[q]
        sense[nv + 2 * K + q] = 8
    return H, f, A, bu, bl, sense, w_lat


@njit(cache=True)
def _reach(S, ok, window, length):
    """Cars (bool (N,)) connected to car 0 through plans ``S`` (N, K) that come within
    ``window`` of each other in progress (nearest image over laps of ``length``) at a common
    stage."""
    n, K = S.shape
    reach = np.zeros(n, np.bool_)
    reach[0] = True
    grown = True
    while grown:
        grown = False
        for a in range(n):
            if not reach[a]:
                continue
            for b in range(n):
                if reach[b] or not ok[b]:
                    continue
                lap = length * np.floor((S[a, 0] - S[b, 0]) / length + 0.5)
                for k in range(K):
                    if abs(S[a, k] - S[b, k] - lap) < window:
                        reach[b] = True
                        grown = True
                        break
    return reach


@njit(cache=True)
def _merit(s, n, vy, n0, u, DtD, lo, hi, margin, w_p, w_r, w_lat, w_vy, w_soft):
    """Best-response cost of a plan (see :meth:`agents.ibr_solver.IBR._best_response`): ``-w_p s^K`` plus the
    input-rate cost ``w_r u' DtD u``, the lateral-motion cost ``sum_k w_lat_k dn_k^2``, the
    slip cost ``w_vy sum_k vy_k^2`` and ``w_soft`` times the squared edge and separation
    violations (``margin < 0``)."""
    K = s.shape[0]
    cost = -w_p * s[K - 1] + w_r * (u @ (DtD @ u)) + w_vy * (vy @ vy)
    prev = n0
    pen = 0.0
    for k in range(K):
        dn = n[k] - prev
        prev = n[k]
        cost += w_lat[k] * dn * dn
        v = max(n[k] - hi[k], lo[k] - n[k], 0.0)
        pen += v * v
    for i in range(margin.shape[0]):
        if margin[i] < 0.0:
            pen += margin[i] * margin[i]
    return cost + w_soft * pen
