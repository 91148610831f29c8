"""The paper's dynamic bicycle model (appendix C) in the Frenet frame, written once.

State per car (SI units): ``x = (s, n, mu, vx, vy, omega)``: arc length [m] (unwrapped),
lateral offset [m] (left positive), heading relative to the centre line [rad], body-frame
longitudinal / lateral velocity [m/s], yaw rate [rad/s]. Input ``u = (d, delta)``: throttle
(negative = brake) [-] and steering angle [rad].

Continuous-time model (paper eq. for car i, track curvature ``kappa(s)``)::

    s'     = (vx cos mu - vy sin mu) / (1 - n kappa)
    n'     =  vx sin mu + vy cos mu
    mu'    =  omega - kappa s'
    vx'    = (F_rx - F_fy sin delta + m vy omega) / m
    vy'    = (F_ry + F_fy cos delta - m vx omega) / m
    omega' = (F_fy lf cos delta - F_ry lr) / Iz

    F_rx = (C1 - C2 vx) d - C3 sgn(vx) - C4 vx^2        (drive/brake, rolling resistance, drag)
    F_fy = Df sin(Cf atan(Bf alpha_f)),  alpha_f = delta - atan((omega lf + vy) / vx)
    F_ry = Dr sin(Cr atan(Br alpha_r)),  alpha_r = atan((omega lr - vy) / vx)

Three documented departures, all for standing starts (``v_low`` = 0.1 m/s by default):

* the slip angles use ``vx_eff = sqrt(vx^2 + v_low^2)`` instead of ``vx``, which removes the
  0/0 singularity at vx = 0 (the slip angle changes by under 0.5% above 1 m/s);
* the lateral tyre forces are multiplied by ``v^2 / (v^2 + v_low^2)`` with
  ``v^2 = vx^2 + vy^2 + (omega (lf + lr) / 2)^2``, so a car at rest with its wheels turned is
  not pushed sideways (the factor is over 0.99 above 1 m/s);
* ``sgn(vx)`` is the smooth ``tanh(vx / v_low)``, so rolling resistance does not push a
  stopped car backwards, and the brake (``d < 0``) force is scaled by it too: a brake stops
  a car, it does not drive it backwards (both factors are 1 to 1e-8 above 2 m/s).

All three are smooth, so the same expression serves the MPC.

Parameters: the 1:43 scale ORCA cars of A. Liniger, A. Domahidi, M. Morari, "Optimization-based
autonomous racing of 1:43 scale RC cars", Optimal Control Applications and Methods 36(5),
628-647, 2015 (the model whose force law the paper uses; C1..C4 = Cm1, Cm2, Cr0, Cr2 there).

:func:`frenet_ode` is the single source of the equations. It calls its maths through the module
global ``M``; :func:`bind` makes copies of it that use ``numpy`` (batched arrays), ``math``
(compiled by numba in the simulator) or ``casadi`` (symbolic, for the MPC).
"""

from __future__ import annotations

import math
import types
from dataclasses import asdict, dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable
    from types import ModuleType
    from typing import Any

M = math  # the maths backend of frenet_ode; replaced per copy by bind()

# indices into the packed parameter vector (see VehicleParams.pack)
P_M, P_IZ, P_LF, P_LR, P_C1, P_C2, P_C3, P_C4, P_BF, P_CF, P_DF, P_BR, P_CR, P_DR, P_VLOW = range(
    15
)
N_PARAMS = 15

STATE_NAMES = ("s", "n", "mu", "vx", "vy", "omega")
STATE_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s")
ACTION_NAMES = ("d", "delta")


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters of one car (defaults: Liniger et al. 2015, 1:43 ORCA car)."""

    m: float = 0.041  # mass [kg]
    Iz: float = 27.8e-6  # yaw moment of inertia [kg m^2]
    lf: float = 0.029  # centre of mass to front axle [m]
    lr: float = 0.033  # centre of mass to rear axle [m]
    C1: float = 0.287  # drive force gain [N]
    C2: float = 0.0545  # drive force loss with speed [N s/m]
    C3: float = 0.0518  # rolling resistance [N]
    C4: float = 0.00035  # aerodynamic drag [N s^2/m^2]
    Bf: float = 2.579  # Pacejka front B [-]
    Cf: float = 1.2  # Pacejka front C [-]
    Df: float = 0.192  # Pacejka front D (peak force) [N]
    Br: float = 3.3852  # Pacejka rear B [-]
    Cr: float = 1.2691  # Pacejka rear C [-]
    Dr: float = 0.1737  # Pacejka rear D (peak force) [N]
    v_low: float = 0.1  # low-speed regularisation of slip angles [m/s]
    length: float = 0.12  # body length [m] (contact, rendering)
    width: float = 0.06  # body width [m] (contact, racing line margin, rendering)
    d_min: float = -1.0  # throttle bounds [-]; negative brakes
    d_max: float = 1.0
    delta_max: float = 0.35  # steering bound [rad], symmetric
    delta_rate_max: float = 3.5  # steering-rate bound [rad/s] (used by the MPC)

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"VehicleParams.{f.name} must be a finite number, got {v!r}")
            if f.name not in ("d_min",) and v <= 0:
                raise ValueError(f"VehicleParams.{f.name} must be positive, got {v}")
        if not self.d_min < self.d_max:
            raise ValueError(f"VehicleParams needs d_min < d_max, got {self.d_min} >= {self.d_max}")

    def pack(self) -> np.ndarray:
        """Parameter vector in the order of the ``P_*`` indices, shape (N_PARAMS,)."""
        return np.array(
            [
                self.m,
                self.Iz,
                self.lf,
                self.lr,
                self.C1,
                self.C2,
                self.C3,
                self.C4,
                self.Bf,
                self.Cf,
                self.Df,
                self.Br,
                self.Cr,
                self.Dr,
                self.v_low,
            ]
        )

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def top_speed(self) -> float:
        """Speed [m/s] where full throttle balances resistance and drag on a straight."""
        a, b, c = self.C4, self.C2, self.C3 - self.C1  # C4 v^2 + C2 v + (C3 - C1) = 0
        return float((-b + math.sqrt(b * b - 4 * a * c)) / (2 * a))

    def stiffness(self, vx: float | np.ndarray) -> float | np.ndarray:
        """Rough largest eigenvalue [1/s] of the lateral/yaw dynamics at speed vx (for sub-steps)."""
        ca_f = self.Bf * self.Cf * self.Df
        ca_r = self.Br * self.Cr * self.Dr
        v = np.sqrt(np.asarray(vx) ** 2 + 4.0 * self.v_low**2)  # the fade caps it at v = v_low
        return (ca_f + ca_r) / (self.m * v) + (ca_f * self.lf**2 + ca_r * self.lr**2) / (
            self.Iz * v
        )


def frenet_ode(
    n: Any, mu: Any, vx: Any, vy: Any, omega: Any, d: Any, delta: Any, kappa: Any, p: Any
) -> tuple[Any, Any, Any, Any, Any, Any]:
    """Time derivatives (s', n', mu', vx', vy', omega') of the Frenet bicycle model.

    Arguments are scalars, equally shaped arrays, or CasADi expressions (whichever the bound
    backend handles); ``p`` is the packed parameter vector (:meth:`VehicleParams.pack`).
    ``s`` itself does not enter: the track reaches the model only through ``kappa = kappa(s)``.
    """
    vx_eff = M.sqrt(vx * vx + p[P_VLOW] * p[P_VLOW])
    alpha_f = delta - M.atan((omega * p[P_LF] + vy) / vx_eff)
    alpha_r = M.atan((omega * p[P_LR] - vy) / vx_eff)
    yaw_v = 0.5 * (p[P_LF] + p[P_LR]) * omega
    v2 = vx * vx + vy * vy + yaw_v * yaw_v
    fade = v2 / (v2 + p[P_VLOW] * p[P_VLOW])  # no lateral force at rest
    f_fy = fade * p[P_DF] * M.sin(p[P_CF] * M.atan(p[P_BF] * alpha_f))
    f_ry = fade * p[P_DR] * M.sin(p[P_CR] * M.atan(p[P_BR] * alpha_r))
    stop = M.tanh(vx / p[P_VLOW])  # smooth sgn(vx)
    d_drive, d_brake = 0.5 * (d + M.fabs(d)), 0.5 * (d - M.fabs(d))
    f_rx = (
        (p[P_C1] - p[P_C2] * vx) * (d_drive + d_brake * stop) - p[P_C3] * stop - p[P_C4] * vx * vx
    )
    sin_mu, cos_mu = M.sin(mu), M.cos(mu)
    sin_d, cos_d = M.sin(delta), M.cos(delta)
    s_dot = (vx * cos_mu - vy * sin_mu) / (1.0 - n * kappa)
    n_dot = vx * sin_mu + vy * cos_mu
    mu_dot = omega - kappa * s_dot
    vx_dot = (f_rx - f_fy * sin_d) / p[P_M] + vy * omega
    vy_dot = (f_ry + f_fy * cos_d) / p[P_M] - vx * omega
    omega_dot = (f_fy * p[P_LF] * cos_d - f_ry * p[P_LR]) / p[P_IZ]
    return s_dot, n_dot, mu_dot, vx_dot, vy_dot, omega_dot


def bind(fn: Callable[..., Any], backend: ModuleType) -> Callable[..., Any]:
    """A copy of ``fn`` whose global ``M`` is ``backend`` (numpy, math or casadi)."""
    g = dict(fn.__globals__)
    g["M"] = backend
    return types.FunctionType(fn.__code__, g, fn.__name__, fn.__defaults__, fn.__closure__)


frenet_ode_numpy = bind(frenet_ode, np)
""":func:`frenet_ode` on numpy arrays (batched over any leading shape)."""


def frenet_ode_casadi() -> Callable[..., tuple]:
    """:func:`frenet_ode` on CasADi symbols (imports casadi lazily)."""
    import casadi

    return bind(frenet_ode, casadi)


def casadi_model(params: VehicleParams | None = None) -> Any:
    """CasADi ``Function('f', [x(6), u(2), kappa], [x_dot(6)])`` of the model."""
    import casadi

    p = [float(v) for v in (params or VehicleParams()).pack()]
    x = casadi.SX.sym("x", 6)
    u = casadi.SX.sym("u", 2)
    kappa = casadi.SX.sym("kappa")
    dx = frenet_ode_casadi()(x[1], x[2], x[3], x[4], x[5], u[0], u[1], kappa, p)
    return casadi.Function(
        "frenet_ode", [x, u, kappa], [casadi.vertcat(*dx)], ["x", "u", "kappa"], ["x_dot"]
    )
