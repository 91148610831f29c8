"""Compiled (numba) step of many races at once: integration, racing rules, reward, observations.

Everything here works on plain arrays so that one call advances ``B`` races of ``N`` cars:

* ``state``  (B, N, 6) float64, per car ``(s, n, mu, vx, vy, omega)`` with unwrapped ``s``;
* ``action`` (B, N, 2) float64, physical ``(d, delta)`` (already within the vehicle's bounds);
* a :class:`TrackTables` of per-grid-point curvature, edges and walls.

One control period ``dt`` is integrated with classical RK4 sub-steps whose number adapts to
the stiffness of the lateral dynamics (many at a standing start, two at racing speed), so the
integration is stable at every speed (:mod:`racing_env.integrator`). The paper's rules apply
(see :class:`racing_env.config.RulesConfig`): contact slow-down, checked over the sub-steps and
applied at the moment of contact (see :func:`_step_one_race`), with the bodies kept apart
(:func:`racing_env.contact._separate`: no car passes through another), and, after the dynamics,
off-track slow-down with re-alignment. A car cannot go more than ``wall_margin`` beyond an edge
(a wall stops it sideways) and cannot roll backwards (``vx >= 0``: a brake stops a car, it does
not reverse it).

This module drives the step (:func:`advance`, with the walls, the off-track rule, the reward and
the lap bookkeeping) and builds the observations (:func:`observe`); the integration of one car
is in :mod:`racing_env.integrator`, the contact rule's kernels in :mod:`racing_env.contact`.
``integrate_car``, ``_n_substeps`` and ``_ode`` are re-exported from here.
"""

from __future__ import annotations

import math
import types
from typing import NamedTuple

import numpy as np
from numba import njit, prange

from .config import (  # the rule vector's layout, also imported from here
    R_CONTACT_DN,
    R_CONTACT_DS,
    R_CONTACT_ON,
    R_FRONT,  # noqa: F401 (re-exported)
    R_MAX_SUB,
    R_OFF_FACTOR,
    R_OFF_ON,
    R_OFF_REJOIN,
    R_REAR,  # noqa: F401 (re-exported)
    R_SUB_GAIN,
    R_WAKE,
    R_WAKE_LENGTH,
    R_WAKE_WIDTH,
)
from .contact import _cut, _lockstep_with_contact, _separate
from .integrator import (
    _n_substeps,
    _ode,  # noqa: F401 (re-exported)
    _rk4_substep,
    integrate_car,  # noqa: F401 (re-exported)
)
from .interp import periodic_lookup as _lookup
from .track import Track
from .wake import wake_of_car


class TrackTables(NamedTuple):
    """Per-grid-point tables of a track, shape (M,) each, and its grid: one argument of the
    compiled kernels."""

    kappa: np.ndarray
    w_left: np.ndarray
    w_right: np.ndarray
    wall_left: np.ndarray
    wall_right: np.ndarray
    ds: float
    length: float

    @classmethod
    def from_track(cls, track: Track, wall_margin: float) -> TrackTables:
        """Walls sit ``wall_margin`` m beyond each edge, and never closer than 10% of the
        radius of curvature to its centre (keeps ``1 - n kappa >= 0.1``)."""
        k = track.kappa
        with np.errstate(divide="ignore", over="ignore"):  # kappa 0 or subnormal: no limit
            lim_l = np.where(k > 0, 0.9 / np.abs(k), np.inf)
            lim_r = np.where(k < 0, 0.9 / np.abs(k), np.inf)
        wall_l = np.minimum(track.w_left + wall_margin, lim_l)
        wall_r = np.minimum(track.w_right + wall_margin, lim_r)
        f64 = lambda a: np.ascontiguousarray(a, dtype=np.float64)
        return cls(
            f64(k),
            f64(track.w_left),
            f64(track.w_right),
            f64(wall_l),
            f64(wall_r),
            float(track.ds),
            float(track.length),
        )


def _step_one_race(b, state, phys, tables, p, dt, rules, reward, contact, offtrack, substeps, wake):
    """Physics, rules and reward of race ``b`` for one control period (inputs ``phys`` (N, 2))
    on the track of the :class:`TrackTables` ``tables``.

    The wake (rule vector's ``R_WAKE`` strength > 0): at the start of the period each car's
    ``(drag_factor, downforce_factor)`` is computed from the cars ahead
    (:func:`racing_env.wake.wake_of_car`, cars of ``R_WAKE_LENGTH`` x ``R_WAKE_WIDTH``) and held
    over the whole period (0.1 s: a gap changes by a few metres in it at full size, the factor
    by a few per cent at most), written to ``wake[b]`` (N, 2); 1.0 exactly when off.

    Contact is checked over the whole period, not only at its end, so that no car can drive
    through another. First every car is integrated on its own (its own number of sub-steps),
    recording the range of its progress and lateral offset over the sub-step points. If no two
    cars' ranges come within the contact box, no contact was possible and the period is done.
    Otherwise the race is integrated again from the start of the period with all cars in
    lockstep (the largest number of sub-steps of any car), sweeping each pair's relative
    ``(ds, dn)`` linearly between sub-step points; at a pair's first moment of contact the car
    in front then gets ``front_factor`` and the car behind ``rear_factor`` (applied to ``vx``
    there and then; a car is slowed at most once per period, by the smallest factor due).
    """
    kappa_tab, w_left, w_right = tables.kappa, tables.w_left, tables.w_right
    ds, length = tables.ds, tables.length
    n_cars = state.shape[1]
    half = 0.5 * length
    before = np.empty(n_cars)
    x0 = np.empty((n_cars, 6))
    lo_s = np.zeros(n_cars)
    hi_s = np.zeros(n_cars)
    lo_n = np.empty(n_cars)
    hi_n = np.empty(n_cars)
    k_max = 2
    max_sub = int(rules[R_MAX_SUB])
    fac = wake[b]
    fac[:, :] = 1.0
    if rules[R_WAKE] > 0.0 and n_cars > 1:
        s_now = state[b, :, 0].copy()
        n_now = state[b, :, 1].copy()
        lens = np.full(n_cars, rules[R_WAKE_LENGTH])
        wids = np.full(n_cars, rules[R_WAKE_WIDTH])
        for i in range(n_cars):
            fac[i, 0], fac[i, 1] = wake_of_car(i, s_now, n_now, lens, wids, length, rules[R_WAKE])
    for i in range(n_cars):
        before[i] = state[b, i, 0]
        x = state[b, i]
        for q in range(6):  # element copies: no slice assignment (a cold race's compile)
            x0[i, q] = x[q]
        k = _n_substeps(x[3], p, dt, rules[R_SUB_GAIN], max_sub)
        k_max = max(k_max, k)
        substeps[b, i] = k
        lo_n[i] = x[1]
        hi_n[i] = x[1]
        h = dt / k
        for _ in range(k):
            _rk4_substep(
                x, phys[i, 0], phys[i, 1], kappa_tab, ds, length, p, h, fac[i, 0], fac[i, 1]
            )
            lo_s[i] = min(lo_s[i], x[0] - x0[i, 0])
            hi_s[i] = max(hi_s[i], x[0] - x0[i, 0])
            lo_n[i] = min(lo_n[i], x[1])
            hi_n[i] = max(hi_n[i], x[1])
        contact[b, i] = 0
        offtrack[b, i] = 0
    applied = np.ones(n_cars)
    possible = False
    if rules[R_CONTACT_ON] > 0.0 and n_cars > 1:
        c_ds, c_dn = rules[R_CONTACT_DS], rules[R_CONTACT_DN]
        # [m] covers the difference between the two integrations (1e-6 m at full size, notes)
        # and the path between sub-step points (a h^2 / 8 < 1 mm at 1 g, h = 25 ms): both are
        # set by speeds, accelerations and sub-step lengths, alike in both classes, not by size
        margin = 0.01
        for i in range(n_cars):
            for j in range(i + 1, n_cars):
                d0 = (x0[i, 0] - x0[j, 0] + half) % length - half
                if (
                    d0 + lo_s[i] - hi_s[j] < c_ds + margin
                    and d0 + hi_s[i] - lo_s[j] > -c_ds - margin
                    and lo_n[i] - hi_n[j] < c_dn + margin
                    and hi_n[i] - lo_n[j] > -c_dn - margin
                ):
                    possible = True
        if possible:
            ahead = np.empty((n_cars, n_cars), dtype=np.bool_)
            _lockstep_with_contact(
                b,
                state,
                phys,
                x0,
                tables,
                p,
                dt,
                rules,
                k_max,
                applied,
                contact,
                substeps,
                ahead,
                fac,
            )
    _clamp_to_walls(b, state, tables)
    if possible:  # a wall may have moved a car sideways into another: keep them apart
        _separate(b, state, x0, ahead, length, c_ds, c_dn, False)
    for i in range(n_cars):
        x = state[b, i]
        e_left = _lookup(w_left, x[0], ds, length)
        e_right = -_lookup(w_right, x[0], ds, length)
        if x[1] > e_left or x[1] < e_right:
            offtrack[b, i] = 1
            if rules[R_OFF_ON] > 0.0:
                _cut(x, applied, i, rules[R_OFF_FACTOR])
                x[2] = 0.0
                x[4] = 0.0
                x[5] = 0.0
                if rules[R_OFF_REJOIN] > 0.0:  # back on the track, its body inside the edge
                    inset = 0.5 * rules[R_WAKE_WIDTH]  # (the cars' width)
                    x[1] = e_left - inset if x[1] > e_left else e_right + inset
    # reward: change of (s_i - max_{j != i} s_j), on unwrapped s
    for i in range(n_cars):
        if n_cars == 1:
            reward[b, i] = state[b, i, 0] - before[i]
            continue
        lead_before = -np.inf
        lead_after = -np.inf
        for j in range(n_cars):
            if j != i:
                lead_before = max(lead_before, before[j])
                lead_after = max(lead_after, state[b, j, 0])
        reward[b, i] = (state[b, i, 0] - lead_after) - (before[i] - lead_before)
    return before


@njit(cache=True)
def _clamp_to_walls(b, state, tables):
    """A car cannot go further than a wall: it stops sideways there (race ``b``, in place)."""
    ds, length = tables.ds, tables.length
    for i in range(state.shape[1]):
        x = state[b, i]
        wl = _lookup(tables.wall_left, x[0], ds, length)
        wr = _lookup(tables.wall_right, x[0], ds, length)
        if x[1] > wl or x[1] < -wr:
            x[1] = wl if x[1] > wl else -wr
            x[2] = 0.0
            x[4] = 0.0
            x[5] = 0.0


def _advance(
    state,
    action,
    normalised,
    act_map,
    tables,
    p,
    dt,
    rules,
    t,
    s_line,
    laps,
    contacts,
    offtracks,
    lap_event,
    reward,
    contact,
    offtrack,
    substeps,
    wake,
    where,
):
    """Advance every race in ``state`` (B, N, 6) by one control period, in place.

    ``action`` (B, N, 2): normalised [-1, 1] actions if ``normalised`` (clipped, then mapped
    with ``act_map = (d_mid, d_half, delta_max)``), else physical ``(d, delta)``, on the
    track of the :class:`TrackTables` ``tables``.
    Per-car outputs (B, N): ``reward`` the change of (s_i - max_{j != i} s_j) (the change of
    s_i when N == 1), ``contact`` / ``offtrack`` 1 if that rule applied this step,
    ``substeps`` RK4 sub-steps used, ``wake`` (B, N, 2) the wake's (drag, downforce) factors
    held over this step (1.0 without a wake), ``lap_event`` the race time [s] of a lap completed this
    step or -1. Running totals updated: ``t`` (B,), ``laps``, ``contacts``, ``offtracks``.
    Returns 0, or 1 if an action is bad (NaN; or, for physical inputs, not finite: normalised
    +-inf is clipped like any out-of-range value) / 2 if a state became non-finite, with the
    race and car in ``where`` (2,); nothing is stepped when an action is bad.
    """
    n_races, n_cars = state.shape[0], state.shape[1]
    length = tables.length
    for b in range(n_races):
        for i in range(n_cars):
            a0, a1 = action[b, i, 0], action[b, i, 1]
            if (
                math.isnan(a0)
                or math.isnan(a1)
                or not (normalised or (math.isfinite(a0) and math.isfinite(a1)))
            ):
                where[0] = b
                where[1] = i
                return 1
    for b in prange(n_races):
        phys = np.empty((n_cars, 2))
        for i in range(n_cars):
            a0, a1 = action[b, i, 0], action[b, i, 1]
            if normalised:
                a0 = min(max(a0, -1.0), 1.0)
                a1 = min(max(a1, -1.0), 1.0)
                a0 = act_map[0] + act_map[1] * a0
                a1 = act_map[2] * a1
            phys[i, 0] = a0
            phys[i, 1] = a1
        before = _step_one_race(
            b, state, phys, tables, p, dt, rules, reward, contact, offtrack, substeps, wake
        )
        # bookkeeping: laps (the line is s_line + k L), time of crossing within the period
        for i in range(n_cars):
            contacts[b, i] += contact[b, i]
            offtracks[b, i] += offtrack[b, i]
            lap_event[b, i] = -1.0
            done = math.floor((state[b, i, 0] - s_line[b]) / length)
            if done > laps[b, i]:
                line = s_line[b] + done * length
                s0, s1 = before[i], state[b, i, 0]
                frac = (line - s0) / (s1 - s0) if s1 > s0 else 1.0
                lap_event[b, i] = (t[b] + frac) * dt
                laps[b, i] = done
        t[b] += 1
    for b in range(n_races):
        for i in range(n_cars):
            for c in range(6):
                if not math.isfinite(state[b, i, c]):
                    where[0] = b
                    where[1] = i
                    return 2
    return 0


def _observe(state, tables, preview_ds, n_preview, s_clip, out):
    """Per-car observations ``out`` (B, N, 6 + 6 (N - 1) + n_preview) float32 from ``state`` on
    the track of the :class:`TrackTables` ``tables``.

    Layout for car i: own ``(s mod length, n, mu, vx, vy, omega)``; then for every other car j
    in index order ``(s_j - s_i, n_j - n_i, wrap(mu_j - mu_i), vx_j - vx_i, vy_j - vy_i,
    omega_j - omega_i)`` with unwrapped s difference clipped to +-s_clip; then kappa at
    ``s_i + k * preview_ds`` for k = 0..n_preview-1.
    """
    n_races, n_cars = state.shape[0], state.shape[1]
    kappa_tab, ds, length = tables.kappa, tables.ds, tables.length
    for b in prange(n_races):
        for i in range(n_cars):
            o = out[b, i]
            xi = state[b, i]
            o[0] = xi[0] % length
            for c in range(1, 6):
                o[c] = xi[c]
            col = 6
            for j in range(n_cars):
                if j == i:
                    continue
                xj = state[b, j]
                o[col] = min(max(xj[0] - xi[0], -s_clip), s_clip)
                o[col + 1] = xj[1] - xi[1]
                o[col + 2] = (xj[2] - xi[2] + math.pi) % (2.0 * math.pi) - math.pi
                for c in range(3, 6):
                    o[col + c] = xj[c] - xi[c]
                col += 6
            for k in range(n_preview):
                o[col + k] = _lookup(kappa_tab, xi[0] + k * preview_ds, ds, length)


# Each kernel is compiled twice from the same source: serial (one race, no thread start-up
# cost: the PettingZoo/Gymnasium envs) and parallel over races (the batched path).
# (distinct qualnames keep numba's on-disk caches of the two variants apart)
def _variant(fn, suffix):
    g = types.FunctionType(fn.__code__, fn.__globals__, fn.__name__ + suffix, fn.__defaults__)
    g.__qualname__ = fn.__qualname__ + suffix
    return g


_step_one_race = njit(cache=True)(_step_one_race)
advance = njit(cache=True)(_variant(_advance, "_serial"))
advance_parallel = njit(cache=True, parallel=True)(_variant(_advance, "_parallel"))
observe = njit(cache=True)(_variant(_observe, "_serial"))
observe_parallel = njit(cache=True, parallel=True)(_variant(_observe, "_parallel"))
