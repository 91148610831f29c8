"""The car's own g-g-v envelope: what accelerations the vehicle model can hold at each speed.

A racing line's speed profile is only drivable if it asks for accelerations the car can
produce. For the paper's bicycle model (:mod:`racing_env.vehicle`) these depend strongly on
speed: at low speed the steering bound limits the curvature, at high speed the motor force
falls off (``C1 - C2 v``) against rolling resistance, drag and the drag of the front tyre's
lateral force. A point mass with a friction coefficient ("0.85 g") misses all of that.

**Quasi-steady cornering.** At path speed ``V`` [m/s] and lateral acceleration ``a_y``
[m/s^2] (a circle of curvature ``a_y / V^2`` driven with yaw rate ``omega = a_y / V``), the
lateral and yaw equations of the model are in equilibrium (``vy' = 0``, ``omega' = 0``)::

    F_ry + F_fy cos(delta) = m vx omega,     F_fy lf cos(delta) = F_ry lr
    =>  F_ry = m vx omega lf / (lf + lr),   F_fy cos(delta) = m vx omega lr / (lf + lr)

The rear force fixes the rear slip angle on the stable side of the Pacejka peak, hence
``vy``; the front force fixes the front slip angle, hence the steering angle ``delta``
(a few fixed-point steps for ``cos(delta)``), and ``vx = sqrt(V^2 - vy^2)``. The point is
*feasible* when both tyres are within their (low-speed faded) peaks and
``|delta| <= delta_max``. The longitudinal equation then gives the accelerations the motor
and brake can add on top of that corner (the model has no combined slip on the rear axle;
the front tyre's lateral force drags through ``sin(delta)``)::

    a_x = (F_rx(vx, d) - F_fy sin(delta)) / m + vy omega,   d = d_max (drive) or d_min (brake)

**The envelope** (:class:`GGV`), computed once per :class:`~racing_env.vehicle.VehicleParams`
and cached in memory (:func:`ggv`): on a speed grid ``v`` (0 .. a little above the top speed),

* ``ay_max[i]``: the largest feasible ``a_y`` at ``v[i]`` (bisection; feasibility is monotone
  in ``a_y``);
* ``ax_max[i, j]``, ``ax_min[i, j]``: drive and brake accelerations [m/s^2] at ``v[i]`` and
  ``a_y = r[j] ay_max[i]`` (``r`` in [0, 1]). ``ax_max`` is negative where the motor cannot hold
  the speed in that corner (the car slows through it), ``ax_min`` is always negative.

A *scaled* envelope (grip factor ``grip`` in (0, 1.5]; ``mu`` before 0.x, which names the
heading in the state) multiplies every acceleration by ``grip``: the
racing line's speed library (:mod:`racing_env.raceline`) holds profiles over ``grip``, ``grip = 1``
being the car's own limit. Units: SI (m/s, m/s^2, rad).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import overload

import numpy as np
from numba import njit

from .vehicle import VehicleParams
from .vehicles.fullsize import FullSizeParams
from .vehicles.fullsize_envelope import fullsize_tables

__all__ = ["GGV", "envelope_at", "ggv", "steady_corner"]

N_SPEEDS = 240
"""Points of the speed grid of :func:`ggv`."""
N_FRACTIONS = 41
"""Points of the lateral-fraction grid ``r`` of :func:`ggv`."""


@overload
def grip_arg(grip: float | None, mu: float | None, where: str, default: float) -> float: ...
@overload
def grip_arg(
    grip: float | None, mu: float | None, where: str, default: None = None
) -> float | None: ...
def grip_arg(
    grip: float | None, mu: float | None, where: str, default: float | None = None
) -> float | None:
    """The envelope scale of a call that takes ``grip`` and still accepts its old name ``mu``
    (which now names only the heading in the state): ``mu`` given warns (DeprecationWarning
    naming ``grip``) and is used; both given is a ValueError. ``default``: the value when
    neither is given (None: ``grip`` as passed)."""
    if mu is None:
        return default if grip is None else grip
    import warnings

    if grip is not None and grip != default:
        raise ValueError(
            f"{where}: give the envelope scale once, as grip= (mu= is its old "
            f"name), got grip={grip!r} and mu={mu!r}"
        )
    warnings.warn(
        f"{where}: mu= is deprecated as the envelope (grip) scale, use grip={mu!r} "
        f"(mu names the heading in the state)",
        DeprecationWarning,
        stacklevel=3,
    )
    return mu


def steady_corner(
    V: float | np.ndarray, ay: float | np.ndarray, vehicle: VehicleParams | None = None
) -> dict[str, np.ndarray]:
    """Quasi-steady cornering at path speed ``V`` [m/s] and lateral acceleration ``ay`` [m/s^2]
    (arrays broadcast; the sign of ``ay`` is the turn direction, the result is symmetric).

    Returns a dict of arrays (broadcast shape): ``feasible`` (bool), ``delta`` [rad] steering,
    ``vx``, ``vy`` [m/s], ``omega`` [rad/s], ``f_front``, ``f_rear`` (tyre force as a fraction
    of its peak), ``ax_max``, ``ax_min`` [m/s^2] (drive / brake longitudinal acceleration on top
    of the corner). Infeasible points carry ``nan`` in the accelerations.
    """
    p = vehicle or VehicleParams()
    V = np.asarray(V, dtype=float)
    ay = np.abs(np.asarray(ay, dtype=float))
    V, ay = np.broadcast_arrays(V, ay)
    Vs = np.maximum(V, 1e-6)
    omega = ay / Vs
    wb = p.lf + p.lr
    yaw_v = 0.5 * wb * omega
    fade = (Vs * Vs + yaw_v * yaw_v) / (Vs * Vs + yaw_v * yaw_v + p.v_low**2)  # vx^2 + vy^2 = V^2

    def rear(vx):
        """(f_r, vy): the rear force the corner needs (fraction of its peak) and the lateral
        velocity whose slip angle gives it (stable side of the peak)."""
        f_r = p.m * vx * omega * p.lf / wb / (fade * p.Dr)
        alpha_r = np.tan(np.arcsin(np.clip(f_r, -1.0, 1.0)) / p.Cr) / p.Br
        return f_r, omega * p.lr - np.sqrt(vx * vx + p.v_low**2) * np.tan(alpha_r)

    # vx solves vx^2 + vy(vx)^2 = V^2; bisection on [V/2, V] (body slip below 60 degrees)
    def excess(vx):
        return vx * vx + rear(vx)[1] ** 2 - Vs * Vs

    lo, hi = 0.5 * Vs, Vs.copy()
    ok = excess(lo) <= 0.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        below = excess(mid) <= 0.0
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    vx = 0.5 * (lo + hi)
    f_r, vy = rear(vx)
    ok &= np.abs(f_r) <= 1.0
    vx_eff = np.sqrt(vx * vx + p.v_low**2)
    # steering: F_fy(delta - beta_f) cos(delta) = m vx omega lr / (lf + lr), by bisection on
    # delta between beta_f and the smaller of the steering bound and the front tyre's peak
    # (the product rises with delta there: cos(delta) > 0.9)
    target = p.m * vx * omega * p.lr / wb
    beta_f = np.arctan((omega * p.lf + vy) / vx_eff)
    alpha_peak_f = math.tan(math.pi / (2.0 * p.Cf)) / p.Bf

    def front(d):
        return fade * p.Df * np.sin(p.Cf * np.arctan(p.Bf * (d - beta_f)))

    d_lo = beta_f
    d_hi = np.maximum(np.minimum(beta_f + alpha_peak_f, p.delta_max), beta_f)
    ok &= front(d_hi) * np.cos(d_hi) >= target * (1.0 - 1e-12)
    for _ in range(50):
        mid = 0.5 * (d_lo + d_hi)
        up = front(mid) * np.cos(mid) < target
        d_lo = np.where(up, mid, d_lo)
        d_hi = np.where(up, d_hi, mid)
    delta = 0.5 * (d_lo + d_hi)
    f_fy = front(delta)
    f_f = f_fy / (fade * p.Df)
    stop = np.tanh(vx / p.v_low)
    resist = p.C3 * stop + p.C4 * vx * vx
    lateral_drag = f_fy * np.sin(delta) / p.m - vy * omega
    ax_max = ((p.C1 - p.C2 * vx) * p.d_max - resist) / p.m - lateral_drag
    ax_min = ((p.C1 - p.C2 * vx) * p.d_min * stop - resist) / p.m - lateral_drag
    nan = np.full(V.shape, np.nan)
    return {
        "feasible": ok,
        "delta": delta,
        "vx": vx,
        "vy": vy,
        "omega": omega,
        "f_front": f_f,
        "f_rear": f_r,
        "ax_max": np.where(ok, ax_max, nan),
        "ax_min": np.where(ok, ax_min, nan),
    }


@dataclass(frozen=True, eq=False)
class GGV:
    """A g-g-v envelope on a grid (see the module docstring).

    ``v`` (I,) speeds [m/s] from 0; ``ay_max`` (I,) [m/s^2]; ``r`` (J,) fractions of
    ``ay_max`` in [0, 1]; ``ax_max``, ``ax_min`` (I, J) [m/s^2]; ``top_speed`` [m/s] where the
    motor balances resistance on a straight.
    """

    v: np.ndarray
    ay_max: np.ndarray
    r: np.ndarray
    ax_max: np.ndarray
    ax_min: np.ndarray
    top_speed: float

    def lateral_limit(
        self, v: float | np.ndarray, grip: float = 1.0, *, mu: float | None = None
    ) -> float | np.ndarray:
        """Largest lateral acceleration [m/s^2] at speed ``v`` [m/s] (any shape), scaled by
        ``grip`` (``mu``: deprecated name of ``grip``)."""
        grip = grip_arg(grip, mu, "lateral_limit", 1.0)
        return grip * np.interp(v, self.v, self.ay_max)

    def longitudinal_limits(
        self,
        v: float | np.ndarray,
        ay: float | np.ndarray,
        grip: float = 1.0,
        *,
        mu: float | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(ax_max, ax_min)`` [m/s^2] at speed ``v`` and lateral acceleration ``ay`` (arrays
        broadcast) of the envelope scaled by ``grip``; ``ay`` beyond the limit counts as at it.
        ``mu``: deprecated name of ``grip``."""
        grip = grip_arg(grip, mu, "longitudinal_limits", 1.0)
        v, ay = np.broadcast_arrays(np.asarray(v, dtype=float), np.abs(np.asarray(ay, dtype=float)))
        v_tab, ay_tab, r_tab, hi_tab, lo_tab = self.tables(grip)
        flat = (
            np.ascontiguousarray(v).ravel(),
            np.ascontiguousarray(ay).ravel(),
            v_tab,
            ay_tab,
            r_tab,
        )
        return (
            _envelope_many(*flat, hi_tab).reshape(v.shape),
            _envelope_many(*flat, lo_tab).reshape(v.shape),
        )

    def corner_speed(
        self, kappa: float | np.ndarray, grip: float = 1.0, *, mu: float | None = None
    ) -> np.ndarray:
        """Highest speed [m/s] at which curvature ``kappa`` [1/m] (any shape) can be held:
        the largest grid speed ``v`` with ``v^2 |kappa| <= grip ay_max(u)`` for every ``u <= v``
        (the connected feasible range from standstill), interpolated between grid points,
        capped at the top speed. ``mu``: deprecated name of ``grip``."""
        grip = grip_arg(grip, mu, "corner_speed", 1.0)
        k = np.abs(np.asarray(kappa, dtype=float))
        lim = grip * self.ay_max  # (I,)
        slack = lim[None, :] - self.v[None, :] ** 2 * k.reshape(-1, 1)  # (P, I), >= 0 feasible
        bad = slack < 0
        first = np.where(bad.any(axis=1), bad.argmax(axis=1), len(self.v))
        out = np.full(k.size, self.top_speed)
        hit = first < len(self.v)
        i = first[hit]
        i0 = np.maximum(i - 1, 0)
        s0, s1 = slack[hit, i0], slack[hit, i]
        w = np.where(i > 0, s0 / np.maximum(s0 - s1, 1e-300), 0.0)
        out[hit] = self.v[i0] + w * (self.v[i] - self.v[i0])
        return np.minimum(out, self.top_speed).reshape(k.shape)

    def tables(
        self, grip: float = 1.0, *, mu: float | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Arrays for the compiled speed profile: ``(v, grip * ay_max, r, grip * ax_max,
        grip * ax_min)`` (``mu``: deprecated name of ``grip``)."""
        grip = grip_arg(grip, mu, "tables", 1.0)
        return self.v, grip * self.ay_max, self.r, grip * self.ax_max, grip * self.ax_min


@njit(cache=True)
def envelope_at(v, ay, v_tab, ay_tab, r_tab, tab):
    """Bilinear look-up of an (I, J) table of :meth:`GGV.tables` at speed ``v`` [m/s] and
    lateral acceleration ``ay`` [m/s^2] (as a fraction of the lateral limit at ``v``, capped
    at 1); the grids are uniform. Compiled: the speed profile's passes call it per point."""
    nv, nr = v_tab.shape[0], r_tab.shape[0]
    x = min(max(v, v_tab[0]), v_tab[nv - 1])
    i = min(int((x - v_tab[0]) / (v_tab[1] - v_tab[0])), nv - 2)
    tx = (x - v_tab[i]) / (v_tab[i + 1] - v_tab[i])
    lim = ay_tab[i] * (1.0 - tx) + ay_tab[i + 1] * tx
    y = min(ay / lim, 1.0) if lim > 1e-9 else 1.0
    j = min(int(y * (nr - 1)), nr - 2)
    ty = (y - r_tab[j]) / (r_tab[j + 1] - r_tab[j])
    return (
        (1 - tx) * (1 - ty) * tab[i, j]
        + tx * (1 - ty) * tab[i + 1, j]
        + (1 - tx) * ty * tab[i, j + 1]
        + tx * ty * tab[i + 1, j + 1]
    )


@njit(cache=True)
def _envelope_many(v, ay, v_tab, ay_tab, r_tab, tab):
    out = np.empty(v.shape[0])
    for k in range(v.shape[0]):
        out[k] = envelope_at(v[k], ay[k], v_tab, ay_tab, r_tab, tab)
    return out


@functools.lru_cache(maxsize=16)
def ggv(vehicle: VehicleParams | FullSizeParams | None = None) -> GGV:
    """The g-g-v envelope of ``vehicle`` (default :class:`VehicleParams`), cached per vehicle.

    A :class:`~racing_env.vehicles.fullsize.FullSizeParams` gets the full-size class's
    envelope (:mod:`racing_env.vehicles.fullsize_envelope`: downforce, power limit, friction
    ellipse and brake split; clean air) on the same grids."""
    if isinstance(vehicle, FullSizeParams):
        tab = fullsize_tables(vehicle, N_SPEEDS, N_FRACTIONS)
        if not (np.all(np.isfinite(tab["ax_max"])) and np.all(np.isfinite(tab["ax_min"]))):
            raise RuntimeError("g-g-v envelope: a point inside the lateral limit is infeasible")
        arrays = {k: a for k, a in tab.items() if isinstance(a, np.ndarray)}
        for a in arrays.values():
            a.setflags(write=False)
        return GGV(**arrays, top_speed=float(tab["top_speed"]))
    p = vehicle or VehicleParams()
    top = p.top_speed
    v = np.linspace(0.0, 1.05 * top, N_SPEEDS)
    vq = np.maximum(v, 0.02)
    # bisection on a_y for the lateral limit at every speed at once
    lo = np.zeros_like(vq)
    hi = np.full_like(vq, 4.0 * (p.Df + p.Dr) / p.m)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        ok = steady_corner(vq, mid, p)["feasible"]
        lo = np.where(ok, mid, lo)
        hi = np.where(ok, hi, mid)
    ay_max = lo
    r = np.linspace(0.0, 1.0, N_FRACTIONS)
    pts = steady_corner(vq[:, None], ay_max[:, None] * r[None, :], p)
    ax_max, ax_min = pts["ax_max"], pts["ax_min"]
    if not (np.all(np.isfinite(ax_max)) and np.all(np.isfinite(ax_min))):
        raise RuntimeError("g-g-v envelope: a point inside the lateral limit is infeasible")
    for a in (v, ay_max, r, ax_max, ax_min):
        a.setflags(write=False)
    return GGV(v=v, ay_max=ay_max, r=r, ax_max=ax_max, ax_min=ax_min, top_speed=float(top))
