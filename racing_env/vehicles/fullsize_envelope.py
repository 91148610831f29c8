"""The full-size class's g-g-v envelope: quasi-steady cornering of its force law.

:func:`racing_env.envelope.ggv` hands a :class:`~racing_env.vehicles.fullsize.FullSizeParams`
to :func:`fullsize_tables` and wraps the tables in the same :class:`~racing_env.envelope.GGV`
as the ORCA car's (speed grid ``v``, ``ay_max``, lateral fractions ``r``, ``ax_max`` and
``ax_min``), so the racing line's speed profile (:mod:`racing_env.raceline.speed`) reads it
unchanged. The equations are those of :func:`~racing_env.vehicles.fullsize.frenet_ode_fullsize`
(see its module docstring); what depends on speed here is the downforce (the grip of both
axles rises with ``vx^2``), the power limit (``P_max / vx``) and the drag.

**Clean air.** The envelope is the car's alone: the wake's drag and downforce factors are 1.
A follower's grip (less downforce) and top speed (less drag) differ; the racing line is the
line of a car in free air, as the ORCA car's is.

**Quasi-steady cornering.** At path speed ``V`` [m/s] and lateral acceleration ``a_y``
[m/s^2] (yaw rate ``omega = a_y / V``), lateral and yaw equilibrium (``vy' = omega' = 0``)
give the axles' lateral forces::

    F_ry = m vx omega lf / L,      F_fy cos(delta) + F_fx sin(delta) = m vx omega lr / L

Each axle's peak ``D_a(vx)`` follows from its load (static share plus downforce, TUM's load
sensitivity; :meth:`FullSizeParams.axle_grip`), faded at standstill like the force law. The
slip angles are those of the pure corner (no longitudinal force): the rear one (Magic Formula
inverted on its stable side) fixes ``vy``, with ``vx = sqrt(V^2 - vy^2)`` by fixed-point
iteration; the front one plus the front axle's direction of travel fixes the steering angle
``delta``. The point is *feasible* when both axles are within their peaks and
``|delta| <= delta_max`` (the steering bound limits only below about 9 m/s).

**Longitudinal limits** on top of the corner: the friction ellipse of the force law,
``F_y <= fade D sqrt((1 - (F_x / D)^2 + e) / (1 + e))``, leaves each axle the longitudinal
fraction ``r_a <= min(1, sqrt((1 + e)(1 - f_a^2)))`` at lateral fraction ``f_a = F_ay /
(fade D_a)``. Then (``F_res = c_drag vx^2 + c_roll m g tanh(vx / v_low)``)::

    drive: F_rx = min(F_drive_max, P_max / vx_eff, r_r D_r)                       (rear)
           a_x  = (F_rx - F_fy sin(delta) - F_res) / m + vy omega
    brake: F_b  = min(F_brake_max tanh(vx / v_low), r_f D_f / k, r_r D_r / (1 - k)),  k = 0.6
           a_x  = -(F_b (k cos(delta) + 1 - k) + F_fy sin(delta) + F_res) / m + vy omega

where under braking ``F_fy`` carries the front brake force's lateral share (``F_fx = -k F_b``,
a few fixed-point steps). **The brake split binds**: the force law has no longitudinal load
transfer, so with 60% of the brake force on the front axle (47% of the static load) the front
reaches its peak first, at ``F_b = D_f / k``: about 0.7 g at rest, 1.2 g at the top speed.
Past it the front tyres saturate (the force law lets them: the rear could still add force up
to ``D_f + D_r``) but then keep 1% of their lateral force: the car no longer steers. The
envelope keeps every axle within its ellipse, the line a car can still steer on. Likewise
the drive never saturates the rear: at low speed ``ax_max`` is the rear grip (5.6 kN at
rest, under the 7 kN cap), at speed ``P_max / v`` minus drag (the two cross near 36 m/s).

The top speed of the envelope is :meth:`FullSizeParams.top_speed` (where ``P_max / v``
balances drag and rolling resistance). Units: SI (m/s, m/s^2, rad, N).
"""

from __future__ import annotations

import math

import numpy as np

from .fullsize import ELLIPSE_EPS, FullSizeParams

__all__ = ["fullsize_tables", "magic_formula_slip", "steady_corner_fullsize"]


def _mf_arg(x: np.ndarray, E: float) -> np.ndarray:
    """The Magic Formula's inner argument ``x - E (x - atan x)`` of ``x = B alpha``."""
    return x - E * (x - np.arctan(x))


def _mf_peak(C: float, E: float) -> float:
    """``B alpha`` [-] at the Magic Formula's peak (``C atan(.) = pi/2``), by bisection on its
    inner argument (increasing in ``x`` for ``E <= 1``); ``inf`` if it never peaks."""
    target = math.tan(math.pi / (2.0 * C)) if C > 1.0 else math.inf
    if not math.isfinite(target):
        return math.inf
    hi = 1.0
    while float(_mf_arg(np.array(hi), E)) < target:
        hi *= 2.0
        if hi > 1e6:
            return math.inf
    lo = 0.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if float(_mf_arg(np.array(mid), E)) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def magic_formula_slip(y: np.ndarray, B: float, C: float, E: float) -> np.ndarray:
    """Slip angle ``alpha`` [rad] on the stable side of the peak where the Magic Formula
    ``sin(C atan(B alpha - E (B alpha - atan(B alpha))))`` equals ``y`` (in [0, 1]; clipped)."""
    y = np.clip(np.asarray(y, dtype=float), 0.0, 1.0)
    x_peak = _mf_peak(C, E)
    target = np.tan(np.arcsin(y) / C)
    lo = np.zeros_like(target)
    hi = np.full_like(target, x_peak if math.isfinite(x_peak) else 1e3)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = _mf_arg(mid, E) < target
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return 0.5 * (lo + hi) / B


def _axle_peaks(vx: np.ndarray, p: FullSizeParams) -> tuple[np.ndarray, np.ndarray]:
    """Peak force of each axle (front, rear) [N] at ``vx`` [m/s], clean air (vectorised
    :meth:`FullSizeParams.axle_grip`)."""
    w = p.m * p.g / p.wheelbase
    out = []
    for static, c_lift, eps in ((w * p.lr, p.c_lift_f, p.eps_f), (w * p.lf, p.c_lift_r, p.eps_r)):
        t = 0.5 * (static + c_lift * vx * vx)
        out.append(2.0 * p.mu * t * (1.0 + eps * (t - p.Fz_shift) / p.Fz0))
    return out[0], out[1]


def _ellipse_room(f: np.ndarray) -> np.ndarray:
    """Longitudinal fraction ``F_x / D`` an axle has left at lateral fraction ``f`` (of its
    faded peak) under the force law's regularised friction ellipse, at most 1."""
    e = ELLIPSE_EPS
    return np.minimum(1.0, np.sqrt(np.maximum((1.0 + e) * (1.0 - f * f), 0.0)))


def steady_corner_fullsize(
    V: float | np.ndarray,
    ay: float | np.ndarray,
    vehicle: FullSizeParams | None = None,
    *,
    limits: bool = True,
) -> dict[str, np.ndarray]:
    """Quasi-steady cornering of the full-size car at path speed ``V`` [m/s] and lateral
    acceleration ``ay`` [m/s^2] in clean air (arrays broadcast; symmetric in the sign of
    ``ay``); see the module docstring.

    Returns a dict of arrays: ``feasible`` (bool), ``delta`` [rad], ``vx``, ``vy`` [m/s],
    ``omega`` [rad/s], ``f_front``, ``f_rear`` (lateral force as a fraction of the faded
    peak), ``D_front``, ``D_rear`` [N] (axle peaks), ``ax_max``, ``ax_min`` [m/s^2] (drive /
    brake on top of the corner; ``nan`` where infeasible; left out with ``limits=False``).
    """
    p = vehicle or FullSizeParams()
    V = np.asarray(V, dtype=float)
    ay = np.abs(np.asarray(ay, dtype=float))
    V, ay = np.broadcast_arrays(V, ay)
    Vs = np.maximum(V, 1e-6)
    omega = ay / Vs
    L = p.wheelbase
    yaw_v = 0.5 * L * omega
    v2 = Vs * Vs + yaw_v * yaw_v  # vx^2 + vy^2 = V^2
    fade = v2 / (v2 + p.v_low**2)
    ok = np.ones(V.shape, dtype=bool)

    # rear axle: its lateral force fixes the rear slip angle, hence vy; vx^2 + vy^2 = V^2
    vx = Vs.copy()
    for _ in range(20):  # contracts ~100x per step but next to the rear's peak
        d_f, d_r = _axle_peaks(vx, p)
        f_r = p.m * vx * omega * p.lf / L / (fade * d_r)
        alpha_r = magic_formula_slip(f_r, p.B_r, p.C_r, p.E_r)
        vx_eff = np.sqrt(vx * vx + p.v_low**2)
        vy = omega * p.lr - vx_eff * np.tan(alpha_r)
        vx_new = np.sqrt(np.maximum(Vs * Vs - vy * vy, 0.25 * Vs * Vs))
        moved = np.abs(vx_new - vx)[f_r <= 0.999]
        vx = vx_new
        if moved.size == 0 or moved.max() <= 1e-12 * float(Vs.max()):
            break
    d_f, d_r = _axle_peaks(vx, p)
    vx_eff = np.sqrt(vx * vx + p.v_low**2)
    f_r = p.m * vx * omega * p.lf / L / (fade * d_r)
    ok &= f_r <= 1.0
    beta_f = np.arctan((omega * p.lf + vy) / vx_eff)

    def front(f_fx):
        """(F_fy, delta, f_f): the front lateral force, steering and lateral fraction of the
        corner with the front longitudinal force ``f_fx`` [N] (fixed point on delta)."""
        delta = beta_f.copy()
        for _ in range(6):
            f_fy = (p.m * vx * omega * p.lr / L - f_fx * np.sin(delta)) / np.cos(delta)
            f_f = f_fy / (fade * d_f)
            delta = beta_f + magic_formula_slip(f_f, p.B_f, p.C_f, p.E_f)
        return f_fy, delta, f_f

    f_fy, delta, f_f = front(np.zeros_like(vx))
    ok &= (f_f <= 1.0) & (delta <= p.delta_max)
    out = {
        "feasible": ok,
        "delta": delta,
        "vx": vx,
        "vy": vy,
        "omega": omega,
        "f_front": f_f,
        "f_rear": f_r,
        "D_front": d_f,
        "D_rear": d_r,
    }
    if not limits:
        return out
    stop = np.tanh(vx / p.v_low)
    f_res = p.c_drag * vx * vx + p.c_roll * p.m * p.g * stop
    coriolis = vy * omega
    # drive: the rear's force cap, power limit and what its ellipse leaves
    f_rx = np.minimum(np.minimum(p.F_drive_max, p.P_max / vx_eff), _ellipse_room(f_r) * d_r)
    ax_max = (f_rx - f_fy * np.sin(delta) - f_res) / p.m + coriolis
    # brake: the split puts k of F_b on the front, which also needs more lateral force
    k = p.k_brake_front
    room_r = _ellipse_room(f_r) * d_r / (1.0 - k) if k < 1.0 else np.inf
    f_b = np.zeros_like(vx)
    for _ in range(4):
        f_fy_b, delta_b, f_f_b = front(-k * f_b)
        f_b = np.minimum(np.minimum(p.F_brake_max * stop, _ellipse_room(f_f_b) * d_f / k), room_r)
    f_fy_b, delta_b, _ = front(-k * f_b)
    ax_min = (
        -(f_b * (k * np.cos(delta_b) + 1.0 - k) + f_fy_b * np.sin(delta_b) + f_res) / p.m + coriolis
    )
    nan = np.full(V.shape, np.nan)
    out["ax_max"] = np.where(ok, ax_max, nan)
    out["ax_min"] = np.where(ok, ax_min, nan)
    return out


def fullsize_tables(
    vehicle: FullSizeParams, n_speeds: int, n_fractions: int
) -> dict[str, np.ndarray | float]:
    """The envelope's tables (the fields of :class:`racing_env.envelope.GGV`): ``v`` (uniform,
    0 .. 1.05 x the top speed, ``n_speeds``), ``ay_max`` (bisection on feasibility), ``r``
    (``n_fractions`` in [0, 1]), ``ax_max``, ``ax_min`` and ``top_speed``
    (:meth:`FullSizeParams.top_speed`, clean air)."""
    p = vehicle
    top = p.top_speed()
    v = np.linspace(0.0, 1.05 * top, n_speeds)
    vq = np.maximum(v, 0.02)
    d_f, d_r = _axle_peaks(vq, p)
    lo = np.zeros_like(vq)
    hi = 2.0 * (d_f + d_r) / p.m
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        ok = steady_corner_fullsize(vq, mid, p, limits=False)["feasible"]
        lo = np.where(ok, mid, lo)
        hi = np.where(ok, hi, mid)
    ay_max = lo
    r = np.linspace(0.0, 1.0, n_fractions)
    pts = steady_corner_fullsize(vq[:, None], ay_max[:, None] * r[None, :], p)
    return {
        "v": v,
        "ay_max": ay_max,
        "r": r,
        "ax_max": pts["ax_max"],
        "ax_min": pts["ax_min"],
        "top_speed": float(top),
    }
