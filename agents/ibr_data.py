"""The data of iterated best response (:mod:`agents.ibr_solver`): its settings
(:class:`IBRConfig`), one car's plan (``_Plan``) and the obstacles of one decision
(``_Decision``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .mpc import MPCConfig


@dataclass(frozen=True)
class IBRConfig:
    """IBR settings. Lengths in m, times in s, weights per m of progress / per unit of the
    normalised inputs (throttle and steering in [-1, 1])."""

    horizon: int = 20  # K stages (2 s at dt = 0.1 s, the paper's IBR)
    rounds: int = 6  # best-response rounds per decision (the paper's N = 6)
    dt: float = 0.1
    substeps: int = 3  # RK4 steps per stage (as the MPC)
    v_low: float = 0.5  # slip regularisation of the prediction model [m/s]
    tol: float = 2e-3  # plans have stopped changing when no predicted (s, n) moves more [m]
    progress_weight: float = 10.0  # w_p: per m of terminal progress
    rate_weight: float = 1.0  # w_r: input-rate cost sum_k ||u^k - u^{k-1}||^2 (k = 0: the applied)
    step_weight: float = 2.0  # w_step: regulariser ||du||^2 of one best response
    trust_weight: float = 3.0  # w_tr: trust region sum_k ||d(s^k, n^k)||^2 on the change of
    # the predicted positions in one best response
    slip_weight: float = 1.0  # w_vy: cost sum_k vy_k^2 of body lateral velocity [per (m/s)^2]:
    # keeps plans out of slides the linearisation cannot follow
    lateral_weight: float = 1.0  # w_n: scale of the second-order progress loss of lateral
    # motion, w_p sum_k (n^k - n^{k-1})^2 / (2 v dt)
    track_margin: float = 0.03  # keep the car centre this far inside the edges
    sep_s: float = 0.15  # longitudinal separation [m]
    sep_n: float = 0.08  # lateral separation [m]
    sep_window: float = 2.0  # only stages closer than this in progress constrain [m]
    soft_rho: float = 1e-4  # DAQP rho_soft: reciprocal weight of soft violations
    max_sensitivity: float = 100.0  # a linearisation that moves a predicted position more than
    # this per unit of input [m] has blown up: the QP is not tried
    qp_iter_limit: int = 2000  # DAQP iterations before a best response counts as failed
    restart_offtrack: float = 0.25  # warm start from a follower rollout when the shifted plan
    # leaves the track by more than this [m]
    early_stop: bool = True  # stop the rounds once the plans have stopped changing
    cautious: bool = True  # also keep clear of every other car going on at its present
    # speed and offset, and cap its plan's progress at that speed
    keep_sides: bool = True  # a car closing in from behind and the car ahead each keep to
    # their present side of the other while beside each other
    skip_independent: bool = True  # solve only cars whose plans reach the IBR car's through
    # plans within sep_window (the others cannot move its plan)
    braking_bound: bool | None = None  # soft rows vx^k <= the race line's braking limit at
    # the stage's progress (None: the class's, on at full size, where a 2 s horizon is shorter
    # than a braking zone from top speed; off for the ORCA car, the paper's IBR)

    def __post_init__(self):
        if not (isinstance(self.horizon, (int, np.integer)) and 2 <= self.horizon <= 100):
            raise ValueError(
                f"IBR horizon must be an integer number of stages in 2..100, got {self.horizon!r}"
            )
        if not (isinstance(self.rounds, (int, np.integer)) and 1 <= self.rounds <= 100):
            raise ValueError(f"IBR rounds must be an integer in 1..100, got {self.rounds!r}")
        if not (isinstance(self.substeps, (int, np.integer)) and 1 <= self.substeps <= 10):
            raise ValueError(f"IBR substeps must be an integer in 1..10, got {self.substeps!r}")
        if not (isinstance(self.slip_weight, (int, float)) and self.slip_weight >= 0):
            raise ValueError(f"IBRConfig.slip_weight must be >= 0, got {self.slip_weight!r}")
        for name in (
            "dt",
            "v_low",
            "tol",
            "progress_weight",
            "rate_weight",
            "step_weight",
            "trust_weight",
            "lateral_weight",
            "sep_s",
            "sep_n",
            "sep_window",
            "soft_rho",
            "restart_offtrack",
            "max_sensitivity",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"IBRConfig.{name} must be a positive number, got {v!r}")
        if not (isinstance(self.qp_iter_limit, (int, np.integer)) and self.qp_iter_limit >= 1):
            raise ValueError(
                f"IBRConfig.qp_iter_limit must be a positive integer, got {self.qp_iter_limit!r}"
            )
        if not (self.braking_bound is None or isinstance(self.braking_bound, bool)):
            raise ValueError(
                f"IBRConfig.braking_bound must be None, True or False, got {self.braking_bound!r}"
            )
        if not (isinstance(self.track_margin, (int, float)) and self.track_margin >= 0):
            raise ValueError(f"IBRConfig.track_margin must be >= 0, got {self.track_margin!r}")

    def mpc_config(self) -> MPCConfig:
        """The :class:`MPCConfig` of the shared stage model, edges and separation rule."""
        return MPCConfig(
            horizon=int(self.horizon),
            dt=self.dt,
            substeps=int(self.substeps),
            v_low=self.v_low,
            track_margin=self.track_margin,
            sep_s=self.sep_s,
            sep_n=self.sep_n,
            sep_window=self.sep_window,
            soft_rho=self.soft_rho,
            restart_offtrack=self.restart_offtrack,
        )


class _Plan:
    """One car's plan: inputs ``U`` (2, K), its prediction ``X`` (6, K) from ``x0`` (6,) with
    curvature ``kap`` (substeps, K), the stage Jacobians ``A`` (36, K), ``B`` (12, K), and the
    edge bounds ``lo, hi`` (K,) [m] on ``n`` at its predicted progress."""

    __slots__ = ("x0", "U", "kap", "X", "A", "B", "lo", "hi", "ok")
    x0: np.ndarray
    U: np.ndarray
    kap: np.ndarray
    X: np.ndarray
    A: np.ndarray
    B: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    ok: bool


@dataclass
class _Decision:
    """The obstacles of one decision, built by :meth:`agents.ibr_solver.IBR.solve` and passed to every best
    response. Rows ``0..N-1`` are every car's current plan ``(S, N)`` (rows, K) [m], kept up
    to date by :meth:`store`; when cautious, rows ``N..2N-1`` every car going on at its
    present progress rate and lateral offset. ``ok`` (rows,) marks usable rows, ``owner``
    (rows,) the car of each row, ``s_cap`` (rows, K) [m] the cap on each row's progress, and
    ``side`` (N, rows) the kept sides (+1 left, -1 right, 0 free) of each car against each
    row."""

    S: np.ndarray
    N: np.ndarray
    ok: np.ndarray
    owner: np.ndarray
    s_cap: np.ndarray
    side: np.ndarray

    def store(self, c: int, plan: _Plan) -> None:
        """Make car ``c``'s row its plan's predicted ``(s, n)`` (or mark it unusable)."""
        self.ok[c] = plan.ok
        if plan.ok:
            self.S[c] = plan.X[0]
            self.N[c] = plan.X[1]


def ibr_class_weights(cfg: IBRConfig, vehicle: object) -> dict[str, Any]:
    """The IBR's weights and tolerances of :class:`IBRConfig`, given for the ORCA car, in
    ``vehicle``'s class (its lengths already scaled, :data:`~agents.mpc.config.CLASS_SCALED_FIELDS`):
    positions and position changes measured in car lengths and widths, speeds in shares of
    the class's top speed, so that a best response weighs the same manoeuvre alike in every
    class (the MPC's rule, :func:`~agents.mpc.config.class_scale`). The ORCA car's are
    unchanged."""
    from agents.theta import theta_length_scales

    from .mpc.config import class_scale

    k_len, k_wid = class_scale(vehicle)
    k_v = 1.0 / theta_length_scales(vehicle)[2]  # the class's top speed over the ORCA car's
    return {
        "progress_weight": cfg.progress_weight / k_len,  # per car length of progress
        "trust_weight": cfg.trust_weight / k_wid**2,  # per car width of moved position
        "soft_rho": cfg.soft_rho * k_wid**2,  # soft violations in car widths
        "slip_weight": cfg.slip_weight / k_v**2,  # lateral velocity in shares of top speed
        "tol": cfg.tol * k_len,
        "max_sensitivity": cfg.max_sensitivity * k_len,
    }
