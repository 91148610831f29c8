"""One merit-checked SQP step of the MPC in one compiled call: :func:`sqp_step` (trial step
lengths on the nonlinear rollout, the cheapest that does not raise the cost, and the new
linearisation), with its records (:class:`StepCode`, :class:`StepConstants`,
:class:`StepResult`). Shared by the Python solve (:mod:`.solver`) and the compiled one
(:mod:`.compiled_solve`)."""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

import numpy as np
from numba import njit

from .codegen import run_prediction, workspace_offsets
from .prediction import kappa_flat
from .qp import ProblemConstants, score_rollout


class StepCode(IntEnum):
    """How a merit-checked SQP step ended (:attr:`StepResult.code`)."""

    FAILED = -1  # a prediction failed
    REJECTED = 0  # no step length lowers the cost: the plan is kept (the rest is meaningless)
    ACCEPTED = 1  # a step accepted, not linearised again (A, B empty)
    RELINEARISED = 2  # a step accepted and the plan linearised again


class StepConstants(NamedTuple):
    """What every SQP step of one :meth:`MPC.solve` shares."""

    x0: np.ndarray  # (6,) the car's Frenet state
    step_sizes: np.ndarray  # merit-checked step lengths, tried in order
    kappa_tab: np.ndarray  # track curvature per grid station [1/m] (grid of problem.ds)
    m: int  # RK4 sub-steps per stage
    problem: ProblemConstants  # the cost's constants (references, weights, bounds, opponents)


class StepResult(NamedTuple):
    """A merit-checked SQP step (:func:`sqp_step`, :meth:`MPC._step_python`)."""

    code: StepCode
    J: float  # cost of the plan (the old one unless accepted)
    u_vec: np.ndarray  # (2K,) inputs [d0, delta0, d1, ...]
    X: np.ndarray  # (6, K) its rollout
    A: np.ndarray | None  # (36, K) stage Jacobians when RELINEARISED, else empty (None in Python)
    B: np.ndarray | None  # (12, K)
    lo: np.ndarray  # (K,) bounds on n along X
    hi: np.ndarray  # (K,)
    s_nominal: np.ndarray  # (K + 1,) progress at the stage boundaries of the plan


@njit(cache=True)
def trial_step(u_vec, du, alpha, s0, s_pred, ds_lin, kappa_tab, ds, length, m):
    """A trial step's inputs and curvature, in one pass: ``u_vec + alpha du`` clipped to
    [-1, 1] (2K,), and the curvature (substeps K,) along the step's linearised progress
    ``[s0, s_pred + alpha ds_lin]``, stage after stage (the compiled prediction's layouts)."""
    nv = u_vec.shape[0]
    K = s_pred.shape[0]
    u_new = np.empty(nv)
    for i in range(nv):
        v = u_vec[i] + alpha * du[i]
        u_new[i] = -1.0 if v < -1.0 else (1.0 if v > 1.0 else v)
    nodes = np.empty(K + 1)
    nodes[0] = s0
    for k in range(K):
        nodes[k + 1] = s_pred[k] + alpha * ds_lin[k]
    return u_new, kappa_flat(kappa_tab, nodes, m, ds, length)


@njit(cache=True, nogil=True)
def _write_inputs(ws, x0, u_vec, kap, o_u, o_kap):
    """A compiled prediction's inputs ``x0``, ``u_vec``, ``kap`` into its workspace ``ws`` at
    their offsets, element by element (a slice assignment pulls numba's shape-error
    formatting into the compile of a cold race)."""
    for i in range(o_u):
        ws[i] = x0[i]
    for i in range(u_vec.shape[0]):
        ws[o_u + i] = u_vec[i]
    for i in range(kap.shape[0]):
        ws[o_kap + i] = kap[i]


@njit(cache=True)
def sqp_step(c, u_vec, du, ds_lin, s_pred, J, relinearise, roll, traj):
    """The merit-checked step of one SQP iteration in one compiled call, for
    :meth:`MPC.solve`: ``c`` the solve's :class:`StepConstants`, ``u_vec`` (2K,) the plan's
    inputs with cost ``J``, ``du`` (2K,) the QP's step, ``ds_lin`` (K,) its linearised change
    of the progress ``s_pred`` (K,). It calls the two compiled predictions itself, the rollout
    ``roll`` and the one with Jacobians ``traj`` (:class:`~agents.mpc.codegen.KernelHandle`).

    Tries the step lengths ``c.step_sizes`` in order (:func:`trial_step`, the nonlinear
    rollout, :func:`~agents.mpc.qp.score_rollout` under ``c.problem``), stops at the first that
    does not raise the cost ``J`` and keeps the cheapest; then, if ``relinearise``, rolls the
    accepted plan out again with its Jacobians and the curvature along its own progress. Returns a
    :class:`StepResult` (see :class:`StepCode`). The arithmetic is :meth:`MPC._step_python`'s,
    kernel for kernel, so the plans are the same bit for bit."""
    K = s_pred.shape[0]
    m, p = c.m, c.problem
    _, o_u, o_kap, o_x, o_a, o_b, o_w = workspace_offsets(K, m)
    empty = np.empty((0, K))
    found = False
    best_J = np.inf
    best_u = u_vec
    best_X = np.empty((6, K))
    best_lo = np.empty(K)
    best_hi = np.empty(K)
    for a in range(c.step_sizes.shape[0]):
        ua, kap_a = trial_step(
            u_vec, du, c.step_sizes[a], c.x0[0], s_pred, ds_lin, c.kappa_tab, p.ds, p.length, m
        )
        _write_inputs(roll.ws, c.x0, ua, kap_a, o_u, o_kap)
        if run_prediction(roll, K, m):
            return StepResult(
                StepCode.FAILED, J, u_vec, best_X, empty, empty, best_lo, best_hi, s_pred
            )
        Xa = roll.ws[o_x:o_a].reshape(K, 6).T.copy()
        Ja, lo, hi = score_rollout(Xa, ua, p)
        if not found or Ja < best_J:
            found = True
            best_J, best_u, best_X, best_lo, best_hi = Ja, ua, Xa, lo, hi
        if Ja <= J:
            break
    if best_J > J:
        return StepResult(
            StepCode.REJECTED, J, u_vec, best_X, empty, empty, best_lo, best_hi, s_pred
        )
    s_nom = np.empty(K + 1)
    s_nom[0] = c.x0[0]
    for k in range(K):
        s_nom[k + 1] = best_X[0, k]
    if not relinearise:
        return StepResult(
            StepCode.ACCEPTED, best_J, best_u, best_X, empty, empty, best_lo, best_hi, s_nom
        )
    _write_inputs(
        traj.ws, c.x0, best_u, kappa_flat(c.kappa_tab, s_nom, m, p.ds, p.length), o_u, o_kap
    )
    if run_prediction(traj, K, m):
        return StepResult(StepCode.FAILED, J, u_vec, best_X, empty, empty, best_lo, best_hi, s_pred)
    X = traj.ws[o_x:o_a].reshape(K, 6).T.copy()
    A = traj.ws[o_a:o_b].reshape(K, 36).T.copy()
    B = traj.ws[o_b:o_w].reshape(K, 12).T.copy()
    J2, lo2, hi2 = score_rollout(X, best_u, p)
    return StepResult(StepCode.RELINEARISED, J2, best_u, X, A, B, lo2, hi2, s_nom)
