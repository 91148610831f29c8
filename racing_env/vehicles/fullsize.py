"""A full-size single-seater: TUM FTM's race car in the paper's Frenet bicycle model.

Same state and input as :mod:`racing_env.vehicle` (the paper's 1:43 ORCA car, which stays the
default): ``x = (s, n, mu, vx, vy, omega)``, ``u = (d, delta)`` with ``d`` in [-1, 1] (negative
brakes) and ``delta`` the steering angle [rad]. The kinematics (s', n', mu') are the paper's.

Parameters: ``params/racecar.ini`` of TUM FTM's global_racetrajectory_optimization
(https://github.com/TUMFTM/global_racetrajectory_optimization; A. Heilmeier, A. Wischnewski et
al., "Minimum curvature trajectory planning and control for an autonomous race car", Vehicle
System Dynamics 58(10), 2020, and C. Christ, A. Wischnewski, A. Heilmeier, B. Lohmann,
"Time-optimal trajectory planning for a race car considering variable tyre-road friction
coefficients", Vehicle System Dynamics 59(4), 2021): ``veh_params``,
``vehicle_params_mintime`` and ``tire_params_mintime``. Every figure of the issue was checked
against that file and agrees. The tyre law is the one of its ``opt_mintime_traj/src/
opt_mintime.py``: ``D = mu F_z (1 + eps F_z / F_z0)`` per tyre, which differs from the
textbook form ``mu F_z (1 + eps (F_z - F_z0) / F_z0)``: with ``eps = -0.1`` TUM's tyre grips
10% less at its nominal load. We follow TUM (the figures were made for it);
``Fz_shift = Fz0`` gives the textbook form.

Force law (axle forces, ``L = lf + lr``; ``f_w``, ``f_d`` are the wake's drag and downforce
factors of :mod:`racing_env.wake`, 1 in clean air)::

    Fz_f = m g lr / L + c_lift_f f_d vx^2          Fz_r = m g lf / L + c_lift_r f_d vx^2
    D_a  = 2 mu (Fz_a / 2) (1 + eps_a (Fz_a / 2 - Fz_shift) / Fz0)     (two tyres per axle)
    F_ay0 = fade D_a sin(C_a atan(B_a alpha_a - E_a (B_a alpha_a - atan(B_a alpha_a))))
    F_drive = max(d, 0) min(F_drive_max, P_max / vx_eff)                         (rear axle)
    F_brake = min(d, 0) F_brake_max tanh(vx / v_low), front share k_brake_front
    F_ax = sat(F_ax_demand, D_a),  F_ay = F_ay0 sqrt((1 - (F_ax / D_a)^2 + e) / (1 + e))
    F_res = c_drag f_w vx^2 + c_roll m g tanh(vx / v_low)

    vx'    = (F_rx + F_fx cos delta - F_fy sin delta - F_res) / m + vy omega
    vy'    = (F_ry + F_fx sin delta + F_fy cos delta) / m - vx omega
    omega' = ((F_fy cos delta + F_fx sin delta) lf - F_ry lr) / Iz

with the ORCA model's slip angles on ``vx_eff = sqrt(vx^2 + v_low^2)`` and its lateral fade
``fade = v^2 / (v^2 + v_low^2)`` (see :mod:`racing_env.vehicle`), ``sat(x, D) = min(max(x,
-D), D)`` and ``e = 1e-4``.

Departures from the paper's structure (the ORCA force law), each with its reason:

* **Power-limited drive, not (C1 - C2 vx) d.** A full-size car is limited by its engine power
  at speed (``P_max / vx``) and by traction and gearing near standstill (``F_drive_max``);
  the power term uses ``vx_eff``, so it is finite at rest (where the 7 kN cap applies).
* **Brakes on both axles**, 60% front (``k_brake_front``); the front share acts along the
  steered wheel, so it also enters vy' and omega'. Faded at standstill by ``tanh(vx/v_low)``
  as in the ORCA model: a brake stops a car, it never drives it backwards.
* **Load-dependent grip with aerodynamic downforce.** The ORCA car's tyre peaks ``Df, Dr``
  are constants; here each axle's load is its static share plus its downforce (scaled by the
  wake), and the peak follows TUM's load sensitivity per tyre, half the axle load on each.
  No load transfer (longitudinal or lateral): it needs the centre-of-gravity height and roll
  split and makes the load depend on the forces it limits; without it the grip is a function
  of speed alone (what the g-g-v envelope and the hand-derived tests rely on). TUM's
  minimum-time model includes it; ignoring it overstates the grip of a corner by about 2.5%
  at 1 g (estimated with its c.g. height 0.38 m, track 1.6 m and roll split 0.5: the loaded
  outer tyre gains less grip than the inner one loses).
* **A friction ellipse on both axles.** The ORCA model has none (the paper's law lets its
  motor force, C1 = 0.29 N, exceed the rear tyre peak, Dr = 0.17 N, without cost). Here the
  drive force (7 kN) exceeds the rear grip at a standing start (5.6 kN) and the front brakes
  (12 kN) exceed the front grip at every speed the car reaches (5.0 kN at rest, 6.5 kN at
  66 m/s): without a limit the car would launch and brake at 1.7 g on 1 g tyres. The
  longitudinal demand is saturated at the axle's peak ``D_a`` and the lateral force scaled
  by the ellipse ``sqrt(1 - (F_x/D)^2)`` (regularised by ``e``, so CasADi's derivative stays
  finite at full saturation, where 1% of the lateral force is left). The issue asked for the
  driven (rear) axle; the front brakes need it as much, so both axles have it.
* **Drag and rolling resistance** as in TUM: ``c_drag vx^2`` (``c_drag = 0.5 rho c_w A``)
  times the wake's drag factor, and ``c_roll m g`` with the ORCA model's smooth sign.
* **``v_low = 0.5 m/s``**, not 0.1: the lateral dynamics' stiffness at rest is about
  ``C_alpha / (m 2 v_low)`` and a full-size car's cornering stiffness per mass is 5x the
  ORCA car's, so 0.1 m/s would need 140 RK4 sub-steps per 0.1 s (more than the simulator's
  cap of 100); 0.5 m/s needs 31 and changes the slip angles by under 0.5% above 5 m/s.

:func:`frenet_ode_fullsize` is the single source of these equations; like
:func:`racing_env.vehicle.frenet_ode` it calls its maths through the module global ``M`` and
:func:`racing_env.vehicle.bind` makes the numpy / math (numba) / casadi copies.
"""

from __future__ import annotations

import math
import sys
from dataclasses import asdict, dataclass, fields
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from ..vehicle import bind

if TYPE_CHECKING:
    from collections.abc import Callable
    from typing import Any

M = math  # the maths backend of frenet_ode_fullsize; replaced per copy by bind()

if sys.version_info >= (3, 11):
    from math import cbrt as _cbrt
else:  # math.cbrt is new in Python 3.11

    def _cbrt(x: float) -> float:
        return math.copysign(abs(x) ** (1.0 / 3.0), x)


# indices into the packed parameter vector (see FullSizeParams.pack)
(
    P_M,  # mass [kg]
    P_IZ,  # yaw inertia [kg m^2]
    P_LF,  # centre of mass to front axle [m]
    P_LR,  # centre of mass to rear axle [m]
    P_PMAX,  # engine power [W]
    P_FDRIVE,  # drive force cap [N]
    P_FBRAKE,  # brake force cap [N]
    P_KBF,  # front share of the brake force [-]
    P_CDRAG,  # 0.5 rho c_w A [kg/m]
    P_CLF,  # 0.5 rho c_l A front [kg/m]
    P_CLR,  # 0.5 rho c_l A rear [kg/m]
    P_MU,  # tyre-road friction [-]
    P_BF,  # Magic Formula front B, C, E, eps
    P_CF,
    P_EF,
    P_EPSF,
    P_BR,  # Magic Formula rear B, C, E, eps
    P_CR,
    P_ER,
    P_EPSR,
    P_FZ0,  # nominal tyre load [N]
    P_FZSHIFT,  # load where D = mu F_z exactly [N] (0: TUM's form)
    P_CROLL,  # rolling resistance coefficient [-]
    P_G,  # gravity [m/s^2]
    P_VLOW,  # low-speed regularisation [m/s]
) = range(25)
N_PARAMS = 25
"""Length of the full-size parameter vector (the ORCA vector has 15: the two never mix up)."""

ELLIPSE_EPS = 1e-4  # regularisation of the friction ellipse (see the module docstring)

# RK4 sub-step rule (see n_substeps_fullsize and docs/fullsize.md)
SUBSTEP_STABILITY = 2.5  # h * lambda_max <= 2.5 / gain (RK4 is stable to about 2.8)
MIN_SUBSTEPS = 4  # accuracy floor at racing speed: 25 ms steps


@dataclass(frozen=True)
class FullSizeParams:
    """Physical parameters of a full-size single-seater (defaults: TUM FTM ``racecar.ini``)."""

    m: float = 1200.0  # mass [kg]
    Iz: float = 1200.0  # yaw moment of inertia [kg m^2]
    lf: float = 1.6  # centre of mass to front axle [m] (wheelbase_front)
    lr: float = 1.4  # centre of mass to rear axle [m] (wheelbase_rear)
    P_max: float = 230e3  # engine power at the wheels [W]
    F_drive_max: float = 7e3  # drive force cap [N] (rear axle)
    F_brake_max: float = 20e3  # brake force cap [N] (both axles)
    k_brake_front: float = 0.6  # front share of the brake force [-]
    c_drag: float = 0.75  # 0.5 rho c_w A [kg/m]
    c_lift_f: float = 0.45  # 0.5 rho c_l A, front axle downforce [kg/m]
    c_lift_r: float = 0.75  # 0.5 rho c_l A, rear axle downforce [kg/m]
    mu: float = 1.0  # tyre-road friction [-] (optim_opts_mintime.mue)
    B_f: float = 10.0  # Magic Formula front stiffness factor B [1/rad]
    C_f: float = 2.5  # Magic Formula front shape factor C [-]
    E_f: float = 1.0  # Magic Formula front curvature factor E [-]
    eps_f: float = -0.1  # front load sensitivity of D [-]
    B_r: float = 10.0  # Magic Formula rear B [1/rad]
    C_r: float = 2.5  # Magic Formula rear C [-]
    E_r: float = 1.0  # Magic Formula rear E [-]
    eps_r: float = -0.1  # rear load sensitivity of D [-]
    Fz0: float = 3000.0  # nominal tyre load [N]
    Fz_shift: float = 0.0  # [N] D = mu Fz (1 + eps (Fz - Fz_shift) / Fz0); 0 = TUM, Fz0 = textbook
    c_roll: float = 0.013  # rolling resistance coefficient [-]
    g: float = 9.81  # gravity [m/s^2]
    v_low: float = 0.5  # low-speed regularisation of slip, fade and sign [m/s]
    length: float = 4.7  # body length [m]
    width: float = 2.0  # body width [m]
    d_min: float = -1.0  # throttle bounds [-]; negative brakes
    d_max: float = 1.0
    delta_max: float = 0.35  # steering bound [rad], symmetric
    delta_rate_max: float = 1.75  # steering-rate bound [rad/s]: delta_max / TUM's t_delta 0.2 s

    def peak_slip(self, axle: str = "rear") -> float:
        """The slip angle [rad] at which the ``axle``'s ("front" or "rear") Magic Formula
        ``sin(C atan(B a - E (B a - atan(B a))))`` peaks (0.0889 rad for B 10, C 2.5, E 1);
        past it the tyre's lateral force falls (to 59% of the peak for these factors)."""
        if axle not in ("front", "rear"):
            raise ValueError(f"axle must be 'front' or 'rear', got {axle!r}")
        B, C, E = (
            (self.B_f, self.C_f, self.E_f) if axle == "front" else (self.B_r, self.C_r, self.E_r)
        )
        a = np.linspace(1e-4, 1.0, 20001)
        ba = B * a
        y = np.sin(C * np.arctan(ba - E * (ba - np.arctan(ba))))
        return float(a[int(np.argmax(y))])

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"FullSizeParams.{f.name} must be a finite number, got {v!r}")
            if f.name in ("d_min", "eps_f", "eps_r"):
                continue
            if f.name == "Fz_shift":
                if v < 0:
                    raise ValueError(f"FullSizeParams.Fz_shift must be >= 0, got {v}")
            elif v <= 0:
                raise ValueError(f"FullSizeParams.{f.name} must be positive, got {v}")
        if not self.d_min < self.d_max:
            raise ValueError(
                f"FullSizeParams needs d_min < d_max, got {self.d_min} >= {self.d_max}"
            )
        if self.k_brake_front > 1:
            raise ValueError(
                f"FullSizeParams.k_brake_front must be in (0, 1], got {self.k_brake_front}"
            )
        for name in ("E_f", "E_r"):
            if getattr(self, name) > 1:
                raise ValueError(f"FullSizeParams.{name} must be <= 1, got {getattr(self, name)}")
        # the load sensitivity must leave every tyre some grip up to 1.5x the top speed
        v = 1.5 * self.top_speed()
        for axle, (fz, eps) in zip(
            ("front", "rear"), zip(self.static_loads(v), (self.eps_f, self.eps_r))
        ):
            k = 1.0 + eps * (0.5 * fz - self.Fz_shift) / self.Fz0
            if not k > 0:
                raise ValueError(
                    f"FullSizeParams: eps_{axle[0]} = {eps} leaves the {axle} tyres no grip "
                    f"at {v:.0f} m/s (1 + eps (Fz - Fz_shift) / Fz0 = {k:.3f})"
                )

    @property
    def wheelbase(self) -> float:
        return self.lf + self.lr

    def pack(self) -> np.ndarray:
        """Parameter vector in the order of the ``P_*`` indices, shape (N_PARAMS,)."""
        return np.array(
            [
                self.m,
                self.Iz,
                self.lf,
                self.lr,
                self.P_max,
                self.F_drive_max,
                self.F_brake_max,
                self.k_brake_front,
                self.c_drag,
                self.c_lift_f,
                self.c_lift_r,
                self.mu,
                self.B_f,
                self.C_f,
                self.E_f,
                self.eps_f,
                self.B_r,
                self.C_r,
                self.E_r,
                self.eps_r,
                self.Fz0,
                self.Fz_shift,
                self.c_roll,
                self.g,
                self.v_low,
            ],
            dtype=np.float64,
        )

    def to_dict(self) -> dict:
        return asdict(self)

    def static_loads(self, v: float = 0.0, downforce_factor: float = 1.0) -> tuple[float, float]:
        """Axle loads (front, rear) [N] at speed ``v`` [m/s]: static share plus downforce."""
        w = self.m * self.g / self.wheelbase
        q = downforce_factor * v * v
        return w * self.lr + self.c_lift_f * q, w * self.lf + self.c_lift_r * q

    def axle_grip(self, v: float = 0.0, downforce_factor: float = 1.0) -> tuple[float, float]:
        """Peak lateral (or longitudinal) force of each axle (front, rear) [N] at speed ``v``."""
        out = []
        for fz, eps in zip(self.static_loads(v, downforce_factor), (self.eps_f, self.eps_r)):
            t = 0.5 * fz
            out.append(2.0 * self.mu * t * (1.0 + eps * (t - self.Fz_shift) / self.Fz0))
        return out[0], out[1]

    def top_speed(self, drag_factor: float = 1.0) -> float:
        """Speed [m/s] where the drive force balances drag and rolling resistance on a straight.

        Power-limited: ``P_max = (c_drag f v^2 + c_roll m g) v``, the positive root of the
        cubic (Cardano); if that lies below ``P_max / F_drive_max`` the force cap binds and
        ``F_drive_max = c_drag f v^2 + c_roll m g``. (The model's own equilibrium uses
        ``vx_eff`` and ``tanh``: it differs by ~1e-5 relative.) Traction does not bind there.
        """
        if not (math.isfinite(drag_factor) and drag_factor > 0):
            raise ValueError(f"drag_factor must be a positive number, got {drag_factor!r}")
        c = self.c_drag * drag_factor
        r = self.c_roll * self.m * self.g
        p, q = r / c, -self.P_max / c  # v^3 + p v + q = 0, one real root (p > 0)
        disc = math.sqrt(q * q / 4.0 + p**3 / 27.0)
        v = _cbrt(-q / 2.0 + disc) + _cbrt(-q / 2.0 - disc)
        if v * self.F_drive_max < self.P_max:
            v = math.sqrt(max(self.F_drive_max - r, 0.0) / c)
        return float(v)

    def stiffness(self, vx: float | np.ndarray) -> float | np.ndarray:
        """Rough largest eigenvalue [1/s] of the lateral/yaw dynamics at speed vx (for sub-steps);
        the same formula as :func:`n_substeps_fullsize`."""
        return _stiffness(np.asarray(vx, dtype=float), self.pack())


def frenet_ode_fullsize(
    n: Any,
    mu: Any,
    vx: Any,
    vy: Any,
    omega: Any,
    d: Any,
    delta: Any,
    kappa: Any,
    p: Any,
    drag_factor: Any = 1.0,
    downforce_factor: Any = 1.0,
) -> tuple[Any, Any, Any, Any, Any, Any]:
    """Time derivatives (s', n', mu', vx', vy', omega') of the full-size car (module docstring).

    Arguments as :func:`racing_env.vehicle.frenet_ode`, ``p`` from :meth:`FullSizeParams.pack`;
    ``drag_factor`` and ``downforce_factor`` are the wake's multipliers (1 = clean air).
    """
    lf, lr, m = p[P_LF], p[P_LR], p[P_M]
    v_low = p[P_VLOW]
    # axle loads: static share plus downforce; peak force D per axle (two tyres, TUM's law)
    q = downforce_factor * vx * vx
    w = m * p[P_G] / (lf + lr)
    tf = 0.5 * (w * lr + p[P_CLF] * q)  # per tyre
    tr = 0.5 * (w * lf + p[P_CLR] * q)
    d_f = 2.0 * p[P_MU] * tf * (1.0 + p[P_EPSF] * (tf - p[P_FZSHIFT]) / p[P_FZ0])
    d_r = 2.0 * p[P_MU] * tr * (1.0 + p[P_EPSR] * (tr - p[P_FZSHIFT]) / p[P_FZ0])
    # slip angles and lateral Magic Formula (ORCA's standing-start regularisations)
    vx_eff = M.sqrt(vx * vx + v_low * v_low)
    ba_f = p[P_BF] * (delta - M.atan((omega * lf + vy) / vx_eff))
    ba_r = p[P_BR] * M.atan((omega * lr - vy) / vx_eff)
    yaw_v = 0.5 * (lf + lr) * omega
    v2 = vx * vx + vy * vy + yaw_v * yaw_v
    fade = v2 / (v2 + v_low * v_low)
    y_f = M.sin(p[P_CF] * M.atan(ba_f - p[P_EF] * (ba_f - M.atan(ba_f))))
    y_r = M.sin(p[P_CR] * M.atan(ba_r - p[P_ER] * (ba_r - M.atan(ba_r))))
    # longitudinal demand: power-limited drive (rear), brakes faded at standstill (both axles)
    stop = M.tanh(vx / v_low)  # smooth sgn(vx)
    d_drive, d_brake = 0.5 * (d + M.fabs(d)), 0.5 * (d - M.fabs(d))
    f_pow = p[P_PMAX] / vx_eff
    f_cap = 0.5 * (p[P_FDRIVE] + f_pow - M.fabs(p[P_FDRIVE] - f_pow))  # min(F_drive_max, P/v)
    f_brake = d_brake * p[P_FBRAKE] * stop
    fx_r = d_drive * f_cap + (1.0 - p[P_KBF]) * f_brake
    fx_f = p[P_KBF] * f_brake
    # friction ellipse per axle: longitudinal saturated at D, lateral scaled by what is left
    fx_r = 0.5 * (M.fabs(fx_r + d_r) - M.fabs(fx_r - d_r))
    fx_f = 0.5 * (M.fabs(fx_f + d_f) - M.fabs(fx_f - d_f))
    r_r, r_f = fx_r / d_r, fx_f / d_f
    e = ELLIPSE_EPS
    f_ry = fade * d_r * y_r * M.sqrt((1.0 - r_r * r_r + e) / (1.0 + e))
    f_fy = fade * d_f * y_f * M.sqrt((1.0 - r_f * r_f + e) / (1.0 + e))
    f_res = p[P_CDRAG] * drag_factor * vx * vx + p[P_CROLL] * m * p[P_G] * stop
    sin_mu, cos_mu = M.sin(mu), M.cos(mu)
    sin_d, cos_d = M.sin(delta), M.cos(delta)
    s_dot = (vx * cos_mu - vy * sin_mu) / (1.0 - n * kappa)
    n_dot = vx * sin_mu + vy * cos_mu
    mu_dot = omega - kappa * s_dot
    vx_dot = (fx_r + fx_f * cos_d - f_fy * sin_d - f_res) / m + vy * omega
    vy_dot = (f_ry + fx_f * sin_d + f_fy * cos_d) / m - vx * omega
    omega_dot = ((f_fy * cos_d + fx_f * sin_d) * lf - f_ry * lr) / p[P_IZ]
    return s_dot, n_dot, mu_dot, vx_dot, vy_dot, omega_dot


frenet_ode_fullsize_numpy = bind(frenet_ode_fullsize, np)
""":func:`frenet_ode_fullsize` on numpy arrays (batched over any leading shape)."""

frenet_ode_fullsize_math = bind(frenet_ode_fullsize, math)
""":func:`frenet_ode_fullsize` on Python floats with ``math``: the copy numba compiles."""

for _copy in (frenet_ode_fullsize_numpy, frenet_ode_fullsize_math):
    _copy.__annotations__ = dict(frenet_ode_fullsize.__annotations__)  # bind() copies code only

ode_fullsize = njit(cache=True)(frenet_ode_fullsize_math)
"""The numba-compiled scalar copy (what a simulator kernel calls)."""


def frenet_ode_fullsize_casadi() -> Callable[..., tuple]:
    """:func:`frenet_ode_fullsize` on CasADi symbols (imports casadi lazily)."""
    import casadi

    return bind(frenet_ode_fullsize, casadi)


def casadi_model_fullsize(params: FullSizeParams | None = None) -> Any:
    """CasADi ``Function('f', [x(6), u(2), kappa, wake(2)], [x_dot(6)])``; ``wake`` is
    ``(drag_factor, downforce_factor)``."""
    import casadi

    p = [float(v) for v in (params or FullSizeParams()).pack()]
    x = casadi.SX.sym("x", 6)
    u = casadi.SX.sym("u", 2)
    kappa = casadi.SX.sym("kappa")
    wake = casadi.SX.sym("wake", 2)
    dx = frenet_ode_fullsize_casadi()(
        x[1], x[2], x[3], x[4], x[5], u[0], u[1], kappa, p, wake[0], wake[1]
    )
    return casadi.Function(
        "frenet_ode_fullsize",
        [x, u, kappa, wake],
        [casadi.vertcat(*dx)],
        ["x", "u", "kappa", "wake"],
        ["x_dot"],
    )


def _stiffness(vx, p):
    """Largest eigenvalue estimate [1/s]: lateral/yaw ``C_alpha (1/(m v) + l^2/(Iz v))`` with
    the cornering stiffness ``B C D`` at the downforce of ``vx`` (clean air: the most), plus the
    faded brake's ``F_brake_max / (m v_low)`` near standstill."""
    w = p[P_M] * p[P_G] / (p[P_LF] + p[P_LR])
    tf = 0.5 * (w * p[P_LR] + p[P_CLF] * vx * vx)
    tr = 0.5 * (w * p[P_LF] + p[P_CLR] * vx * vx)
    d_f = 2.0 * p[P_MU] * tf * (1.0 + p[P_EPSF] * (tf - p[P_FZSHIFT]) / p[P_FZ0])
    d_r = 2.0 * p[P_MU] * tr * (1.0 + p[P_EPSR] * (tr - p[P_FZSHIFT]) / p[P_FZ0])
    ca_f = p[P_BF] * p[P_CF] * d_f
    ca_r = p[P_BR] * p[P_CR] * d_r
    v_low = p[P_VLOW]
    v = (vx * vx + 4.0 * v_low * v_low) ** 0.5  # the fade caps C / (m v) near v = 2 v_low
    lat = (ca_f + ca_r) / (p[P_M] * v) + (ca_f * p[P_LF] ** 2 + ca_r * p[P_LR] ** 2) / (p[P_IZ] * v)
    brake = p[P_FBRAKE] / p[P_M] * v_low / (vx * vx + v_low * v_low)
    return lat + brake


_stiffness_nb = njit(cache=True)(_stiffness)


@njit(cache=True)
def n_substeps_fullsize(vx, p, dt, gain, max_sub):
    """RK4 sub-steps per control period: ``h lambda_max <= SUBSTEP_STABILITY / gain``, at least
    ``MIN_SUBSTEPS`` (accuracy at racing speed, see the notes), at most ``max_sub``."""
    lam = _stiffness_nb(vx, p)
    k = int(math.ceil(dt * lam * gain / SUBSTEP_STABILITY))
    return min(max(k, MIN_SUBSTEPS), max_sub)


@njit(cache=True)
def rk4_fullsize(x, d, delta, kappa, p, dt, n_sub, drag_factor=1.0, downforce_factor=1.0):
    """Advance one car's state ``x`` (6,) in place over ``dt`` with ``n_sub`` classical RK4
    steps at constant curvature ``kappa`` and wake factors (``vx >= 0``, as the simulator)."""
    h = dt / n_sub
    y = np.empty(6)
    for _ in range(n_sub):
        k1 = ode_fullsize(
            x[1], x[2], x[3], x[4], x[5], d, delta, kappa, p, drag_factor, downforce_factor
        )
        for j in range(6):
            y[j] = x[j] + 0.5 * h * k1[j]
        k2 = ode_fullsize(
            y[1], y[2], y[3], y[4], y[5], d, delta, kappa, p, drag_factor, downforce_factor
        )
        for j in range(6):
            y[j] = x[j] + 0.5 * h * k2[j]
        k3 = ode_fullsize(
            y[1], y[2], y[3], y[4], y[5], d, delta, kappa, p, drag_factor, downforce_factor
        )
        for j in range(6):
            y[j] = x[j] + h * k3[j]
        k4 = ode_fullsize(
            y[1], y[2], y[3], y[4], y[5], d, delta, kappa, p, drag_factor, downforce_factor
        )
        for j in range(6):
            x[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        if x[3] < 0.0:
            x[3] = 0.0
