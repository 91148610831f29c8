"""The MPC's whole solve in one compiled call: :func:`solve_problem` is :meth:`MPC.solve
<agents.mpc.solver.MPC.solve>` (warm start, restart from the follower, the RTI-SQP loop with
DAQP, fallback, shifted plan) for one car, and :func:`solve_problems` solves a range of a
batch of cars of one kind (same track, car and config) without the GIL, so that threads
share a batch (:func:`solve_many`).

**The same plans.** Every step is the Python solve's arithmetic, kernel for kernel: the same
compiled helpers (:func:`~agents.mpc.sqp_step.sqp_step`, :func:`~agents.mpc.qp.linearised_qp`,
:func:`~agents.mpc.qp.score_rollout`, the follower's rollout), DAQP's C solver through
:func:`~agents.mpc.daqp_native.solve_qp` (``daqp.solve`` bit for bit) and the progress
change ``G[0::2] @ du`` through the BLAS ``gemv`` as numpy calls it. So a plan is the one the
Python solve makes, bit for bit where numba's BLAS and numpy's agree (they do here, on the
same OpenBLAS kernels; ``tests/test_compiled_solve.py``), and always the same whether the
car is solved alone or in a batch of any size on any number of threads: each problem runs on
private workspaces (:func:`~agents.mpc.codegen.private_handle`) in one thread.

**What it covers.** The paper's solve: a compiled prediction, no damped steps, no second
start, DAQP's own weighting of the soft rows, and the ORCA car's follower warm start. The
full-size class (exact soft rows, throttle limits) and ``plan=damped`` keep the Python solve
(:meth:`MPC.compiled <agents.mpc.solver.MPC.compiled>` says which one a solver uses).
"""

from __future__ import annotations

import os
import time
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numba import njit

from .codegen import KernelSpec, private_handle, run_prediction, workspace_offsets
from .daqp_native import solve_qp
from .prediction import _rollout, kappa_flat, stage_nodes_of
from .qp import ProblemConstants, linearised_qp, predicted_decrease, score_rollout
from .sqp_step import StepCode, StepConstants, _write_inputs, sqp_step

if TYPE_CHECKING:
    from .solver import MPC

#: :func:`solve_problem`'s status codes (the Python solve's ``last_status`` strings)
OK, NONFINITE, QP_FAILED, PREDICTION_FAILED = 0, 1, 2, 3

#: :func:`solve_problem`'s counters, in order (the MPC's ``stats`` keys; ``fallbacks`` stays 0
#: here: the fallback is taken, and counted, by ``MPC._finish``)
COUNTERS = ("restarts", "fallbacks", "qp_iterations", "rejected_steps", "extra_iterations")


class SolveTables(NamedTuple):
    """What every solve of one MPC shares (its track, car and config), for the compiled
    solve. Lengths in metres, times in seconds, inputs normalised to [-1, 1]."""

    kappa_tab: np.ndarray  # track curvature per grid station [1/m]
    lo_tab: np.ndarray  # lower bound on n per grid station [m]
    hi_tab: np.ndarray  # upper bound on n per grid station [m]
    ds: float  # track grid spacing [m]
    length: float  # track length [m]
    DtD: np.ndarray  # (2K, 2K) input-rate cost
    rate: float  # bound on the steering change per stage (normalised)
    dt: float  # stage length [s]
    sep_s: float  # longitudinal separation [m]
    sep_n: float  # lateral separation [m]
    sep_window: float  # progress distance within which an opponent constrains [m]
    slip: tuple  # ProblemConstants' seven slip-row fields (all zeros: no rows)
    step_sizes: np.ndarray  # merit-checked step lengths
    K: int  # horizon (stages)
    m: int  # RK4 sub-steps per stage
    curvature_passes: int
    sqp_iterations: int
    merit_rtol: float
    qp_iter_limit: int
    restart_offtrack: float  # [m]
    v_low: float  # [m/s] the MPC's low-speed regularisation (restart and stop rules)
    follower: tuple  # the follower warm start's tables: n, mu, kappa, v refs, gains, car, act map
    roll: KernelSpec  # the rollout
    traj: KernelSpec  # the prediction with its Jacobians


@njit(cache=True, nogil=True)
def _follower(t, x0):
    """Flat inputs (2K,) of the raceline follower's law rolled out from ``x0`` (the ORCA car's
    :func:`~agents.mpc.prediction.follower_rollout`)."""
    n_ref, mu_ref, kappa_ref, v_ref, gains, pack, act_map = t.follower
    U = np.empty((2, t.K))
    V = np.empty(t.K)
    _rollout(
        x0.copy(),
        n_ref,
        mu_ref,
        kappa_ref,
        v_ref,
        t.kappa_tab,
        t.ds,
        t.length,
        gains,
        pack,
        act_map,
        t.dt,
        U,
        V,
    )
    return np.ascontiguousarray(U.T).reshape(-1)


@njit(cache=True, nogil=True)
def _states(h, K, m):
    o = workspace_offsets(K, m)
    return h.ws[o[3] : o[4]].reshape(K, 6).T.copy()


@njit(cache=True, nogil=True)
def _plan(t, roll, traj, x0, u_vec, s_nom, has_nom):
    """``MPC._plan``: the rollout ``X`` (6, K) of ``u_vec`` with the curvature along its own
    progress and its Jacobians ``A`` (36, K), ``B`` (12, K); ``ok`` False if a prediction
    failed."""
    K, m = t.K, t.m
    o = workspace_offsets(K, m)
    kap = kappa_flat(t.kappa_tab, stage_nodes_of(s_nom, has_nom, x0, K, t.dt), m, t.ds, t.length)
    nodes = np.empty(K + 1)
    for _ in range(t.curvature_passes):
        _write_inputs(roll.ws, x0, u_vec, kap, o[1], o[2])
        if run_prediction(roll, K, m):
            return False, np.empty((6, K)), np.empty((36, K)), np.empty((12, K))
        X = _states(roll, K, m)
        if not np.isfinite(X).all():
            break
        nodes[0] = x0[0]
        for k in range(K):  # element copies, as in the other kernels (a smaller compile)
            nodes[k + 1] = X[0, k]
        kap = kappa_flat(t.kappa_tab, nodes, m, t.ds, t.length)
    _write_inputs(traj.ws, x0, u_vec, kap, o[1], o[2])
    if run_prediction(traj, K, m):
        return False, np.empty((6, K)), np.empty((36, K)), np.empty((12, K))
    X = _states(traj, K, m)
    A = traj.ws[o[4] : o[5]].reshape(K, 36).T.copy()
    B = traj.ws[o[5] : o[6]].reshape(K, 12).T.copy()
    return True, X, A, B


@njit(cache=True, nogil=True)
def _off_track(X, lo, hi):
    """How far the plan's rollout leaves its bounds on n, at most [m] (negative inside)."""
    off = -np.inf
    for k in range(X.shape[1]):
        off = max(off, max(X[1, k] - hi[k], lo[k] - X[1, k]))
    return off


@njit(cache=True, nogil=True)
def solve_problem(
    t, x0, s_ref, n_ref, q, w_soft, rho, delta_applied, opp, u_warm, fresh, s_nom, has_nom
):
    """One :meth:`MPC.solve <agents.mpc.solver.MPC.solve>` under the tables ``t``
    (:class:`SolveTables`): ``x0`` (6,) the car's Frenet state, ``s_ref, n_ref`` (K,) the
    references, ``q`` the tracking weight in the cost's units and ``w_soft``, ``rho`` the soft
    rows' weights (the Python solve's ``problem.q``, ``problem.w_soft`` and DAQP's
    ``rho_soft``), ``delta_applied`` the steering applied last (normalised), ``opp`` (M, K, 2)
    the nearby cars' predicted ``(s, n)``, ``u_warm`` (2K,) the shifted plan (read unless
    ``fresh``), ``s_nom`` (K + 1,) the previous nominal progress (read if ``has_nom``).

    Returns ``(status, exitflag, u_plan (2K,), X (6, K), J, s_nom (K + 1,), has_nom,
    counters (5,))``: the status code (:data:`OK`, :data:`NONFINITE`, :data:`QP_FAILED` with
    DAQP's ``exitflag``, :data:`PREDICTION_FAILED`), the plan's inputs (before the fallback
    and the shift), its rollout and cost, the nominal for the next solve and the
    :data:`COUNTERS`."""
    K, m = t.K, t.m
    counters = np.zeros(5, np.int64)
    roll = private_handle(t.roll, K, m)
    traj = private_handle(t.traj, K, m)
    p = ProblemConstants(
        s_ref,
        n_ref,
        q,
        t.DtD,
        delta_applied,
        t.rate,
        t.lo_tab,
        t.hi_tab,
        t.ds,
        t.length,
        opp,
        t.dt,
        t.sep_s,
        t.sep_n,
        t.sep_window,
        w_soft,
        t.slip[0],
        t.slip[1],
        t.slip[2],
        t.slip[3],
        t.slip[4],
        t.slip[5],
        t.slip[6],
    )
    u_vec = _follower(t, x0) if fresh else u_warm.copy()
    ok, X, A, B = _plan(t, roll, traj, x0, u_vec, s_nom, has_nom)
    if not ok:
        return PREDICTION_FAILED, 0, u_vec, X, np.inf, s_nom, has_nom, counters
    J, lo, hi = score_rollout(X, u_vec, p)
    if not fresh:
        off = np.inf if J == np.inf else _off_track(X, lo, hi)
        if off > t.restart_offtrack or x0[3] < 2.0 * t.v_low:
            uf = _follower(t, x0)
            ok, Xf, Af, Bf = _plan(t, roll, traj, x0, uf, s_nom, has_nom)
            if not ok:
                return PREDICTION_FAILED, 0, u_vec, X, np.inf, s_nom, has_nom, counters
            Jf, lof, hif = score_rollout(Xf, uf, p)
            if Jf < J:
                u_vec, X, A, B, J, lo, hi = uf, Xf, Af, Bf, Jf, lof, hif
                counters[0] += 1
    c = StepConstants(x0, t.step_sizes, t.kappa_tab, m, p)
    status, exitflag = OK, 0
    for it in range(t.sqp_iterations):
        if J == np.inf:
            status = NONFINITE
            break
        ok, G, H, f, Acon, blo, bhi, sense = linearised_qp(X, A, B, u_vec, lo, hi, p)
        if not ok:
            status = NONFINITE
            break
        du, flag, iters = solve_qp(H, f, Acon, bhi, blo, sense, rho, t.qp_iter_limit)
        counters[2] += iters
        if flag < 0 or not np.isfinite(du).all():
            if it == 0:
                status, exitflag = QP_FAILED, flag
            break
        if predicted_decrease(H, f, Acon, blo, bhi, sense, du, w_soft) <= t.merit_rtol * J:
            break
        ds_lin = np.ascontiguousarray(G[0::2]) @ du
        relinearise = it + 1 < t.sqp_iterations
        step = sqp_step(c, u_vec, du, ds_lin, X[0].copy(), J, relinearise, roll, traj)
        if step.code == StepCode.FAILED:
            return PREDICTION_FAILED, 0, u_vec, X, J, s_nom, has_nom, counters
        if step.code == StepCode.REJECTED:
            counters[3] += 1
            break
        u_vec, X, J, lo, hi = step.u_vec, step.X, step.J, step.lo, step.hi
        s_nom, has_nom = step.s_nominal, True
        if step.code == StepCode.ACCEPTED:
            break
        counters[4] += 1
        A, B = step.A, step.B
    return status, exitflag, u_vec, X, J, s_nom, has_nom, counters


def solve_outputs(nb: int, K: int) -> tuple:
    """Empty outputs of :func:`solve_problems` for ``nb`` problems of horizon ``K``."""
    return (
        np.zeros(nb, np.int64),
        np.zeros(nb, np.int64),
        np.empty((nb, 2 * K)),
        np.empty((nb, 6, K)),
        np.empty(nb),
        np.empty((nb, K + 1)),
        np.zeros(nb, np.bool_),
        np.zeros((nb, 5), np.int64),
    )


@njit(cache=True, nogil=True)
def solve_problems(
    t,
    x0,
    s_ref,
    n_ref,
    q,
    w_soft,
    rho,
    delta_applied,
    opp,
    n_opp,
    u_warm,
    fresh,
    s_nom,
    has_nom,
    out,
    first,
    last,
):
    """:func:`solve_problem` for problems ``first..last - 1`` of a batch under the same tables
    ``t``, each exactly as alone, results into ``out`` (:func:`solve_outputs`). Releases the
    GIL, so that threads can solve disjoint ranges of one batch at once. Arguments stacked:
    ``x0`` (B, 6), ``s_ref, n_ref`` (B, K), ``q, w_soft, rho, delta_applied`` (B,), ``opp``
    (B, M, K, 2) of which the first ``n_opp[b]`` rows are car b's, ``u_warm`` (B, 2K),
    ``fresh`` (B,) bool, ``s_nom`` (B, K + 1), ``has_nom`` (B,) bool. ``out`` holds
    ``status, exitflag`` (B,), ``u_plan`` (B, 2K), ``X`` (B, 6, K), ``J`` (B,), ``s_nom``
    (B, K + 1), ``has_nom`` (B,), ``counters`` (B, 5)."""
    status, exitflag, u_out, X_out, J_out, nom_out, has_out, counters = out
    for b in range(first, last):
        r = solve_problem(
            t,
            x0[b],
            s_ref[b],
            n_ref[b],
            q[b],
            w_soft[b],
            rho[b],
            delta_applied[b],
            np.ascontiguousarray(opp[b, : n_opp[b]]),
            u_warm[b],
            fresh[b],
            s_nom[b].copy(),
            has_nom[b],
        )
        status[b], exitflag[b] = r[0], r[1]
        u_out[b] = r[2]
        X_out[b] = r[3]
        J_out[b] = r[4]
        nom_out[b] = r[5]
        has_out[b] = r[6]
        counters[b] = r[7]


# ------------------------------------------------------------------ the MPC's side
def tables_for(mpc: MPC, follower: Any) -> SolveTables:
    """The :class:`SolveTables` of ``mpc`` (its track, car, config, compiled predictions) with
    the warm start's raceline ``follower`` (reset on the track)."""
    cfg, t, v = mpc.cfg, mpc.track, mpc.vehicle
    act_map = np.array([0.5 * (v.d_max + v.d_min), 0.5 * (v.d_max - v.d_min), v.delta_max])
    tables = (*follower.tables(), follower.gains(), v.pack(), act_map)
    return SolveTables(
        t.kappa,
        mpc._bounds_n.lo_table,
        mpc._bounds_n.hi_table,
        float(t.ds),
        float(t.length),
        mpc._DtD,
        float(mpc._rate),
        float(cfg.dt),
        float(cfg.sep_s),
        float(cfg.sep_n),
        float(cfg.sep_window),
        tuple(float(x) for x in mpc._slip),
        mpc._step_sizes,
        int(cfg.horizon),
        int(cfg.substeps),
        int(cfg.curvature_passes),
        int(cfg.sqp_iterations),
        float(cfg.merit_rtol),
        int(cfg.qp_iter_limit),
        float(cfg.restart_offtrack),
        float(cfg.v_low),
        tuple(np.ascontiguousarray(a, dtype=float) for a in tables),
        mpc._roll.kernel_spec(),  # type: ignore[union-attr]
        mpc._traj.kernel_spec(),  # type: ignore[union-attr]
    )


# ------------------------------------------------------------------ batches of MPCs
def solve_many(mpcs: list[MPC], problems: list[tuple]) -> list[np.ndarray]:
    """``mpcs[i].solve(*problems[i])`` for every i (``problems[i]`` the arguments ``(x0,
    s_ref, n_ref, q, opponents, u_prev)``), the inputs to apply, each exactly what the MPC
    gives alone. MPCs of one ``batch_key`` whose solve is ``compiled`` are solved together
    (:func:`_solve_group`); the others one by one from Python. Each problem's ``solve_ms``
    is its group's time shared equally."""
    out: list[Any] = [None] * len(mpcs)
    groups: dict[tuple, list[int]] = {}
    for i, mpc in enumerate(mpcs):
        if mpc.compiled:
            groups.setdefault(mpc.batch_key(), []).append(i)
        else:
            out[i] = mpc.solve(*problems[i])
    for rows in groups.values():
        t0 = time.perf_counter()
        results = _solve_group([mpcs[i] for i in rows], [problems[i] for i in rows])
        share = (time.perf_counter() - t0) / len(rows)
        for i, r in zip(rows, results):
            out[i] = mpcs[i]._finish(np.asarray(problems[i][0], dtype=float), r, share)
    return out


_pools: dict[int, Any] = {}
# a forked child has none of its parent's threads: it builds its own pool when it needs one
os.register_at_fork(after_in_child=_pools.clear)


def _pool(threads: int):
    """A thread pool of ``threads`` workers, kept for the process (:func:`_solve_group`)."""
    if threads not in _pools:
        from concurrent.futures import ThreadPoolExecutor

        _pools[threads] = ThreadPoolExecutor(threads, thread_name_prefix="mpc-solve")
    return _pools[threads]


def _solve_group(mpcs: list[MPC], problems: list[tuple]) -> list[tuple]:
    """Solve the problems of MPCs of one ``batch_key`` in compiled calls
    (:func:`solve_problems`), split over the process's thread budget
    (:func:`agents.threads.thread_budget`: 1 in a pool worker) in contiguous ranges; the
    results, one :func:`solve_problem` tuple per problem."""
    from agents.threads import thread_budget

    args = [m._compiled_args(*p) for m, p in zip(mpcs, problems)]
    warm = [m._warm() for m in mpcs]
    nb, K = len(mpcs), mpcs[0].cfg.horizon
    n_opp = np.array([a[7].shape[0] for a in args], dtype=np.int64)
    opp = np.zeros((nb, max(1, int(n_opp.max())), K, 2))
    for b, a in enumerate(args):
        opp[b, : n_opp[b]] = a[7]
    stacked = (
        mpcs[0]._solve_tables(),
        np.stack([a[0] for a in args]),
        np.stack([a[1] for a in args]),
        np.stack([a[2] for a in args]),
        np.array([a[3] for a in args]),
        np.array([a[4] for a in args]),
        np.array([a[5] for a in args]),
        np.array([a[6] for a in args]),
        opp,
        n_opp,
        np.stack([w[0] for w in warm]),
        np.array([a[8] for a in args]),
        np.stack([w[1] for w in warm]),
        np.array([w[2] for w in warm]),
        solve_outputs(nb, K),
    )
    threads = min(nb, thread_budget())
    if threads <= 1:
        solve_problems(*stacked, 0, nb)
    else:
        edges = np.linspace(0, nb, threads + 1).astype(int)
        ranges = zip(edges[:-1], edges[1:])
        list(_pool(threads).map(lambda r: solve_problems(*stacked, *r), ranges))
    out = stacked[-1]
    return [tuple(r[b] for r in out) for b in range(nb)]
