"""The contact rule of the compiled step, one race at a time (numba kernels called by
:mod:`racing_env.simulator`): a period in which two cars may have touched is integrated again
from its start with every car in lockstep (:func:`_lockstep_with_contact`), each pair's relative
motion swept between RK4 sub-step points (:func:`_box_entry`) so that the slow-down applies at
the first moment of contact (:func:`_cut`, which the off-track rule uses too), and the bodies
are kept apart after every sub-step (:func:`_separate`: no car passes through another). The
rules themselves are described in :class:`racing_env.config.RulesConfig`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .config import R_CONTACT_DN, R_CONTACT_DS, R_CONTACT_REPEAT, R_FRONT, R_REAR, TOUCHING
from .integrator import _rk4_substep


@njit(cache=True)
def _box_entry(ds0, dn0, ds1, dn1, half_s, half_n):
    """First fraction ``u`` in [0, 1] at which the segment ``(ds0, dn0) -> (ds1, dn1)`` is
    inside the open box ``|ds| < half_s, |dn| < half_n``, or -1 if it never is (slab test)."""
    lo, hi = 0.0, 1.0
    for a0, a1, half in ((ds0, ds1, half_s), (dn0, dn1, half_n)):
        da = a1 - a0
        if da == 0.0:
            if not abs(a0) < half:
                return -1.0
        else:
            t1 = (-half - a0) / da
            t2 = (half - a0) / da
            if t1 > t2:
                t1, t2 = t2, t1
            lo = max(lo, t1)
            hi = min(hi, t2)
    return lo if lo < hi else -1.0


@njit(cache=True)
def _cut(x, applied, i, f):
    """Slow car ``i`` so that its total cut in this period is ``min(applied[i], f)``."""
    if f < applied[i]:
        x[3] = x[3] * f / applied[i] if applied[i] > 0.0 else 0.0
        applied[i] = f


@njit(cache=True)
def _wrapped(d, length):
    """``d`` wrapped into [-length/2, length/2)."""
    return (d + 0.5 * length) % length - 0.5 * length


@njit(cache=True)
def _separate(b, state, x_from, ahead, length, c_ds, c_dn, swept):
    """Keep the bodies of race ``b``'s cars apart: no car ends a sub-step overlapping, or
    beyond, a car it is not laterally clear of (env v2).

    ``ahead[i, j]`` is true when car i is ahead of car j in the pair's order: the order they
    had when they were last laterally clear (``|n_i - n_j| >= c_dn``). The rear car of a pair
    must stay at least ``c_ds`` m behind the front car unless the two are laterally clear. With
    ``swept``, each pair's relative motion from ``x_from`` (N, 6), the states before the
    sub-step, to ``state[b]`` is swept linearly, as the contact rule sweeps it; where it enters
    the forbidden region
    ``{s_front - s_rear < c_ds, |n_front - n_rear| < c_dn}`` it is corrected:

    * entered from behind (through the rear face of the front car): the rear car is put back
      along s to exactly ``c_ds`` behind, and its ``vx`` is limited to the front car's (a
      perfectly inelastic bump along the track; ``mu``, ``vy``, ``omega`` unchanged);
    * entered from the side (the cars were side by side and one steered into the other): the
      two are pushed apart sideways, half each, to exactly ``c_dn`` apart on the side they came
      from (velocities unchanged: they slide along each other).

    Not ``swept`` (after the walls, which move cars only sideways), an overlapping pair is put
    apart along s. A car corrected may now overlap another, so the corrections are repeated
    until none is needed (at most ``4 N`` rounds). Finally a pair that is laterally clear takes
    the order of its current positions: a car passes another only through free space.
    Corrections change positions, never the step's reward bookkeeping: the reward is the
    change of ``s_i - max_j s_j`` between the states before and after the period, so it still
    telescopes.
    """
    n_cars = state.shape[1]
    # a correction puts a pair exactly (ds_to, dn_to) apart; the forbidden region ends 1 nm
    # short of that, so rounding never finds the pair overlapping again
    ds_to, dn_to = c_ds, c_dn
    c_ds, c_dn = c_ds - 1e-9, c_dn - 1e-9
    for _ in range(4 * n_cars):
        moved = False
        for i in range(n_cars):
            for j in range(i + 1, n_cars):
                f, r = (i, j) if ahead[i, j] else (j, i)
                xf, xr = state[b, f], state[b, r]
                g1 = _wrapped(xf[0] - xr[0], length)
                dn1 = xf[1] - xr[1]
                if g1 >= c_ds or g1 < -0.25 * length:  # apart, or far apart (across the wrap)
                    continue
                if not swept:
                    if abs(dn1) < c_dn:
                        xr[0] -= ds_to - g1
                        xr[3] = min(xr[3], xf[3])
                        moved = True
                    continue
                g0 = _wrapped(x_from[f, 0] - x_from[r, 0], length)
                dn0 = x_from[f, 1] - x_from[r, 1]
                # first fraction of the sub-step in {g < c_ds} (tg) and in {|dn| < c_dn} (tn)
                if g0 < c_ds:
                    tg = 0.0
                else:
                    tg = (g0 - c_ds) / (g0 - g1)
                if dn1 == dn0:
                    if abs(dn0) >= c_dn:
                        continue
                    tn, tn_out = 0.0, 1.0
                else:
                    t1 = (-c_dn - dn0) / (dn1 - dn0)
                    t2 = (c_dn - dn0) / (dn1 - dn0)
                    if t1 > t2:
                        t1, t2 = t2, t1
                    tn, tn_out = max(t1, 0.0), min(t2, 1.0)
                if max(tg, tn) >= tn_out:
                    continue  # never both: passed beside, or still clear
                if tg >= tn:  # from behind
                    xr[0] -= ds_to - g1
                    xr[3] = min(xr[3], xf[3])
                else:  # from the side
                    side = 1.0 if dn0 + tn * (dn1 - dn0) >= 0.0 else -1.0
                    need = side * dn_to - dn1
                    if side * dn1 >= c_dn:
                        continue
                    xf[1] += 0.5 * need
                    xr[1] -= 0.5 * need
                moved = True
        if not moved:
            break
    for i in range(n_cars):
        for j in range(i + 1, n_cars):
            if abs(state[b, i, 1] - state[b, j, 1]) >= c_dn:  # laterally clear
                d = _wrapped(state[b, i, 0] - state[b, j, 0], length)
                if d != 0.0:
                    ahead[i, j] = d > 0.0
                    ahead[j, i] = not ahead[i, j]


@njit(cache=True)
def _lockstep_with_contact(
    b, state, phys, x0, tables, p, dt, rules, n_sub, applied, contact, substeps, ahead, wake
):
    """Integrate race ``b`` again from ``x0`` (N, 6) with every car in lockstep (``n_sub`` RK4
    sub-steps on the :class:`racing_env.simulator.TrackTables` ``tables``, car i in the wake
    factors ``wake[i] = (drag, downforce)`` held over the period), applying the
    contact rule of the rule vector ``rules`` at each pair's first moment of contact and
    keeping the bodies apart after every sub-step (:func:`_separate`; ``ahead`` (N, N) is
    filled with the pairs' order)."""
    kappa_tab, ds, length = tables.kappa, tables.ds, tables.length
    c_ds, c_dn = rules[R_CONTACT_DS], rules[R_CONTACT_DN]
    front_f, rear_f = rules[R_FRONT], rules[R_REAR]
    repeat = rules[R_CONTACT_REPEAT] > 0.0
    touch_ds, touch_dn = (1.0 + TOUCHING) * c_ds, (1.0 + TOUCHING) * c_dn
    n_cars = x0.shape[0]
    half = 0.5 * length
    h = dt / n_sub
    d_start = np.empty((n_cars, n_cars))  # wrapped s_i - s_j at the start of the period
    hit = np.zeros((n_cars, n_cars), dtype=np.bool_)
    prev = np.empty((n_cars, 2))
    prev_x = np.empty((n_cars, 6))
    for i in range(n_cars):
        for q in range(6):  # element copies: no slice assignment (a cold race's compile)
            state[b, i, q] = x0[i, q]
        substeps[b, i] = n_sub
        for j in range(n_cars):
            d_start[i, j] = (x0[i, 0] - x0[j, 0] + half) % length - half
            ahead[i, j] = d_start[i, j] > 0.0 or (d_start[i, j] == 0.0 and i < j)
    for m in range(n_sub + 1):
        if m > 0:
            for i in range(n_cars):
                prev[i, 0] = state[b, i, 0] - x0[i, 0]
                prev[i, 1] = state[b, i, 1]
                for q in range(6):
                    prev_x[i, q] = state[b, i, q]
                _rk4_substep(
                    state[b, i],
                    phys[i, 0],
                    phys[i, 1],
                    kappa_tab,
                    ds,
                    length,
                    p,
                    h,
                    wake[i, 0],
                    wake[i, 1],
                )
        for i in range(n_cars):
            for j in range(i + 1, n_cars):
                if hit[i, j]:
                    continue
                ds1 = d_start[i, j] + (state[b, i, 0] - x0[i, 0]) - (state[b, j, 0] - x0[j, 0])
                dn1 = state[b, i, 1] - state[b, j, 1]
                if m == 0:  # already touching at the start of the period
                    if not repeat and abs(ds1) < touch_ds and abs(dn1) < touch_dn:
                        # in touch since the last period: no new slow-down this period
                        hit[i, j] = True
                        contact[b, i] = 1
                        contact[b, j] = 1
                        continue
                    u = 0.0 if abs(ds1) < c_ds and abs(dn1) < c_dn else -1.0
                    ds_at, ds_from = ds1, ds1
                else:
                    ds_from = d_start[i, j] + prev[i, 0] - prev[j, 0]
                    u = _box_entry(ds_from, prev[i, 1] - prev[j, 1], ds1, dn1, c_ds, c_dn)
                    ds_at = ds_from + u * (ds1 - ds_from)
                if u < 0.0:
                    continue
                hit[i, j] = True
                contact[b, i] = 1
                contact[b, j] = 1
                # who is behind at the moment of contact (level: who was behind before it)
                i_front = ds_at > 0.0 or (ds_at == 0.0 and ds_from >= 0.0)
                front, rear = (i, j) if i_front else (j, i)
                for car, f in ((front, front_f), (rear, rear_f)):
                    if f >= applied[car]:
                        continue
                    x = state[b, car]
                    if m > 0:  # redo the sub-step: up to the moment of contact, cut, on
                        for q in range(x.shape[0]):  # no slice assignment (cold compile)
                            x[q] = prev_x[car, q]
                        if u > 0.0:
                            _rk4_substep(
                                x,
                                phys[car, 0],
                                phys[car, 1],
                                kappa_tab,
                                ds,
                                length,
                                p,
                                u * h,
                                wake[car, 0],
                                wake[car, 1],
                            )
                    _cut(x, applied, car, f)
                    if m > 0 and u < 1.0:
                        _rk4_substep(
                            x,
                            phys[car, 0],
                            phys[car, 1],
                            kappa_tab,
                            ds,
                            length,
                            p,
                            (1.0 - u) * h,
                            wake[car, 0],
                            wake[car, 1],
                        )
        if m > 0:
            _separate(b, state, prev_x, ahead, length, c_ds, c_dn, True)
