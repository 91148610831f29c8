"""One car's dynamics over a control period, compiled (numba): classical RK4 sub-steps of the
vehicle model (:func:`racing_env.vehicle.frenet_ode`) on the track's curvature, their number
adapted to the stiffness of the lateral dynamics (:func:`_n_substeps`: many at a standing start,
two at racing speed) so that the integration is stable at every speed; a car never rolls
backwards (``vx >= 0``) and its heading stays within [-pi, pi]. The compiled step
(:mod:`racing_env.simulator`, which re-exports these names), its contact rule
(:mod:`racing_env.contact`) and the MPC's follower rollout integrate with these kernels.

One kernel serves every vehicle class: it dispatches on the length of the packed parameter
vector ``p`` (15: the paper's ORCA car, :meth:`racing_env.vehicle.VehicleParams.pack`; 25: the
full-size car, :meth:`racing_env.vehicles.fullsize.FullSizeParams.pack`), in
:func:`_ode_any` (the force law) and :func:`_n_substeps` (the sub-step rule). The wake's
factors ``(fw, fd)`` (drag, downforce; :mod:`racing_env.wake`) are held over the period; the
full-size ODE takes both, the ORCA car (no downforce) takes the drag factor on its drag term
``C4 vx^2`` only, and with ``fw == 1`` its ODE is the paper's, bit for bit.
"""

from __future__ import annotations

import math

from numba import njit

from .interp import periodic_lookup as _lookup
from .vehicle import (
    P_BF,
    P_BR,
    P_C4,
    P_CF,
    P_CR,
    P_DF,
    P_DR,
    P_IZ,
    P_LF,
    P_LR,
    P_M,
    P_VLOW,
    bind,
    frenet_ode,
)
from .vehicles.fullsize import N_PARAMS as N_PARAMS_FULLSIZE
from .vehicles.fullsize import n_substeps_fullsize, ode_fullsize

_ode = njit(cache=True)(bind(frenet_ode, math))


@njit(cache=True)
def _ode_any(n, mu, vx, vy, omega, d, delta, kappa, p, fw, fd):
    """The force law of the class of ``p`` (its length: 25 full-size, else ORCA) with the
    wake's drag and downforce factors ``fw``, ``fd``; ORCA: ``C4 vx^2`` scaled by ``fw``
    (``fd`` unused), the paper's ODE itself when ``fw == 1``."""
    if p.shape[0] == N_PARAMS_FULLSIZE:
        return ode_fullsize(n, mu, vx, vy, omega, d, delta, kappa, p, fw, fd)
    r = _ode(n, mu, vx, vy, omega, d, delta, kappa, p)
    if fw != 1.0:  # the drag term C4 vx^2 times fw: add back the (1 - fw) share
        return (r[0], r[1], r[2], r[3] + (1.0 - fw) * p[P_C4] * vx * vx / p[P_M], r[4], r[5])
    return r


@njit(cache=True)
def _n_substeps(vx, p, dt, gain, max_sub):
    """Sub-steps for stable RK4: h * lambda_max <= 2.5 / gain (RK4 is stable to about 2.8);
    the full-size class (``p`` of length 25) by its own rule
    (:func:`racing_env.vehicles.fullsize.n_substeps_fullsize`)."""
    if p.shape[0] == N_PARAMS_FULLSIZE:
        return n_substeps_fullsize(vx, p, dt, gain, max_sub)
    ca_f = p[P_BF] * p[P_CF] * p[P_DF]
    ca_r = p[P_BR] * p[P_CR] * p[P_DR]
    # with the low-speed force fade, C / (m v) peaks near C / (m 2 v_low)
    v = math.sqrt(vx * vx + 4.0 * p[P_VLOW] * p[P_VLOW])
    lam = (ca_f + ca_r) / (p[P_M] * v) + (ca_f * p[P_LF] ** 2 + ca_r * p[P_LR] ** 2) / (p[P_IZ] * v)
    k = int(math.ceil(dt * lam * gain / 2.5))
    return min(max(k, 2), max_sub)


@njit(cache=True)
def _slope_at(x, k, a, d, delta, kappa_tab, ds, length, p, fw, fd):
    """The ODE's slope at the state ``x + a k`` (an RK4 stage; ``x``, ``k`` (6,))."""
    return _ode_any(
        x[1] + a * k[1],
        x[2] + a * k[2],
        x[3] + a * k[3],
        x[4] + a * k[4],
        x[5] + a * k[5],
        d,
        delta,
        _lookup(kappa_tab, x[0] + a * k[0], ds, length),
        p,
        fw,
        fd,
    )


@njit(cache=True)
def _rk4_substep(x, d, delta, kappa_tab, ds, length, p, h, fw, fd):
    """One classical RK4 step of length ``h`` of one car's state ``x`` (6,), in place, with
    the wake's factors ``fw``, ``fd`` (1, 1: clean air)."""
    kappa = _lookup(kappa_tab, x[0], ds, length)
    k1 = _ode_any(x[1], x[2], x[3], x[4], x[5], d, delta, kappa, p, fw, fd)
    k2 = _slope_at(x, k1, 0.5 * h, d, delta, kappa_tab, ds, length, p, fw, fd)
    k3 = _slope_at(x, k2, 0.5 * h, d, delta, kappa_tab, ds, length, p, fw, fd)
    k4 = _slope_at(x, k3, h, d, delta, kappa_tab, ds, length, p, fw, fd)
    for j in range(6):
        x[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
    if x[3] < 0.0:
        x[3] = 0.0
    if x[2] > math.pi or x[2] < -math.pi:
        x[2] = (x[2] + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def integrate_car(x, d, delta, kappa_tab, ds, length, p, dt, n_sub, fw=1.0, fd=1.0):
    """Advance one car's state ``x`` (6,) in place over ``dt`` with ``n_sub`` RK4 steps (any
    class: ``p`` of either length), in the wake's factors ``fw``, ``fd`` (default clean air)."""
    h = dt / n_sub
    for _ in range(n_sub):
        _rk4_substep(x, d, delta, kappa_tab, ds, length, p, h, fw, fd)
