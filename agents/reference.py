"""The paper's policy parametrization: theta = (q, zeta, s1, s2, s3) and the MPC reference.

Section "Policy Parametrization" of the paper restricts every car's policy to an MPC that tracks
a *reference trajectory*; five numbers shape both:

* ``q``    weight of the position-tracking cost, ``Q = q I`` (``R = I`` on input rates);
* ``zeta`` scale of the race-line velocities (the *perturbed race line*);
* ``s1``   lateral clearance wanted when overtaking;
* ``s2``   how sharply the overtake / block shifts decay with longitudinal distance;
* ``s3``   blocking strength.

:func:`reference_trajectory` builds the reference ``(s_ref, n_ref)`` for the MPC's predicted
states ``k = 1..K`` exactly as the paper does (see its docstring for the one sign we changed),
:func:`opponent_neighbours` picks the car just ahead ``j^*`` and just behind ``j_*``.

Conventions (same as :mod:`racing_env`): Frenet state ``(s, n, mu, vx, vy, omega)`` with
*unwrapped* ``s`` [m] (``s`` and ``s + k L`` are the same place on different laps), ``n`` [m]
lateral offset, left positive, ``mu`` [rad] heading relative to the centre line, ``vx, vy``
[m/s] body-frame velocities, ``omega`` [rad/s] yaw rate. Every longitudinal difference in this
module is a difference of unwrapped progress, never a wrapped one.

Everything is numpy, with no Python loop over the horizon (only over the <= 2 neighbours);
per-(race line, track) tables are computed once and cached (:mod:`agents.reference_tables`).
Measured on a shared 2-core box: about 26 us per call without opponents and 70 us with both
neighbours inside the shift range (K = 15), 15-20 us more when theta is passed as an array
instead of a :class:`Theta`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from racing_env.vehicle import VehicleParams

from . import theta as _theta
from .neighbours import _neighbours_list, opponent_neighbours  # noqa: F401 (re-exported)
from .reference_tables import (
    _CACHE,  # noqa: F401 (re-exported)
    _check_horizon,
    _interp1,
    _run_up,  # noqa: F401 (re-exported)
    _steps,
    _Tables,
    _tables,
    clear_cache,
)
from .theta import *  # noqa: F403 (theta's public names, re-exported: see __all__)
from .theta import Theta
from .wake_moves import TOW_RANGE  # noqa: F401 (re-exported: the tow's geometry)
from .wake_moves import wake_moves as _wake_moves

_ORCA = VehicleParams()  # the default size (built once, not in every decision)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from racing_env.raceline.result import Raceline
    from racing_env.track import Track

__all__ = [
    *_theta.__all__,
    "Reference",
    "opponent_neighbours",
    "reference_trajectory",
    "clear_cache",
]


# ====================================================================== reference
class Reference:
    """Result of :func:`reference_trajectory`; arrays have shape (K,), entry ``k-1`` belongs to
    the MPC's predicted state ``k = 1..K``.

    * ``s_ref`` [m] unwrapped reference progress (= the perturbed race line's ``s_pert``);
    * ``n_ref`` [m] lateral reference, ``clip(n_pert + n_ot + n_bl)`` to the track minus half
      the car's width;
    * ``n_pert`` [m] perturbed race line, ``n_ot`` [m] overtake shift, ``n_bl`` [m] block shift;
    * ``v_pert`` [m/s] perturbed race-line progress rate ``zeta * s_dot_rl`` at step ``k``;
    * ``ahead`` / ``behind``: opponent row indices of ``j^*`` / ``j_*`` (``-1`` if none);
    * ``side``: the side (+1 left, -1 right) on which the overtake shift passes ``j^*`` when
      :func:`reference_trajectory` chose it (``side`` given), 0 where no shift applies.
    """

    __slots__ = ("s_ref", "n_ref", "n_pert", "n_ot", "n_bl", "v_pert", "ahead", "behind", "side")

    def __init__(self, s_ref, n_ref, n_pert, n_ot, n_bl, v_pert, ahead, behind, side=0.0):
        self.s_ref, self.n_ref, self.n_pert = s_ref, n_ref, n_pert
        self.n_ot, self.n_bl, self.v_pert = n_ot, n_bl, v_pert
        self.ahead, self.behind, self.side = ahead, behind, side

    @property
    def s_pert(self) -> np.ndarray:
        """Perturbed race-line progress [m] (identical to ``s_ref``)."""
        return self.s_ref

    def __repr__(self) -> str:
        return (
            f"Reference(K={len(self.s_ref)}, s {self.s_ref[0]:.3f}..{self.s_ref[-1]:.3f} m, "
            f"ahead={self.ahead}, behind={self.behind}, "
            f"max|n_ot|={np.max(np.abs(self.n_ot)):.3g} m, "
            f"max|n_bl|={np.max(np.abs(self.n_bl)):.3g} m)"
        )


_STATE_NAMES = ("s", "n", "mu", "vx", "vy", "omega")


def _bad_state(name: str, arr: np.ndarray) -> None:
    flat = arr.reshape(-1, 6)
    r, c = np.argwhere(~np.isfinite(flat))[0]
    where = f"{name}[{r}]" if arr.ndim == 2 else name
    raise ValueError(f"{where} state {_STATE_NAMES[c]} is not finite: {float(flat[r, c])!r}")


def reference_trajectory(
    theta: Theta | Sequence[float] | np.ndarray,
    ego: np.ndarray,
    opponents: np.ndarray | None,
    raceline: Raceline,
    track: Track,
    K: int = 15,
    dt: float = 0.1,
    vehicle_width: float | None = None,
    friction: float | None = None,
    integration: str = "exact",
    reachable: bool = True,
    blend: Raceline | None = None,
    side: float | str | None = None,
    vehicle: object | None = None,
    tow: bool = False,
) -> Reference:
    """The MPC reference of the paper for one car.

    Parameters
    ----------
    theta : :class:`Theta` or array-like (5,)
        ``(q, zeta, s1, s2, s3)``; validated against ``THETA_LOW``/``THETA_HIGH``
        (``q`` is not used here, it weighs the MPC cost).
    ego : array (6,)
        The car's Frenet state ``(s, n, mu, vx, vy, omega)``, ``s`` unwrapped.
    opponents : array (m, 6), m = 0..7 (or ``None``)
        The other cars' states, same convention.
    raceline : :class:`racing_env.raceline.Raceline` of ``track``
    track : :class:`racing_env.track.Track`
    K : int, dt : float [s]
        Horizon steps and step length.
    vehicle_width : float [m]
        Width used for the track clip (default ``VehicleParams().width`` = 0.06 m).
    friction : float
        Speed profile of the race line's library (default: nominal).
    integration : ``"exact"`` or ``"euler"``
        How the perturbed race line integrates the race-line velocity (see step 1).
    reachable : bool
        Cap the reference's progress at what the car can reach from its current speed
        (step 1b; default). ``False`` is the paper's reference, literally.
    vehicle : the car's parameters (default ``None``: the ORCA car)
        Of another vehicle class, theta's lengths are read in that class's size
        (:func:`agents.theta.theta_length_scales`: ``s1`` in car widths, ``s2`` in car
        lengths, ``s3`` per share of the top speed), :data:`PASS_ROOM` is scaled by the width
        ratio and ``vehicle_width`` defaults to its width. The run-up of step 1b is the
        track's vehicle class's (``track.vehicle_class``).
    tow : bool
        Do not hold back a car that is faster than the race line (step 1c; default off, the
        paper's reference; the MPC agent turns it on in a world with a wake).

    Construction (``k = 1..K``, every longitudinal difference on unwrapped progress):

    1. *Perturbed race line.* Start at the race-line point nearest the ego: ``s = s_ego``,
       ``n = n_rl(s_ego)``. Sample the race line in time, point ``m`` (``m = 0..K``) being
       where a car on the race-line speed profile is ``m dt`` later, and integrate its Frenet
       velocity ``vbar = (v cos mu_rl / (1 - n_rl kappa), v sin mu_rl)`` (``mu_rl`` the
       race-line heading relative to the centre line) scaled by ``zeta``:
       ``p_pert^k = p_pert^{k-1} + zeta vbar_{k-1} dt``.
       ``integration="exact"`` (default) takes ``vbar_{k-1}`` as the race line's velocity
       *over* step ``k-1`` (its displacement between samples ``k-1`` and ``k`` over ``dt``,
       the exact time average of the formula above), so ``p_pert^k = p^0 + zeta (p_rl(t_k)
       - p_rl(t_0))`` and ``zeta = 1`` reproduces the sampled race line exactly.
       ``integration="euler"`` takes the point velocity at sample ``k-1`` (the literal
       left-point reading): it lags the race line by half a step, on the default track up to
       0.22 m laterally (median 9 cm) at ``zeta = 1``, ``dt = 0.1 s``, which is why it is not
       the default. ``v_pert^k = zeta s_dot_rl(t_k)`` [m/s] in both cases.
       Note that ``zeta`` scales the lateral velocity too, so for ``zeta != 1`` the lateral
       profile is the race line's *in time*, not in space: with ``zeta < 1`` the reference
       swings across the track over a shorter distance than the race line does.
    1b. *Reachable progress* (``reachable=True``, our addition). The race line's time
       sampling starts at the race line's speed wherever the car is, so a car that is slow
       (from rest at the start, after a contact, slowed off the track) is asked to be where
       a car at racing speed would be: the reference runs away from it, the MPC plans to
       chase it into the next corner too fast, and a plan that waits is cheaper than one
       that leaves the track at its tail (a car stopped beside the track could wait for
       ever). So the progress ``s_pert^k - s_ego`` is capped at ``REACH_SLACK`` (1.1) times
       the distance a full-throttle run on a straight covers in ``k dt`` from the car's
       progress rate (the g-g-v envelope's drive limit,
       :func:`~agents.reference_tables._run_up`). Where the cap binds the reference keeps its
       path and arrives later: ``n_pert^k`` is the uncapped reference's lateral offset at the
       capped progress (interpolated in ``s``), and ``v_pert^k`` at most the run's speed. At
       racing speed the run outpaces the profile and the cap does not bind.
    1c. *The tow* (``tow=True``, our addition for worlds with a wake). A car in another's
       wake is faster on a straight than the race line's speed profile, whose top speed is
       the car's own in clean air; tracking the line would make it lift. With a car ahead
       within :data:`TOW_RANGE` (15 lengths, 1.5 widths to the side) and the car's progress
       rate over the line's at its position by :data:`TOW_MARGIN` (1 m/s), the
       reference is at least a run from the car's current speed: full throttle in clean air
       (the run-up of 1b, holding the speed above the top speed), never faster than the
       race line's braking limit (the speed from which the car still brakes for the corners
       ahead, :meth:`~agents.reference_tables._Tables.braking_sdot2`). Where that run is
       ahead of the line's progress it replaces it (``v_pert`` likewise, ``n_pert`` the
       line's offset at the run's progress).
    2. *Opponents* keep their Frenet progress rate ``s_dot_j = (vx cos mu - vy sin mu) /
       (1 - n kappa)`` and lateral position: ``s_j^k = s_j + k dt s_dot_j``, ``n_j^k = n_j``.
       Only ``j^*`` (just ahead) and ``j_*`` (just behind), see :func:`opponent_neighbours`.
    3. *Overtake shift* ``n_ot^k = sum_j sign(n_ego - n_j) max((s1 - |n_ego - n_j|)
       exp(-s2 (s_pert^k - s_j^k)^2), 0)`` with lateral positions at time t. ``sign(0)``
       (level cars) picks the side of the opponent with more room to the track edge at
       ``s_j`` (left on a tie).
    4. *Block shift* ``n_bl^k = sum_j 1(v_pert^k <= v_j) 1(s_pert^k >= s_j^k)
       (n_j^k - n_pert^k) (1 - exp(-s3 (v_j - v_pert^k))) exp(-s2 (s_pert^k - s_j^k)^2)``,
       ``v`` being Frenet progress rates [m/s]. **Sign change:** the paper prints the factor
       ``1 - exp(-s3 (v_pert - v_j))``, which under its own indicator ``v_pert <= v_j`` is
       ``<= 0`` and unbounded below for ``s3 > 0``: it would push the ego *away* from the
       faster car behind, possibly by many times the gap, the opposite of the stated intent
       ("changes the trajectory of the ego vehicle towards trailing vehicle to block it"). We
       use ``1 - exp(-s3 (v_j - v_pert))``, a fraction in ``[0, 1)`` of the lateral gap.
       Like the paper's indicator, the block shift switches off *abruptly* at the step where
       the faster car's prediction passes the reference (``gap`` changes sign while
       ``exp(-s2 gap^2)`` is near 1), so ``n_bl`` can jump by its full size between two steps.
    5. ``n_ref = clip(n_pert + n_ot + n_bl, -w_right(s_ref) + w/2, w_left(s_ref) - w/2)``
       (the paper clips to the track; we keep the car's body on it); ``s_ref = s_pert``.
    6. *The wake space* (``h > 0`` or ``c > 0``; our addition, :data:`WAKE_BOUNDS_DOC`), before
       the clip of 5, with ``L``, ``W`` the car's length and width and ``d_b`` the distance
       along the track to the next braking point of the race line (the line of the larger
       blend weight; :meth:`~agents.reference_tables._Tables.brake_points`). *Hold:* with
       ``j^*`` at most ``h L`` ahead and under ``1.5 W`` aside, the ego on a straight
       (``|kappa| L < 0.01`` at its ``s``) and ``d_b > p L``, ``n_ref^k = n_j`` (the car
       ahead's offset, the slipstream) and ``n_ot = n_bl = 0``. *Pull out:* within ``p L``
       of the braking point the hold lets go and 3-4 apply. *Cover:* with ``d_b <= p L`` and
       ``j_*`` at most ``15 L`` behind and under ``1.5 W`` aside, ``n_ref`` moves the
       fraction ``c`` of the way to the inside edge of the coming corner (its apex's side,
       the body on the track).

    Returns a :class:`Reference`. Raises ``ValueError`` on a bad shape, a non-finite state, a
    theta out of bounds, ``K < 1``, ``dt <= 0`` or a car beyond the centre line's radius of
    curvature (``1 - n kappa <= 0``).
    """
    th = theta if isinstance(theta, Theta) else Theta.from_array(theta)
    K, dt = _check_horizon(K, dt)
    if integration == "exact":
        exact = True
    elif integration == "euler":
        exact = False
    else:
        raise ValueError(f"integration must be 'exact' or 'euler', got {integration!r}")
    x = np.asarray(ego, dtype=float)
    if x.shape != (6,):
        raise ValueError(f"ego state must have shape (6,) (s, n, mu, vx, vy, omega), got {x.shape}")
    if not np.isfinite(x).all():
        _bad_state("ego", x)
    if opponents is None:
        m = 0
    else:
        opp = np.asarray(opponents, dtype=float)
        if opp.ndim == 1 and opp.shape == (6,):
            opp = opp[None, :]
        elif opp.size == 0:
            opp = opp.reshape(0, 6)
        if opp.ndim != 2 or opp.shape[1] != 6:
            raise ValueError(f"opponents must have shape (m, 6), got {opp.shape}")
        m = opp.shape[0]
        if m and not np.isfinite(opp).all():
            _bad_state("opponents", opp)
    k_s1, k_s2, k_s3 = _theta.theta_length_scales(vehicle)
    if vehicle_width is None and k_s1 != 1.0:
        vehicle_width = vehicle.width  # type: ignore[union-attr]
    if vehicle_width is None:
        w_half = _DEFAULT_HALF_WIDTH
    else:
        w_half = 0.5 * float(vehicle_width)
        if not (math.isfinite(w_half) and w_half >= 0):
            raise ValueError(
                f"vehicle_width must be a finite width >= 0 [m], got {vehicle_width!r}"
            )
    tab = _tables(raceline, track, friction)
    L, inv_ds = tab.L, tab.inv_ds
    steps, steps1 = _steps(K, dt)  # dt*(0..K), dt*(1..K)
    s_e, n_e = float(x[0]), float(x[1])
    base = math.floor(s_e / L) * L  # start of the ego's lap [m]
    s_e_w = s_e - base  # in [0, L)

    # ---- 1. perturbed race line, sampled in time from the ego's s
    s_pert, n_pert, n_pert0, v_pert = _perturbed_line(tab, th.zeta, s_e, s_e_w, steps, K, dt, exact)
    if th.b > 0.0:  # extended space: blend the lines
        if blend is None:
            raise ValueError(
                f"theta b = {th.b!r} blends in a second race line; pass it as "
                f"blend= (the track's lap-time line)"
            )
        s_b, n_b, n_b0, v_b = _perturbed_line(
            _tables(blend, track, friction), th.zeta, s_e, s_e_w, steps, K, dt, exact
        )
        a = 1.0 - th.b
        s_pert = a * s_pert + th.b * s_b
        n_pert = a * n_pert + th.b * n_b
        n_pert0 = a * n_pert0 + th.b * n_b0
        v_pert = a * v_pert + th.b * v_b
    if reachable:  # ---- 1b. cap at the run-up
        v0 = _ego_rate(x, tab, s_e_w)
        run_t, run_v, run_x = tab.run_t, tab.run_v, tab.run_x
        if v0 < run_v[-1]:
            t0 = float(np.interp(v0, run_v, run_t))
            tr = steps1 + t0
            reach = np.interp(tr, run_t, run_x)
            reach -= float(np.interp(t0, run_t, run_x))
            beyond = tr > run_t[-1]  # past the run's end: at top speed
            if beyond.any():
                reach[beyond] += (tr[beyond] - run_t[-1]) * run_v[-1]
            v_run = np.interp(tr, run_t, run_v)
        else:  # at (or above) the top speed
            reach = steps1 * v0
            v_run = np.full(K, v0)
        reach *= REACH_SLACK
        capped = s_pert - s_e > reach
        if capped.any():
            # same path, later: n as a function of progress along the uncapped reference
            n_pert = np.where(
                capped,
                np.interp(s_e + reach, np.append(s_e, s_pert), np.append(n_pert0, n_pert)),
                n_pert,
            )
            s_pert = np.where(capped, s_e + reach, s_pert)
            v_pert = np.where(capped, np.minimum(v_pert, v_run), v_pert)

    if tow and m and in_a_wake(x, opp, vehicle):  # ---- 1c. not held back in a tow
        tabs = [(1.0 - th.b, tab)] + ([(th.b, _tables(blend, track, friction))] if th.b > 0 else [])
        v_e = _ego_rate(x, tab, s_e_w)
        s_pert, n_pert, v_pert = _tow_floor(
            v_e, tabs, th.zeta, s_e_w, base, s_pert, n_pert, v_pert, dt
        )

    n_ref = n_pert.copy()
    n_ot = n_bl = None  # stay None while no shift applies
    ahead = behind = -1
    pass_side = 0.0
    if m:
        rows = opp.tolist()
        ahead, behind = _neighbours_list([r[0] - s_e for r in rows])
        s1, s2, s3 = th.s1, th.s2, th.s3
        if k_s1 != 1.0:  # another vehicle class: theta's lengths in its size
            s1, s2, s3 = s1 * k_s1, s2 * k_s2, s3 * k_s3
        v_min = float(v_pert.min()) if s3 > 0 else math.inf
        for j in (ahead, behind):  # at most 2; vectorised over K
            if j < 0:
                continue
            sj, nj, muj, vxj, vyj, _ = rows[j]
            sj_w = sj - math.floor(sj / L) * L
            den = 1.0 - nj * _interp1(tab.kap, sj_w, inv_ds)
            if den <= 0:
                raise ValueError(
                    f"opponents[{j}] at n = {nj!r} lies beyond the centre line's "
                    f"radius of curvature (1 - n kappa = {den:.3g} <= 0)"
                )
            vj = (vxj * math.cos(muj) - vyj * math.sin(muj)) / den  # Frenet progress rate
            gap = steps1 * -vj
            gap -= sj
            gap += s_pert  # (K,) s_pert^k - s_j^k, unwrapped
            decay = gap * gap
            decay *= -s2
            np.exp(decay, out=decay)  # (K,) exp(-s2 gap^2)
            # ---- 3. overtake: sign(dn) max((s1 - |dn|) decay, 0); decay > 0 leaves the max
            #      to the scalar (s1 - |dn|)
            dn = n_e - nj
            if side is not None and j == ahead:  # extended: chosen / held side
                sgn = _pass_side(side, dn, nj, sj_w, tab, inv_ds, w_half, PASS_ROOM * k_s1)
                c = s1 - sgn * dn  # to s1 beside j on that side
                pass_side = sgn if decay.max() > PASS_HOLD_DECAY else 0.0
            else:
                c = s1 - abs(dn)
                if dn > 0:
                    sgn = 1.0
                elif dn < 0:
                    sgn = -1.0
                else:  # level: side with more room
                    room_l, room_r = _room(tab, sj_w, inv_ds, nj)
                    sgn = 1.0 if room_l >= room_r else -1.0
            if c > 0:
                decay_c = decay * (sgn * c)
                if n_ot is None:
                    n_ot = decay_c
                else:
                    n_ot += decay_c
            # ---- 4. block: 1(v_pert <= v_j) 1(gap >= 0) (n_j - n_pert)
            #      (1 - exp(-s3 (v_j - v_pert))) decay   (sign of the s3 factor: see docstring).
            # The speed indicator is implicit: 1 - exp(-s3 max(v_j - v_pert, 0)) is 0 where
            # the ego reference is at least as fast.
            if s3 > 0 and vj >= v_min:
                behind_ref = gap >= 0  # (K,) 1(s_pert^k >= s_j^k)
                if behind_ref.any():
                    dv = v_pert - vj  # (K,) < 0 where j is faster
                    dv *= s3
                    np.minimum(dv, 0.0, out=dv)
                    np.expm1(dv, out=dv)  # -(1 - exp(-s3 max(v_j - v_pert, 0)))
                    dv *= decay
                    decay_c = n_pert - nj  # (n_pert - n_j) flips the sign back
                    dv *= decay_c
                    dv *= behind_ref
                    if n_bl is None:
                        n_bl = dv
                    else:
                        n_bl += dv
    if n_ot is not None:
        n_ref += n_ot
    if n_bl is not None:
        n_ref += n_bl
    if n_ot is None:
        n_ot = np.zeros(K)
    if n_bl is None:
        n_bl = np.zeros(K)
    if m and (th.h > 0.0 or th.c > 0.0):  # ---- 6. the wake space: hold, pull out, cover
        tab_w = _tables(blend, track, friction) if th.b >= 0.5 else tab
        n_ref, n_ot, n_bl = _wake_moves(
            th, x, rows, ahead, behind, tab_w, vehicle, w_half, s_e_w, n_ref, n_ot, n_bl
        )

    # ---- 5. clip to the track at s_ref
    if tab.w_const is not None:  # constant widths: scalar bounds
        np.minimum(n_ref, tab.w_const[0] - w_half, out=n_ref)
        np.maximum(n_ref, w_half - tab.w_const[1], out=n_ref)
    else:
        s_w = s_pert - base  # [0, 2L) unless the horizon is long
        if s_w[-1] >= 2.0 * L:
            s_w = s_w - np.floor(s_w / L) * L
        hi = np.interp(s_w, tab.st2, tab.wl2)
        hi -= w_half
        lo = np.interp(s_w, tab.st2, tab.wr2)
        lo -= w_half
        np.minimum(n_ref, hi, out=n_ref)
        np.negative(lo, out=lo)
        np.maximum(n_ref, lo, out=n_ref)
    return Reference(s_pert, n_ref, n_pert, n_ot, n_bl, v_pert, ahead, behind, pass_side)


PASS_HOLD_DECAY = 1e-3
"""The chosen side is reported (and an agent may hold it) while the overtake shift's decay
``exp(-s2 gap^2)`` exceeds this somewhere on the horizon."""
PASS_ROOM = 0.12
"""Least free width [m] beside the car ahead, between it and the track edge (two car widths),
for the extended space's ``side="room"`` rule to pass on that side."""


def _room(tab: _Tables, sj_w: float, inv_ds: float, nj: float) -> tuple[float, float]:
    """Room [m] between a car at lateral offset ``nj`` and the left and right track edges at
    wrapped progress ``sj_w``."""
    return _interp1(tab.wl, sj_w, inv_ds) - nj, _interp1(tab.wr, sj_w, inv_ds) + nj


def _pass_side(side, dn, nj, sj_w, tab, inv_ds, w_half, pass_room=PASS_ROOM) -> float:
    """The side (+1 left, -1 right) of the car ahead to pass on: ``side`` itself when it is
    +-1 (held by the agent), else (``"room"``) the side the ego is on (``sign(dn)``, the one
    with more room when level), unless the room between the car ahead and that edge is below
    :data:`PASS_ROOM` and the other side has more."""
    if side == 1 or side == -1:
        return float(side)
    if side != "room":
        raise ValueError(f"side must be None, 'room', 1 or -1, got {side!r}")
    room_l, room_r = _room(tab, sj_w, inv_ds, nj)
    room_l -= w_half
    room_r -= w_half
    sgn = 1.0 if dn > 0 or (dn == 0 and room_l >= room_r) else -1.0
    mine, other = (room_l, room_r) if sgn > 0 else (room_r, room_l)
    if mine < pass_room and other > mine:
        sgn = -sgn
    return sgn


#: How much faster [m/s] than the race line's progress rate a car must be for the reference to
#: follow it rather than hold it back (step 1c of :func:`reference_trajectory`).
TOW_MARGIN = 1.0


def in_a_wake(
    x: np.ndarray,
    opp: np.ndarray,
    vehicle: object | None,
    reach: tuple[float, float] = TOW_RANGE,
) -> bool:
    """Whether a car of ``opp`` (m, 6) is ahead of the ego ``x`` (6,) within ``reach``
    (default :data:`TOW_RANGE`: lengths and widths of ``vehicle``, the ORCA car's without
    one)."""
    length = float(getattr(vehicle, "length", _ORCA.length))
    width = float(getattr(vehicle, "width", _ORCA.width))
    gap = opp[:, 0] - float(x[0])
    side = np.abs(opp[:, 1] - float(x[1]))
    return bool(np.any((gap > 0) & (gap < reach[0] * length) & (side < reach[1] * width)))


def _ego_rate(x, tab, s_e_w: float) -> float:
    """The car's progress rate [m/s] along the centre line, at least 0:
    ``(vx cos mu - vy sin mu) / (1 - n kappa)``; a ``ValueError`` where the car lies beyond the
    centre line's radius of curvature (``1 - n kappa <= 0``)."""
    den = 1.0 - float(x[1]) * _interp1(tab.kap, s_e_w, tab.inv_ds)
    if den <= 0:
        raise ValueError(
            f"ego at n = {float(x[1])!r} lies beyond the centre line's radius of "
            f"curvature (1 - n kappa = {den:.3g} <= 0)"
        )
    return max((x[3] * math.cos(x[2]) - x[4] * math.sin(x[2])) / den, 0.0)


def _tow_floor(v, tabs, zeta, s_e_w, base, s_pert, n_pert, v_pert, dt):
    """Step 1c of :func:`reference_trajectory`: ``(s_pert, n_pert, v_pert)`` (K,) with the
    progress raised, where the car at progress rate ``v`` [m/s] outruns the race line, to a
    run from its current speed under the braking limit. ``tabs``: ``[(weight, tables)]`` of
    the line (and the blended line), whose weighted progress rates and offsets make the line;
    ``s_e_w`` the car's progress on the lap, ``base`` the lap's start [m]."""
    v_line = sum(w * float(np.interp(s_e_w, t.st2, t.sdot2)) for w, t in tabs) * zeta
    if not v > v_line + TOW_MARGIN:
        return s_pert, n_pert, v_pert
    tab = tabs[0][1]
    run_t, run_v = tab.run_t, tab.run_v
    K = s_pert.shape[0]
    s_f = np.empty(K)
    v_f = np.empty(K)
    s = s_e_w  # on the two-lap grid
    brakes = [(w, t, t.braking_sdot2()) for w, t in tabs]
    for k in range(K):
        if v < run_v[-1]:  # full throttle in clean air from v ...
            v_new = float(np.interp(np.interp(v, run_v, run_t) + dt, run_t, run_v))
        else:  # ... or hold a speed above the top speed (the tow's)
            v_new = v
        v_brk = sum(w * float(np.interp(s, t.st2, b)) for w, t, b in brakes)
        v_new = min(v_new, v_brk)
        s += 0.5 * (v + v_new) * dt
        v = v_new
        s_f[k], v_f[k] = s + base, v
    ahead = s_f > s_pert
    if not ahead.any():
        return s_pert, n_pert, v_pert
    n_f = sum(w * np.interp(s_f - base, t.st2, t.nrl2) for w, t in tabs)
    return (
        np.where(ahead, s_f, s_pert),
        np.where(ahead, n_f, n_pert),
        np.where(ahead, v_f, v_pert),
    )


def _perturbed_line(tab, zeta, s_e, s_e_w, steps, K, dt, exact):
    """Step 1 of :func:`reference_trajectory` on one race line's tables: ``(s_pert, n_pert,
    n_pert0, v_pert)``, shapes (K,), (K,), scalar, (K,)."""
    L, T, inv_ds = tab.L, tab.T, tab.inv_ds
    tk = steps + _interp1(tab.tt, s_e_w, inv_ds)  # (K+1,) race-line times [s]
    if tk[-1] < 2.0 * T:
        skw = np.interp(tk, tab.tt2, tab.st2)  # race-line s at tk, 0..2L [m]
        sk = skw  # ... already unwrapped from base
    else:  # horizon longer than a lap
        lapk = np.floor(tk / T)
        skw = np.interp(tk - lapk * T, tab.tt2, tab.st2)  # wrapped, [0, L]
        sk = skw + lapk * L  # unwrapped from base
    sd = np.interp(skw, tab.st2, tab.sdot2)  # (K+1,) race-line s_dot [m/s]
    if exact:
        # step velocity = race-line displacement over the step / dt (exact time average of the
        # Frenet velocity), so p_pert^k = p^0 + zeta (p_rl(t_k) - p_rl(t_0))
        nk = np.interp(skw, tab.st2, tab.nrl2)  # (K+1,) race-line n at t_k
        s_pert = sk[1:] - sk[0]
        s_pert *= zeta
        s_pert += s_e
        n_pert0 = float(nk[0])
        n_pert = nk[1:] - nk[0]
        n_pert *= zeta
        n_pert += nk[0]
    else:
        # explicit Euler on the point velocities at t_{k-1}, literally as printed
        nd = np.interp(skw, tab.st2, tab.ndot2)  # (K+1,) race-line n_dot [m/s]
        zdt = zeta * dt
        s_pert = sd[:K].cumsum()
        s_pert *= zdt
        s_pert += s_e
        n_pert0 = _interp1(tab.nrl, s_e_w, inv_ds)
        n_pert = nd[:K].cumsum()
        n_pert *= zdt
        n_pert += n_pert0
    v_pert = sd[1:]
    v_pert *= zeta  # (K,) zeta * s_dot_rl(t_k)
    return s_pert, n_pert, n_pert0, v_pert


_DEFAULT_HALF_WIDTH = 0.5 * VehicleParams().width

REACH_SLACK = 1.1
"""The reachable-progress cap (step 1b of :func:`reference_trajectory`) is this multiple of
the full-throttle run's distance: it binds only on a car at least 10% behind its reference's
pace (from rest, after a contact or off the track), not on a car at the limit whose reference
asks for a few per cent more (zeta up to 1.05), which a hard cap slowed by about 1% a lap."""
