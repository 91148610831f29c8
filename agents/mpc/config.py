"""The MPC's settings: :class:`MPCConfig` (horizon, prediction model, constraints, SQP)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class MPCConfig:
    """MPC settings. Lengths in m, times in s."""

    horizon: int = 15  # K
    dt: float = 0.1
    substeps: int = 3  # RK4 steps per stage
    v_low: float = 0.5  # slip regularisation of the prediction model at rest [m/s]
    v_blend: float = 1.0  # ... fading to the simulator's v_low above this speed [m/s]
    track_margin: float = 0.03  # keep the car centre this far inside the edges
    sep_s: float = 0.15  # longitudinal separation p_x^min
    sep_n: float = 0.08  # lateral separation p_y^min
    sep_window: float = 2.0  # only opponents within this progress distance constrain
    soft_rho: float = 1e-4  # DAQP rho_soft at q <= soft_q_ref: a soft violation v costs
    # v^2 / (2 rho), rho = soft_rho_at(q)
    soft_q_ref: float = 20.0  # above this tracking weight rho shrinks like 1 / q
    sqp_iterations: int = 12  # most SQP iterations (QPs) per solve: the SQP stops earlier
    # when a QP step predicts a relative decrease of the cost
    # below merit_rtol, or when no step length lowers it
    merit_rtol: float = 1e-3  # predicted relative cost decrease worth a merit check
    step_sizes: tuple = (1.0, 0.5, 0.25, 0.125)  # merit-checked step lengths of each QP step
    curvature_passes: int = 1  # re-rollouts of a plan with the curvature along its own
    # progress (0: along the previous plan's progress only)
    restart_offtrack: float = 0.06  # warm start from a follower rollout when the shifted plan
    # leaves the track by more than this [m]
    qp_iter_limit: int = 300  # DAQP active-set iterations; a QP that needs more (rare
    # cycling) falls back instead of spinning for 10 ms
    step_damping: tuple = ()  # where no step length of a QP step lowers the cost, solve the
    # QP again with lam * mean(diag H) added to its Hessian, for each lam in turn, until a
    # step is accepted (Levenberg-Marquardt: a shorter step turned toward steepest descent);
    # () keeps the plain line search. Opt-in: docs/policy-space.md, "Damped steps"
    slip: float | None = None  # soft bounds on the rear and front slip angles of the
    # predicted states, as a fraction of each tyre's peak slip angle; None: the class's
    # default (full size 1.0: its peaky tyre loses 40% of its grip past the peak, and a plan
    # that slides the rear spins the car after the horizon, one past the front's peak locks
    # the steering where it no longer turns the car; ORCA: none, the paper's MPC); 0: none
    exact_soft: bool | None = None  # charge every soft row's violation v as the cost does,
    # v^2 / (2 rho), in the QP (:func:`agents.mpc.qp.exact_soft_qp`; DAQP alone divides it by
    # the row's squared norm, and its step can raise the cost); None: the class's default
    # (full size on; ORCA off, the paper's MPC, so that its stored races stay valid)
    second_start: bool = False  # where the SQP's plan still pays the soft rows' penalty (a
    # track edge or a separation violated), solve again from the raceline follower's
    # rollout and from the plan with less throttle, and keep the cheapest (a local solution
    # in traffic that IPOPT avoids)

    def __post_init__(self):
        if not (isinstance(self.horizon, int) and 2 <= self.horizon <= 100):
            raise ValueError(f"MPC horizon must be an integer in 2..100, got {self.horizon!r}")
        if not (isinstance(self.substeps, int) and 1 <= self.substeps <= 10):
            raise ValueError(f"MPC substeps must be an integer in 1..10, got {self.substeps!r}")
        for name in (
            "dt",
            "v_low",
            "v_blend",
            "sep_s",
            "sep_n",
            "sep_window",
            "soft_rho",
            "soft_q_ref",
        ):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"MPCConfig.{name} must be positive, got {v!r}")
        if not (isinstance(self.qp_iter_limit, int) and self.qp_iter_limit >= 1):
            raise ValueError(
                f"MPCConfig.qp_iter_limit must be a positive integer, got {self.qp_iter_limit!r}"
            )
        if self.track_margin < 0 or self.sqp_iterations < 1:
            raise ValueError(
                f"MPCConfig needs track_margin >= 0 and sqp_iterations >= 1, got "
                f"{self.track_margin}, {self.sqp_iterations}"
            )
        if not (isinstance(self.curvature_passes, int) and 0 <= self.curvature_passes <= 5):
            raise ValueError(
                f"MPCConfig.curvature_passes must be an integer in 0..5, got "
                f"{self.curvature_passes!r}"
            )
        if not (np.isfinite(self.merit_rtol) and self.merit_rtol >= 0):
            raise ValueError(f"MPCConfig.merit_rtol must be >= 0, got {self.merit_rtol!r}")
        try:
            damping = tuple(self.step_damping)
        except TypeError:  # not a sequence of factors
            damping = None
        if damping is None or any(
            isinstance(lam, bool) or not isinstance(lam, (int, float)) or not (0 < lam < np.inf)
            for lam in damping
        ):
            raise ValueError(
                f"MPCConfig.step_damping must be positive finite factors, got {self.step_damping!r}"
            )
        if self.slip is not None and (isinstance(self.slip, bool) or not (0.0 <= self.slip <= 5.0)):
            raise ValueError(
                f"MPCConfig.slip must be None or a fraction in [0, 5] of the peak slip "
                f"angles, got {self.slip!r}"
            )
        if self.exact_soft is not None and not isinstance(self.exact_soft, bool):
            raise ValueError(
                f"MPCConfig.exact_soft must be None, True or False, got {self.exact_soft!r}"
            )
        steps = tuple(self.step_sizes)
        if not steps or any(not (0 < a <= 1) for a in steps):
            raise ValueError(
                f"MPCConfig.step_sizes must be step lengths in (0, 1], got {self.step_sizes!r}"
            )

    def soft_rho_at(self, q: float) -> float:
        """DAQP's ``rho_soft`` for tracking weight ``q``: ``soft_rho * min(1, soft_q_ref / q)``,
        so the soft rows (track edges, separations) keep their weight relative to tracking."""
        return self.soft_rho * min(1.0, self.soft_q_ref / float(q))


CLASS_SCALED_FIELDS: dict[str, str] = {
    "track_margin": "width",
    "sep_s": "length",
    "sep_n": "width",
    "sep_window": "length",
    "restart_offtrack": "width",
}
"""The :class:`MPCConfig` (and :class:`agents.ibr.IBRConfig`) lengths [m], given for the ORCA
car, that scale with the car's ``"length"`` or ``"width"`` ratio to it (see
:func:`class_scale`)."""


def class_scale(vehicle: Any) -> tuple[float, float]:
    """``(k_len, k_wid)``: the car's length and width over the ORCA car's
    (:func:`racing_env.scaling.size_ratios`; exactly (1, 1) for the ORCA car).

    The one place where the MPC family (``mpc``, ``alpha``, ``ibr``) adapts its metres, tuned
    to the 0.12 m x 0.06 m ORCA car, to another vehicle class:

    * the config's lengths of :data:`CLASS_SCALED_FIELDS` (:func:`config_for_vehicle`);
    * the cost: position errors and soft-row violations [m] are measured in ORCA-car widths
      (divided by ``k_wid``), so ``q``, ``soft_rho`` and the theta box weigh a deviation of
      one car width alike in every class (``MPC``: ``q / k_wid^2``, ``rho k_wid^2``);
    * theta's lengths (:func:`agents.theta.theta_in_metres`): ``s1`` [m] times ``k_wid``,
      ``s2`` [1/m^2] over ``k_len^2``, ``s3`` [s/m] over the ratio of the two classes' top
      speeds; and the extended space's :data:`agents.reference.PASS_ROOM` times ``k_wid``.

    Times, speeds, input bounds and counts do not scale; the input bounds and the rates are
    the class's own parameters.
    """
    from racing_env.scaling import size_ratios

    return size_ratios(vehicle)


def config_for_vehicle(cfg: MPCConfig, vehicle: Any) -> MPCConfig:
    """``cfg`` with its lengths of :data:`CLASS_SCALED_FIELDS` scaled to ``vehicle``'s size
    (:func:`class_scale`); ``cfg`` itself for the ORCA car's size."""
    from dataclasses import replace

    k = dict(zip(("length", "width"), class_scale(vehicle)))
    if k["length"] == 1.0 and k["width"] == 1.0:
        return cfg
    return replace(cfg, **{f: getattr(cfg, f) * k[kind] for f, kind in CLASS_SCALED_FIELDS.items()})


def slip_bound(cfg: MPCConfig, vehicle: Any) -> tuple[float, ...]:
    """The trailing fields of :class:`agents.mpc.qp.ProblemConstants` for the MPC's soft rows
    on the slip angles (:func:`agents.mpc.qp.slip_rows`): ``(slip_max, slip_max_f [rad],
    slip_scale [m/rad], l_f, l_r [m], delta_max [rad], v_low [m/s])``. The bounds are
    ``cfg.slip`` (None: 1.0 for the full-size class, none for the ORCA car) times each
    tyre's peak slip angle; a violation of one peak slip angle weighs like a car width beyond
    a track edge. All zeros (no rows) when there is no bound."""
    from racing_env.vehicles import FullSizeParams

    full = isinstance(vehicle, FullSizeParams)
    frac = (1.0 if full else 0.0) if cfg.slip is None else float(cfg.slip)
    if frac == 0.0:
        return (0.0,) * 7
    if not full:
        raise ValueError(
            f"MPCConfig.slip={cfg.slip!r} needs a vehicle with Magic Formula tyres "
            f"(FullSizeParams), got {type(vehicle).__name__}"
        )
    rear, front = vehicle.peak_slip("rear"), vehicle.peak_slip("front")
    v = vehicle
    return frac * rear, frac * front, v.width / rear, v.lf, v.lr, v.delta_max, v.v_low


def exact_soft_on(cfg: MPCConfig, vehicle: Any) -> bool:
    """Whether the MPC's QPs charge the soft rows exactly (``cfg.exact_soft``; None: on for
    the full-size class, off for the ORCA car)."""
    from racing_env.vehicles import FullSizeParams

    if cfg.exact_soft is None:
        return isinstance(vehicle, FullSizeParams)
    return bool(cfg.exact_soft)


PLANS: dict[str, dict[str, Any]] = {
    "rti": {},
    "damped": {"step_damping": (1.0, 10.0, 100.0), "sqp_iterations": 20},
}
"""The MPC agent's ``plan`` choices, as :class:`MPCConfig` fields over the config given:
``"rti"``, the RTI-SQP as configured (default); ``"damped"``, damped SQP steps and up to 20
SQP iterations (plans within 5% of IPOPT's cost in 94% of the states of 3-car races at the
top of the box against 81%, at 1.4x the median solve time; docs "Damped steps")."""
