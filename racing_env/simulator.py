"""Compiled (numba) step of many races at once: integration, racing rules, reward, observations.

Everything here works on plain arrays so that one call advances ``B`` races of ``N`` cars:

* ``state``  (B, N, 6) float64, per car ``(s, n, mu, vx, vy, omega)`` with unwrapped ``s``;
* ``action`` (B, N, 2) float64, physical ``(d, delta)`` (already within the vehicle's bounds);
* a :class:`TrackTables` of per-grid-point curvature, edges and walls.

One control period ``dt`` is integrated with classical RK4 sub-steps whose number adapts to
the stiffness of the lateral dynamics (many at a standing start, two at racing speed), so the
integration is stable at every speed. The paper's rules apply (see
:class:`racing_env.config.RulesConfig`): contact slow-down, checked over the sub-steps and
applied at the moment of contact (see :func:`_step_one_race`), with the bodies kept apart
(:func:`_separate`: no car passes through another), and, after the dynamics,
off-track slow-down with re-alignment. A car cannot go more than ``wall_margin`` beyond an edge (a wall stops it
sideways) and cannot roll backwards (``vx >= 0``: a brake stops a car, it does not reverse it).
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from .interp import periodic_lookup as _lookup  # also imported from here by controllers, agents.mpc
from .track import Track
from .vehicle import (
    P_BF,
    P_BR,
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

_ode = njit(cache=True)(bind(frenet_ode, math))

# rule vector layout (see RulesConfig.pack)
(
    R_CONTACT_ON,
    R_CONTACT_DS,
    R_CONTACT_DN,
    R_FRONT,
    R_REAR,
    R_OFF_ON,
    R_OFF_FACTOR,
    R_MAX_SUB,
    R_SUB_GAIN,
) = range(9)


@dataclass(frozen=True)
class TrackTables:
    """Per-grid-point tables of a track, shape (M,) each, for the compiled kernels."""

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
        with np.errstate(divide="ignore"):
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


@njit(cache=True)
def _n_substeps(vx, p, dt, gain, max_sub):
    """Sub-steps for stable RK4: h * lambda_max <= 2.5 / gain (RK4 is stable to about 2.8)."""
    ca_f = p[P_BF] * p[P_CF] * p[P_DF]
    ca_r = p[P_BR] * p[P_CR] * p[P_DR]
    # with the low-speed force fade, C / (m v) peaks near C / (m 2 v_low)
    v = math.sqrt(vx * vx + 4.0 * p[P_VLOW] * p[P_VLOW])
    lam = (ca_f + ca_r) / (p[P_M] * v) + (ca_f * p[P_LF] ** 2 + ca_r * p[P_LR] ** 2) / (p[P_IZ] * v)
    k = int(math.ceil(dt * lam * gain / 2.5))
    return min(max(k, 2), max_sub)


@njit(cache=True, inline="always")
def _rk4_substep(x, d, delta, kappa_tab, ds, length, p, h):
    """One classical RK4 step of length ``h`` of one car's state ``x`` (6,), in place."""
    s, n, mu, vx, vy, om = x[0], x[1], x[2], x[3], x[4], x[5]
    k1 = _ode(n, mu, vx, vy, om, d, delta, _lookup(kappa_tab, s, ds, length), p)
    s2 = s + 0.5 * h * k1[0]
    k2 = _ode(
        n + 0.5 * h * k1[1],
        mu + 0.5 * h * k1[2],
        vx + 0.5 * h * k1[3],
        vy + 0.5 * h * k1[4],
        om + 0.5 * h * k1[5],
        d,
        delta,
        _lookup(kappa_tab, s2, ds, length),
        p,
    )
    s3 = s + 0.5 * h * k2[0]
    k3 = _ode(
        n + 0.5 * h * k2[1],
        mu + 0.5 * h * k2[2],
        vx + 0.5 * h * k2[3],
        vy + 0.5 * h * k2[4],
        om + 0.5 * h * k2[5],
        d,
        delta,
        _lookup(kappa_tab, s3, ds, length),
        p,
    )
    s4 = s + h * k3[0]
    k4 = _ode(
        n + h * k3[1],
        mu + h * k3[2],
        vx + h * k3[3],
        vy + h * k3[4],
        om + h * k3[5],
        d,
        delta,
        _lookup(kappa_tab, s4, ds, length),
        p,
    )
    for j in range(6):
        x[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
    if x[3] < 0.0:
        x[3] = 0.0
    if x[2] > math.pi or x[2] < -math.pi:
        x[2] = (x[2] + math.pi) % (2.0 * math.pi) - math.pi


@njit(cache=True)
def integrate_car(x, d, delta, kappa_tab, ds, length, p, dt, n_sub):
    """Advance one car's state ``x`` (6,) in place over ``dt`` with ``n_sub`` RK4 steps."""
    h = dt / n_sub
    for _ in range(n_sub):
        _rk4_substep(x, d, delta, kappa_tab, ds, length, p, h)


@njit(cache=True, inline="always")
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


@njit(cache=True, inline="always")
def _cut(x, applied, i, f):
    """Slow car ``i`` so that its total cut in this period is ``min(applied[i], f)``."""
    if f < applied[i]:
        x[3] = x[3] * f / applied[i] if applied[i] > 0.0 else 0.0
        applied[i] = f


def _step_one_race(
    b,
    state,
    phys,
    kappa_tab,
    w_left,
    w_right,
    wall_left,
    wall_right,
    ds,
    length,
    p,
    dt,
    rules,
    reward,
    contact,
    offtrack,
    substeps,
):
    """Physics, rules and reward of race ``b`` for one control period (inputs ``phys`` (N, 2)).

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
    for i in range(n_cars):
        before[i] = state[b, i, 0]
        x = state[b, i]
        x0[i] = x
        k = _n_substeps(x[3], p, dt, rules[R_SUB_GAIN], max_sub)
        k_max = max(k_max, k)
        substeps[b, i] = k
        lo_n[i] = x[1]
        hi_n[i] = x[1]
        h = dt / k
        for _ in range(k):
            _rk4_substep(x, phys[i, 0], phys[i, 1], kappa_tab, ds, length, p, h)
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
        margin = 0.01  # [m] covers the difference between the two integrations
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
                kappa_tab,
                ds,
                length,
                p,
                dt,
                k_max,
                c_ds,
                c_dn,
                rules[R_FRONT],
                rules[R_REAR],
                applied,
                contact,
                substeps,
                ahead,
            )
            _clamp_to_walls(b, state, wall_left, wall_right, ds, length)
            # a wall may have moved a car sideways into another: keep them apart
            _separate(b, state, x0, ahead, length, c_ds, c_dn, False)
    if not possible:
        _clamp_to_walls(b, state, wall_left, wall_right, ds, length)
    for i in range(n_cars):
        x = state[b, i]
        if x[1] > _lookup(w_left, x[0], ds, length) or x[1] < -_lookup(w_right, x[0], ds, length):
            offtrack[b, i] = 1
            if rules[R_OFF_ON] > 0.0:
                _cut(x, applied, i, rules[R_OFF_FACTOR])
                x[2] = 0.0
                x[4] = 0.0
                x[5] = 0.0
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


@njit(cache=True, inline="always")
def _clamp_to_walls(b, state, wall_left, wall_right, ds, length):
    """A car cannot go further than a wall: it stops sideways there (race ``b``, in place)."""
    for i in range(state.shape[1]):
        x = state[b, i]
        wl = _lookup(wall_left, x[0], ds, length)
        wr = _lookup(wall_right, x[0], ds, length)
        if x[1] > wl or x[1] < -wr:
            x[1] = wl if x[1] > wl else -wr
            x[2] = 0.0
            x[4] = 0.0
            x[5] = 0.0


@njit(cache=True, inline="always")
def _wrapped(d, length):
    """``d`` wrapped into [-length/2, length/2)."""
    return (d + 0.5 * length) % length - 0.5 * length


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


def _lockstep_with_contact(
    b,
    state,
    phys,
    x0,
    kappa_tab,
    ds,
    length,
    p,
    dt,
    n_sub,
    c_ds,
    c_dn,
    front_f,
    rear_f,
    applied,
    contact,
    substeps,
    ahead,
):
    """Integrate race ``b`` again from ``x0`` (N, 6) with every car in lockstep (``n_sub`` RK4
    sub-steps), applying the contact rule at each pair's first moment of contact and keeping
    the bodies apart after every sub-step (:func:`_separate`; ``ahead`` (N, N) is filled with
    the pairs' order)."""
    n_cars = x0.shape[0]
    half = 0.5 * length
    h = dt / n_sub
    d_start = np.empty((n_cars, n_cars))  # wrapped s_i - s_j at the start of the period
    hit = np.zeros((n_cars, n_cars), dtype=np.bool_)
    prev = np.empty((n_cars, 2))
    prev_x = np.empty((n_cars, 6))
    for i in range(n_cars):
        state[b, i] = x0[i]
        substeps[b, i] = n_sub
        for j in range(n_cars):
            d_start[i, j] = (x0[i, 0] - x0[j, 0] + half) % length - half
            ahead[i, j] = d_start[i, j] > 0.0 or (d_start[i, j] == 0.0 and i < j)
    for m in range(n_sub + 1):
        if m > 0:
            for i in range(n_cars):
                prev[i, 0] = state[b, i, 0] - x0[i, 0]
                prev[i, 1] = state[b, i, 1]
                prev_x[i] = state[b, i]
                _rk4_substep(state[b, i], phys[i, 0], phys[i, 1], kappa_tab, ds, length, p, h)
        for i in range(n_cars):
            for j in range(i + 1, n_cars):
                if hit[i, j]:
                    continue
                ds1 = d_start[i, j] + (state[b, i, 0] - x0[i, 0]) - (state[b, j, 0] - x0[j, 0])
                dn1 = state[b, i, 1] - state[b, j, 1]
                if m == 0:  # already touching at the start of the period
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
                        x[:] = prev_x[car]
                        if u > 0.0:
                            _rk4_substep(
                                x, phys[car, 0], phys[car, 1], kappa_tab, ds, length, p, u * h
                            )
                    _cut(x, applied, car, f)
                    if m > 0 and u < 1.0:
                        _rk4_substep(
                            x, phys[car, 0], phys[car, 1], kappa_tab, ds, length, p, (1.0 - u) * h
                        )
        if m > 0:
            _separate(b, state, prev_x, ahead, length, c_ds, c_dn, True)


def _advance(
    state,
    action,
    normalised,
    act_map,
    kappa_tab,
    w_left,
    w_right,
    wall_left,
    wall_right,
    ds,
    length,
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
    where,
):
    """Advance every race in ``state`` (B, N, 6) by one control period, in place.

    ``action`` (B, N, 2): normalised [-1, 1] actions if ``normalised`` (clipped, then mapped
    with ``act_map = (d_mid, d_half, delta_max)``), else physical ``(d, delta)``.
    Per-car outputs (B, N): ``reward`` the change of (s_i - max_{j != i} s_j) (the change of
    s_i when N == 1), ``contact`` / ``offtrack`` 1 if that rule applied this step,
    ``substeps`` RK4 sub-steps used, ``lap_event`` the race time [s] of a lap completed this
    step or -1. Running totals updated: ``t`` (B,), ``laps``, ``contacts``, ``offtracks``.
    Returns 0, or 1 if an action is bad (NaN; or, for physical inputs, not finite: normalised
    +-inf is clipped like any out-of-range value) / 2 if a state became non-finite, with the
    race and car in ``where`` (2,); nothing is stepped when an action is bad.
    """
    n_races, n_cars = state.shape[0], state.shape[1]
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
            b,
            state,
            phys,
            kappa_tab,
            w_left,
            w_right,
            wall_left,
            wall_right,
            ds,
            length,
            p,
            dt,
            rules,
            reward,
            contact,
            offtrack,
            substeps,
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


def _observe(state, kappa_tab, ds, length, preview_ds, n_preview, s_clip, out):
    """Per-car observations ``out`` (B, N, 6 + 6 (N - 1) + n_preview) float32 from ``state``.

    Layout for car i: own ``(s mod length, n, mu, vx, vy, omega)``; then for every other car j
    in index order ``(s_j - s_i, n_j - n_i, wrap(mu_j - mu_i), vx_j - vx_i, vy_j - vy_i,
    omega_j - omega_i)`` with unwrapped s difference clipped to +-s_clip; then kappa at
    ``s_i + k * preview_ds`` for k = 0..n_preview-1.
    """
    n_races, n_cars = state.shape[0], state.shape[1]
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


_separate = njit(cache=True)(_separate)
_lockstep_with_contact = njit(cache=True)(_lockstep_with_contact)
_step_one_race = njit(cache=True)(_step_one_race)
advance = njit(cache=True)(_variant(_advance, "_serial"))
advance_parallel = njit(cache=True, parallel=True)(_variant(_advance, "_parallel"))
observe = njit(cache=True)(_variant(_observe, "_serial"))
observe_parallel = njit(cache=True, parallel=True)(_variant(_observe, "_parallel"))
