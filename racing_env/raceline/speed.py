"""The speed profile along a closed path for the car's g-g-v envelope scaled by ``grip``
(:mod:`racing_env.envelope`): forward (drive) and backward (braking) passes around the lap
until nothing changes, and the lap time of a profile."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..envelope import envelope_at, ggv, grip_arg
from ..vehicle import VehicleParams
from .config import AnyVehicle

G = 9.81
"""Gravitational acceleration [m/s^2]."""


def accel_limits(
    v: float | np.ndarray,
    kappa: float | np.ndarray,
    grip: float | None = None,
    vehicle: AnyVehicle | None = None,
    *,
    mu: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Largest acceleration and deceleration [m/s^2] (deceleration >= 0) at speed ``v`` [m/s]
    on a path of curvature ``kappa`` [1/m] for the car's g-g-v envelope scaled by ``grip``
    (:mod:`racing_env.envelope`; ``mu``: deprecated name of ``grip``); arrays broadcast.

    ``a_acc = grip ax_max(v, v^2 |kappa|)`` is the drive acceleration on top of that corner: it is
    *negative* where the motor cannot hold the speed in the corner (the car slows through it).
    ``a_brk = -grip ax_min(v, v^2 |kappa|)``. A lateral demand beyond the envelope counts as at it.
    """
    grip = _required_grip(grip, mu, "accel_limits")
    env = ggv(vehicle or VehicleParams())
    v = np.asarray(v, dtype=float)
    hi, lo = env.longitudinal_limits(v, v * v * np.abs(np.asarray(kappa, dtype=float)), grip)
    return hi, np.maximum(-lo, 0.0)


def _required_grip(grip, mu, where: str) -> float:
    grip = grip_arg(grip, mu, where)
    if grip is None:
        raise TypeError(f"{where}() missing the envelope scale grip")
    return grip


def speed_limit(
    kappa: float | np.ndarray,
    grip: float | None = None,
    vehicle: AnyVehicle | None = None,
    *,
    mu: float | None = None,
) -> float | np.ndarray:
    """Quasi-steady speed cap [m/s] of curvature ``kappa`` [1/m] (any shape): the highest speed
    at which the envelope scaled by ``grip`` holds ``v^2 |kappa|`` (the steering bound at low
    speed, the tyres above), and never above the top speed (:meth:`GGV.corner_speed`).
    ``mu``: deprecated name of ``grip``."""
    grip = _required_grip(grip, mu, "speed_limit")
    return ggv(vehicle or VehicleParams()).corner_speed(kappa, grip)


def speed_profile(
    kappa: np.ndarray,
    ds: float | np.ndarray,
    grip: float | None = None,
    vehicle: AnyVehicle | None = None,
    max_sweeps: int = 200,
    *,
    mu: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Periodic speed profile ``(vx, ax)`` [m/s], [m/s^2] on a closed path, shapes (M,).

    ``kappa`` [1/m] at the M points, ``ds[k]`` [m] the distance from point k to point k+1
    (the last one closes the lap); ``grip`` scales the car's g-g-v envelope
    (:func:`racing_env.envelope.ggv`; 1 = the car's own limit; ``mu``: its deprecated name). Starts from
    :func:`speed_limit` and repeats a forward (drive) and a backward (braking) pass around the
    lap until no speed changes; the result satisfies
    ``v[k+1]^2 - v[k]^2 <= 2 ds[k] a_acc(v[k], kappa[k])`` and
    ``v[k]^2 - v[k+1]^2 <= 2 ds[k] a_brk(v[k+1], kappa[k+1])`` (indices mod M, see
    :func:`accel_limits`; ``a_acc`` may be negative in fast corners, where the car slows).
    ``ax[k] = (v[k+1]^2 - v[k]^2) / (2 ds[k])`` is the acceleration on segment k.
    The passes converge geometrically where the drive limit falls with the lateral demand:
    a few tens of sweeps on most lines, 56 on Spa at full scale with ``grip = 0.5``
    (``max_sweeps``, then a RuntimeError).
    """
    grip = _required_grip(grip, mu, "speed_profile")
    p = vehicle or VehicleParams()
    kappa, ds = _checked_path(kappa, ds, grip, "speed_profile")
    v2 = speed_limit(kappa, grip, p) ** 2
    vx = _settle(v2, kappa, ds, grip, p, max_sweeps, "speed profile")
    ax = (np.roll(v2, -1) - v2) / (2.0 * ds)
    return vx, ax


def braking_limit(
    kappa: np.ndarray,
    ds: np.ndarray,
    grip: float,
    vehicle: AnyVehicle,
    v_cap: float,
    max_sweeps: int = 200,
) -> np.ndarray:
    """The braking limit [m/s] (M,) on a closed path (``kappa``, ``ds`` as
    :func:`speed_profile`): the highest speed at each point from which the car can still
    brake for every corner ahead within its envelope scaled by ``grip``, the speed profile's
    backward (braking) passes alone, with the top-speed cap of the straights raised to
    ``v_cap`` [m/s] (a car in another's tow is faster than its own top speed). It is never
    below :func:`speed_profile`'s speeds."""
    kappa, ds = _checked_path(kappa, ds, grip, "braking_limit")
    top = ggv(vehicle).top_speed
    v = speed_limit(kappa, grip, vehicle)
    v = np.where(v >= top * (1.0 - 1e-9), max(float(v_cap), top), v)
    return _settle(v * v, kappa, ds, grip, vehicle, max_sweeps, "braking limit", drive=False)


def _checked_path(kappa, ds, grip: float, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``(kappa, ds)`` as float arrays, checked: equal 1-D shapes of at least 2 points, finite,
    ``ds > 0``; ``grip`` in (0, 1.5]."""
    kappa = np.asarray(kappa, dtype=float)
    ds = np.asarray(ds, dtype=float)
    if kappa.shape != ds.shape or kappa.ndim != 1 or len(kappa) < 2:
        raise ValueError(
            f"{where} needs kappa and ds of equal 1-D shape, got {kappa.shape}, {ds.shape}"
        )
    if not (np.all(np.isfinite(kappa)) and np.all(np.isfinite(ds)) and np.all(ds > 0)):
        raise ValueError(f"{where} needs finite kappa and finite positive ds")
    if not (math.isfinite(grip) and 0 < grip <= 1.5):
        raise ValueError(f"envelope scale grip must be in (0, 1.5], got {grip!r}")
    return kappa, ds


def _settle(v2, kappa, ds, grip, vehicle, max_sweeps, what: str, drive: bool = True):
    """The speeds [m/s] after :func:`_profile_sweeps` from the squared speeds ``v2`` (changed in
    place) under ``vehicle``'s envelope scaled by ``grip``; ``drive=False``: the backward
    (braking) passes alone. A ``RuntimeError`` naming ``what`` if they did not settle."""
    v_tab, ay_tab, r_tab, axp_tab, axm_tab = ggv(vehicle).tables(grip)
    if not drive:
        axp_tab = np.full_like(axp_tab, 1e12)  # the forward pass never binds
    ok = _profile_sweeps(
        v2,
        np.abs(kappa),
        ds,
        v_tab,
        ay_tab,
        r_tab,
        axp_tab,
        axm_tab,
        int(np.argmin(v2)),
        int(max_sweeps),
    )
    if not ok:
        raise RuntimeError(f"{what} did not settle in {max_sweeps} sweeps")
    return np.sqrt(v2)


@njit(cache=True)
def _profile_sweeps(v2, kab, ds, v_tab, ay_tab, r_tab, axp_tab, axm_tab, start, max_sweeps):
    """Forward/backward passes of :func:`speed_profile` on ``v2`` (squared speeds, in place);
    False if they did not settle in ``max_sweeps``."""
    m = v2.shape[0]
    for _ in range(max_sweeps):
        changed = False
        for j in range(m):  # forward: drive
            k = (start + j) % m
            k1 = k + 1 if k + 1 < m else 0
            vk2 = v2[k]
            vk = math.sqrt(vk2)
            a = envelope_at(vk, vk2 * kab[k], v_tab, ay_tab, r_tab, axp_tab)
            cand = max(vk2 + 2.0 * ds[k] * a, 0.0)
            if cand < v2[k1] * (1.0 - 1e-12):
                v2[k1] = cand
                changed = True
        for j in range(m):  # backward: braking
            k1 = (start - j) % m
            k = k1 - 1 if k1 > 0 else m - 1
            vk2 = v2[k1]
            vk = math.sqrt(vk2)
            a = -envelope_at(vk, vk2 * kab[k1], v_tab, ay_tab, r_tab, axm_tab)
            cand = vk2 + 2.0 * ds[k] * max(a, 0.0)
            if cand < v2[k] * (1.0 - 1e-12):
                v2[k] = cand
                changed = True
        if not changed:
            return True
    return False


def lap_time_of(vx: np.ndarray, ds: float | np.ndarray) -> float:
    """Lap time [s] of a periodic profile: ``sum 2 ds[k] / (v[k] + v[k+1])``."""
    vx = np.asarray(vx, dtype=float)
    return float(np.sum(2.0 * np.asarray(ds) / np.maximum(vx + np.roll(vx, -1), 1e-12)))
