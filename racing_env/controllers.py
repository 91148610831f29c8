"""The built-in raceline-following controller.

It follows the agent protocol of :mod:`agents` (``reset(track, agent_id, seed)``,
``act(observation) -> action``) so it can drive opponents inside the Gymnasium env without
``racing_env`` importing ``agents``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from .config import RaceConfig, _is_int
from .interp import periodic_lookup as _lookup
from .observation import split_observation
from .track import Track
from .tracks import make_track
from .vehicle import VehicleParams
from .vehicles import FullSizeParams, vehicle_for_track
from .vehicles.fullsize import (
    P_BR,
    P_CLF,
    P_CLR,
    P_CR,
    P_EPSF,
    P_EPSR,
    P_FBRAKE,
    P_FZ0,
    P_FZSHIFT,
    P_G,
    P_KBF,
    P_MU,
)
from .vehicles.fullsize import P_LF as P_LF_FS
from .vehicles.fullsize import P_LR as P_LR_FS
from .vehicles.fullsize import P_M as P_M_FS
from .vehicles.fullsize import P_VLOW as P_VLOW_FS

if TYPE_CHECKING:
    from .raceline import Raceline, RacelineConfig

#: where the full-size class's constants start in :meth:`RacelineFollower.gains` (the ORCA
#: car's gains end there: its feed-forward and its races stay the same bit for bit)
FULLSIZE_GAINS = 13
#: shares ``(drive, brake)`` of an axle's peak force the full-size follower asks of it along
#: the car (its traction and brake limits). At the peak itself the friction ellipse leaves the
#: axle almost no lateral force and the car spins or goes straight on; with the yaw-rate
#: damping and the traction rule of :data:`FULLSIZE_STEER` 90% holds (a fixed 60% drive, used
#: before them, lost 1-2 s a lap at slow corners' exits; 90% without them spun the car at
#: 36 m/s on Monza's straight).
FULLSIZE_GRIP_USE = (0.9, 0.9)
#: least share of an axle's peak force along the car that the full-size follower's friction
#: ellipse leaves it (:func:`_fullsize_long_room`) where the corner asks all its grip across
FULLSIZE_LONG_FLOOR = 0.3
#: the full-size follower's steering law ``(preview_floor [m], preview_time [s], k_yaw [-],
#: slip_onset [-], speed_preview [s], k_mu [-])``: a preview ``D = max(preview_floor, preview_time
#: vx)`` (the ORCA law's ``preview_min`` scaled by the length ratio, 19.6 m, is 1.6 s at 12 m/s: the car cut
#: Monza's first chicane); yaw-rate damping ``k_yaw L (vx kappa_cmd - omega) / vx`` added to
#: the steering (it counter-steers a car that yaws faster than its path asks); and a
#: traction rule: the drive share falls linearly from ``slip_onset`` of the rear tyre's peak
#: slip angle to nothing at the peak (the rear's lateral force is what keeps the car's yaw
#: stable); its speed target is the profile's ``speed_preview`` s ahead (its brakes ask
#: ``FULLSIZE_GRIP_USE[1]`` of the front's peak where the profile asks all of it: with the
#: ORCA law's 0.3 s it reached Monza's first chicane 3 m/s too fast); ``slip_onset`` >= 1:
#: no traction rule. ``k_mu`` is the heading error's gain ``k_mu / D`` (the ORCA law's 2):
#: at 2 the car lagged its line by up to 1.7 m through Monza's Curva Grande at 49 m/s, on
#: the inside edge's last 5 cm in clean air, and a follower in dirty air left the track
#: there about once a race; at 3 it no longer did (4 seeds of two followers, 90 s; lateral
#: gains of 2 and 4 instead, or a shorter preview, made it weave off the track)
FULLSIZE_STEER = (6.0, 0.7, 0.6, 0.3, 0.6, 3.0)


def understeer_gradient(v: VehicleParams | FullSizeParams) -> float:
    """Linear-range understeer gradient K_us [rad s^2/m] of the bicycle model:
    ``delta = L kappa + K_us v^2 kappa`` in steady cornering (cornering stiffness = B C D).

    For the full-size class D is each axle's peak force at its static load (no downforce:
    K_us is then -6.8e-5 rad s^2/m, slightly oversteering; with the downforce of 60 m/s it
    is nearly neutral, 2e-7, so the steering differs by under 0.1% of ``L kappa``)."""
    if isinstance(v, FullSizeParams):
        d_f, d_r = v.axle_grip(0.0)
        ca_f, ca_r = v.B_f * v.C_f * d_f, v.B_r * v.C_r * d_r
    else:
        ca_f, ca_r = v.Bf * v.Cf * v.Df, v.Br * v.Cr * v.Dr
    return v.m / (v.lf + v.lr) * (v.lr / ca_f - v.lf / ca_r)


def raceline_config_for(
    vehicle: VehicleParams | FullSizeParams, objective: str = "curvature"
) -> RacelineConfig:
    """The racing-line settings of ``vehicle``'s class with objective ``objective``: the
    package's defaults for the ORCA car, for another class the same scaled to the car's size
    (:func:`racing_env.scaling.scaled_configs`, its ``raceline``: edge margin and station
    spacing). Every agent of a class races on the line of these settings."""
    from dataclasses import replace

    from .raceline import RacelineConfig

    if isinstance(vehicle, VehicleParams):
        return RacelineConfig(objective=objective)
    base = RacelineConfig(objective=objective)
    k = _size_ratios(vehicle)
    return replace(base, **{f: getattr(base, f) * k[kind] for f, kind in _RACELINE_LENGTHS.items()})


# The lengths of racing_env.scaling.SCALED_FIELDS this module scales itself (scaling reads the
# follower's defaults from this module, so it cannot import scaling; a test checks they agree)
_FOLLOWER_LENGTHS = {
    "preview_min": "length",
    "yield_gap": "width",
    "yield_behind": "length",
    "yield_ahead": "length",
}
_RACELINE_LENGTHS = {"margin": "width", "point_spacing": "length"}


def _size_ratios(vehicle: VehicleParams | FullSizeParams) -> dict[str, float]:
    """``{"length": k_len, "width": k_wid}``: the car's size over the ORCA car's (as
    :func:`racing_env.scaling.size_ratios`)."""
    ref = VehicleParams()
    return {"length": vehicle.length / ref.length, "width": vehicle.width / ref.width}


class RacelineFollower:
    """Follows the racing line at the speed profile of envelope scale ``grip`` (agent spec
    ``raceline:grip=0.75``; ``mu=``, its old name, is still accepted with a DeprecationWarning).

    ``line`` picks the line (:data:`racing_env.raceline.OBJECTIVES`): ``"curvature"``
    (default, the paper's minimum-curvature line) or ``"lap_time"``.

    A path follower in the Frenet frame: the commanded path curvature is the racing line's
    curvature ahead plus feedback on the heading and lateral errors to the line, with a
    preview distance ``D = max(preview_min, preview_time * vx)``::

        kappa_cmd = kappa_ref + 2 / D * (mu_ref - (mu + beta)) + 1 / D^2 * (n_ref - n)
        delta     = atan(L kappa_cmd) + K_us vx^2 kappa_cmd

    (``beta`` the body slip angle, ``K_us`` the car's understeer gradient, so the steering
    is right at the grip the speed profile uses). ``line_fraction`` scales the racing line's
    offsets towards the centre line to keep a margin from the edges. Throttle is a
    feed-forward of rolling resistance and drag plus ``k_speed`` times the error to the
    profile speed ``speed_preview`` s ahead (so it brakes before corners). The feed-forward
    is the class's force law: ``(C3 + C4 vx^2) / (C1 - C2 vx)`` for the ORCA car; for the
    full-size class ``(c_drag vx^2 + c_roll m g) / min(F_drive_max, P_max / vx_eff)``, the
    drag and rolling resistance against the power-limited drive.

    The full-size class steers by its own law (:data:`FULLSIZE_STEER`; ``preview_min``,
    ``preview_time`` and ``speed_preview`` are the ORCA car's): the preview is time-based,
    ``D = max(6 m, 0.7 s vx)``; yaw-rate damping ``0.6 L (vx kappa_cmd - omega) / vx`` is
    added to ``delta``; the drive fades out as the rear tyre's slip angle goes from 30% of
    its peak to the peak; the speed target is the profile 0.6 s ahead.

    The vehicle class comes from the track at ``reset`` (``track.vehicle_class``, ``"orca"``
    when absent): without a ``vehicle`` the follower drives the class's default car; a
    ``vehicle`` of another class than the track's is a ``ValueError``. Its lengths
    (``preview_min``, ``yield_gap``, ``yield_behind``, ``yield_ahead``) left at their
    defaults are the ORCA car's and are scaled to the class's size at ``reset``
    (:func:`racing_env.scaling.scaled_configs`); a length given explicitly is used as given
    (in metres, bounded by the ORCA bounds times the class's size ratio when ``vehicle`` is
    given, else by the ORCA bounds).

    It never yields by default. At full size it does not run into a car ahead either
    (``keep_gap``, default None: on for the full-size class, off for the ORCA car, whose
    follower ignores other cars as it always has): its speed target is at most the speed from
    which it can still brake (at :data:`KEEP_DECEL`) to a car's speed before it comes within
    :data:`KEEP_GAP` car lengths of it, for every car ahead within 30 lengths and less than
    1.2 car widths to the side (:meth:`gap_speed`). In full-size racing the car behind
    answers for a collision from behind. ``yield_gap`` [m] > 0 makes it leave
    room: while another car is between ``yield_behind`` [m] behind it and ``yield_ahead`` [m]
    ahead of it (progress difference), the follower's lateral target keeps at least
    ``yield_gap`` from that car's lateral offset on the follower's own side of it (its line is
    shifted away where it would run closer, never past the track's edges). The window is
    closed and read from the observation's relative progress ``s_j - s``, as the env computed
    it; at equal lateral offsets the follower keeps to the left of the other car (``n``
    larger). ``n_preview`` is
    the env's curvature preview length, to read the other cars from the observation.
    """

    #: shown by ``alpha-racer agents`` beside the deprecated keyword
    param_notes = {"mu": "deprecated name of grip"}

    def __init__(
        self,
        vehicle: VehicleParams | FullSizeParams | None = None,
        grip: float = 1.0,
        speed_scale: float = 1.0,
        line_fraction: float = 0.9,
        preview_min: float = 0.5,
        preview_time: float = 0.2,
        speed_preview: float = 0.3,
        k_speed: float = 2.0,
        line: str = "curvature",
        yield_gap: float = 0.0,
        yield_behind: float = 0.2,
        yield_ahead: float = 0.4,
        n_preview: int = RaceConfig.n_preview,
        keep_gap: bool | None = None,
        *,
        mu: float | None = None,
    ):
        from .envelope import grip_arg
        from .raceline import RacelineConfig

        grip = grip_arg(grip, mu, "RacelineFollower (agent spec raceline)", 1.0)
        self.raceline_config = RacelineConfig(objective=line)  # names line and choices if bad
        if not (0.0 < speed_scale <= 1.5):
            raise ValueError(f"speed_scale must be in (0, 1.5], got {speed_scale}")
        if not (0.0 <= line_fraction <= 1.0):
            raise ValueError(f"line_fraction must be in [0, 1], got {line_fraction}")
        if preview_min <= 0 or preview_time < 0 or speed_preview < 0 or k_speed <= 0:
            raise ValueError(
                "preview_min and k_speed must be positive, preview_time and "
                f"speed_preview non-negative; got {preview_min}, {k_speed}, "
                f"{preview_time}, {speed_preview}"
            )
        k = _size_ratios(vehicle) if vehicle is not None else {"length": 1.0, "width": 1.0}
        k_len, k_wid = k["length"], k["width"]
        for name, v, hi in (
            ("yield_gap", yield_gap, 0.3 * k_wid),
            ("yield_behind", yield_behind, 2.0 * k_len),
            ("yield_ahead", yield_ahead, 2.0 * k_len),
        ):
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0.0 <= v <= hi):
                raise ValueError(f"{name} must be a number in [0, {hi}] m, got {v!r}")
        if not (_is_int(n_preview) and n_preview >= 0):
            raise ValueError(f"n_preview must be a non-negative integer, got {n_preview!r}")
        self.yield_gap, self.yield_behind, self.yield_ahead = yield_gap, yield_behind, yield_ahead
        if keep_gap is not None and not isinstance(keep_gap, bool):
            raise ValueError(f"keep_gap must be True, False or None, got {keep_gap!r}")
        self.keep_gap = keep_gap
        self.n_preview = n_preview
        self.vehicle_given = vehicle
        self.vehicle: VehicleParams | FullSizeParams = vehicle or VehicleParams()
        self._lengths = {  # as given: the ones left at their defaults scale with the class
            "preview_min": preview_min,
            "yield_gap": yield_gap,
            "yield_behind": yield_behind,
            "yield_ahead": yield_ahead,
        }
        self.grip = grip
        self.speed_scale = speed_scale
        self.line_fraction = line_fraction
        self.preview_min = preview_min
        self.preview_time = preview_time
        self.speed_preview = speed_preview
        self.k_speed = k_speed
        #: the full-size class's ``(grip_use, steer)`` constants in :meth:`gains`; ``None``:
        #: :data:`FULLSIZE_GRIP_USE` and :data:`FULLSIZE_STEER` (the MPC's warm start sets
        #: its own, :func:`agents.mpc.prediction.make_follower`)
        self.fullsize_law: tuple[tuple[float, ...], tuple[float, ...]] | None = None
        self.k_us = understeer_gradient(self.vehicle)
        self.track: Track | None = None
        self.raceline: Raceline | None = None
        self.agent_id: str | None = None

    @property
    def mu(self) -> float:
        """Deprecated name of :attr:`grip` (``mu`` names the heading in the state)."""
        import warnings

        warnings.warn(
            "RacelineFollower.mu is deprecated, use .grip (the envelope scale)",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.grip

    @property
    def line(self) -> str:
        """The racing line followed (``RacelineConfig.objective``)."""
        return self.raceline_config.objective

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        from .raceline import get_raceline

        self.track = make_track(track)
        self._set_class(self.track)
        self.raceline = rl = get_raceline(
            self.track, self.vehicle, raceline_config_for(self.vehicle, self.line)
        )
        rl.speed_at(0.0, self.grip)  # fail now, with the library's message, if out of range
        f = self.line_fraction
        # reference tables on the track grid: offset, its slope (heading to the centre line), curvature
        t = self.track
        self._n_ref = f * rl.offset_at(t.s_grid)
        self._mu_ref = np.arctan(
            np.gradient(np.concatenate([self._n_ref[-1:], self._n_ref, self._n_ref[:1]]), t.ds)[
                1:-1
            ]
        )
        self._kappa_ref = (
            f * np.interp(t.s_grid, rl.s_track, rl.kappa, period=t.length) + (1 - f) * t.kappa
        )
        self._v_ref = self.speed_scale * rl.speed_at(t.s_grid, self.grip)
        self._gains = self.gains()
        self.agent_id = agent_id

    def _set_class(self, track: Track) -> None:
        """The track's vehicle class: its car (unless one was given), the understeer gradient
        and the lengths left at their defaults scaled to the car's size."""
        import inspect

        vehicle = vehicle_for_track(track, self.vehicle_given, "RacelineFollower (raceline)")
        if vehicle is self.vehicle and getattr(self, "_sized_for", None) is vehicle:
            return
        self.vehicle = vehicle
        self.k_us = understeer_gradient(vehicle)
        params = inspect.signature(RacelineFollower.__init__).parameters
        k = _size_ratios(vehicle)
        for name, given in self._lengths.items():
            default = params[name].default
            kind = _FOLLOWER_LENGTHS[name]
            setattr(self, name, default * k[kind] if given == default else given)
        self._sized_for = vehicle

    def gains(self) -> np.ndarray:
        """Packed controller constants for :func:`follower_action`: 13 for the ORCA car, and
        for the full-size class 38 more (from :data:`FULLSIZE_GAINS`: ``c_drag``, ``c_roll m
        g``, ``F_drive_max``, ``P_max``, ``v_low``, the two :data:`FULLSIZE_GRIP_USE`, the
        six :data:`FULLSIZE_STEER`, then :meth:`FullSizeParams.pack`); the ORCA entries
        C1..C4 are then 1, 0, 0, 0 (not read)."""
        v = self.vehicle
        if isinstance(v, FullSizeParams):
            grip_use, steer = self.fullsize_law or (FULLSIZE_GRIP_USE, FULLSIZE_STEER)
            motor = [1.0, 0.0, 0.0, 0.0]
            extra = [
                v.c_drag,
                v.c_roll * v.m * v.g,
                v.F_drive_max,
                v.P_max,
                v.v_low,
                *grip_use,
                *steer,
                *v.pack(),
            ]
        else:
            motor, extra = [v.C1, v.C2, v.C3, v.C4], []
        return np.array(
            [
                self.preview_min,
                self.preview_time,
                self.speed_preview,
                self.k_speed,
                v.lf + v.lr,
                self.k_us,
                *motor,
                v.d_min,
                v.d_max,
                v.delta_max,
                *extra,
            ]
        )

    def tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(n_ref, mu_ref, kappa_ref, v_ref) on the track grid, the follower's references."""
        return self._n_ref, self._mu_ref, self._kappa_ref, self._v_ref

    def act(self, observation: np.ndarray) -> np.ndarray:
        """Normalised ``[throttle, steering]`` (float32, in [-1, 1]) from an env observation."""
        if self.track is None:
            raise RuntimeError("RacelineFollower.act() before reset(track, ...)")
        n_ref = self._n_ref
        if self.yield_gap > 0.0:
            shift = self.yield_shift(observation)
            if shift != 0.0:  # the table, not the looked-up value: the measured races are so
                n_ref = n_ref + shift
        keep = self.keep_gap
        if keep is None:
            keep = isinstance(self.vehicle, FullSizeParams)
        a = follower_action(
            np.asarray(observation[:6], dtype=np.float64),
            n_ref,
            self._mu_ref,
            self._kappa_ref,
            self._v_ref,
            self.track.ds,
            self.track.length,
            self._gains,
            self.gap_speed(observation) if keep else NO_SPEED_CAP,
        )
        return np.array(a, dtype=np.float32)

    def gap_speed(self, observation: np.ndarray) -> float:
        """The highest speed [m/s] from which the follower still brakes, at
        :data:`KEEP_DECEL`, to the speed of a car ahead before it is :data:`KEEP_GAP` car
        lengths behind it (progress difference, centre to centre): the least over the cars
        0 to 30 lengths ahead and under 1.2 widths to the side; a car already closer caps it
        at that car's speed less 1 m/s per metre too close. :data:`NO_SPEED_CAP` when none."""
        ego, others, gaps = self._others(observation)
        length, width = self.vehicle.length, self.vehicle.width
        cap = NO_SPEED_CAP
        for gap, row in zip(gaps, others):
            if 0.0 < gap < 30.0 * length and abs(row[1] - ego[1]) < 1.2 * width:
                room = gap - KEEP_GAP * length
                v_j = max(float(row[3]), 0.0)
                v = math.sqrt(v_j * v_j + 2.0 * KEEP_DECEL * room) if room > 0 else v_j + room
                cap = min(cap, max(v, 0.0))
        return cap

    def _others(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(ego (6,), others (M, 6), gaps (M,))`` of an observation: ``gaps`` the other cars'
        relative progress as observed, not rebuilt from absolute s (at a window's edge the
        rebuilt ``s_j - s`` can differ from it in the last bit)."""
        ego, others = split_observation(observation, self.n_preview)
        gaps = np.asarray(observation, dtype=float)[6 : 6 * (len(others) + 1) : 6]
        return ego, others, gaps

    def yield_shift(self, observation: np.ndarray) -> float:
        """The lateral shift [m] of the follower's target that leaves ``yield_gap`` to every car
        in its yield window (0 when none is there or the line already keeps clear)."""
        t = self.track
        if t is None:
            raise RuntimeError("RacelineFollower.yield_shift() before reset(track, ...)")
        ego, others, gaps = self._others(observation)
        s, n = ego[0], ego[1]
        line = _lookup(self._n_ref, s, t.ds, t.length)
        target = line
        for gap, n_j in zip(gaps, others[:, 1]):
            if -self.yield_behind <= gap <= self.yield_ahead:
                side = 1.0 if n_j <= n else -1.0  # its side of the other car; a tie goes left
                keep = n_j + side * self.yield_gap
                if side * (target - keep) < 0.0:
                    target = keep
        if target != line:  # never past the track's edges (its body inside them)
            w_left, w_right = t.widths(s)
            half = 0.5 * self.vehicle.width
            target = min(max(target, -float(w_right) + half), float(w_left) - half)
        return target - line


@njit(cache=True)
def _fullsize_axle_peaks(vx, p):
    """Peak force [N] of the full-size car's (front, rear) axle at speed ``vx`` in clean air
    (``p`` :meth:`FullSizeParams.pack`; the force law's ``D_a``)."""
    w = p[P_M_FS] * p[P_G] / (p[P_LF_FS] + p[P_LR_FS])
    q = vx * vx
    tf = 0.5 * (w * p[P_LR_FS] + p[P_CLF] * q)
    tr = 0.5 * (w * p[P_LF_FS] + p[P_CLR] * q)
    d_f = 2.0 * p[P_MU] * tf * (1.0 + p[P_EPSF] * (tf - p[P_FZSHIFT]) / p[P_FZ0])
    d_r = 2.0 * p[P_MU] * tr * (1.0 + p[P_EPSR] * (tr - p[P_FZSHIFT]) / p[P_FZ0])
    return d_f, d_r


@njit(cache=True)
def _fullsize_long_room(a_y, d_front, d_rear, p):
    """Fractions ``(r_front, r_rear)`` of the full-size car's axle peaks ``d_front, d_rear``
    [N] left along the car at lateral acceleration ``a_y`` [m/s^2] (steady cornering: the
    front axle carries ``l_r / L`` of ``m a_y``, the rear ``l_f / L``): ``sqrt(1 - (F_y /
    D)^2)``, at least :data:`FULLSIZE_LONG_FLOOR` (a car too fast for its corner may still
    brake)."""
    lf, lr = p[P_LF_FS], p[P_LR_FS]
    f_y = p[P_M_FS] * abs(a_y) / (lf + lr)
    u_f = min(f_y * lr / d_front, 1.0)
    u_r = min(f_y * lf / d_rear, 1.0)
    floor = FULLSIZE_LONG_FLOOR
    return max(math.sqrt(1.0 - u_f * u_f), floor), max(math.sqrt(1.0 - u_r * u_r), floor)


#: :meth:`RacelineFollower.gap_speed` (``keep_gap``): the gap [car lengths] the follower keeps
#: to a car ahead on its line, and the deceleration [m/s^2] it plans to brake at for it (0.7 g,
#: under the full-size car's brake limit of 0.73-1.22 g)
KEEP_GAP = 1.5
KEEP_DECEL = 7.0
#: no speed cap for :func:`follower_action` (no car to keep a gap to)
NO_SPEED_CAP = 1e30


@njit(cache=True)
def follower_action(x, n_ref, mu_ref, kappa_ref, v_ref, ds, length, g, v_cap=NO_SPEED_CAP):
    """The follower's control law (see :class:`RacelineFollower`) for state ``x`` (6,):
    normalised ``(throttle, steering)``. ``g`` from :meth:`RacelineFollower.gains`;
    ``v_cap`` [m/s] caps the speed target (:meth:`RacelineFollower.gap_speed`)."""
    s, n, mu, vx, vy = x[0], x[1], x[2], x[3], x[4]
    fullsize = g.shape[0] > FULLSIZE_GAINS
    f = FULLSIZE_GAINS
    if fullsize:  # full-size class: a time-based preview with a small floor, its heading gain
        preview, k_mu = max(g[f + 7], g[f + 8] * vx), g[f + 12]
    else:
        preview, k_mu = max(g[0], g[1] * vx), 2.0
    beta = math.atan2(vy, max(vx, 0.1))
    kappa_cmd = (
        _lookup(kappa_ref, s + 0.5 * preview, ds, length)
        + k_mu / preview * (_lookup(mu_ref, s, ds, length) - (mu + beta))
        + 1.0 / preview**2 * (_lookup(n_ref, s, ds, length) - n)
    )
    delta = math.atan(g[4] * kappa_cmd) + g[5] * vx * vx * kappa_cmd
    v_target = min(_lookup(v_ref, s + g[2] * vx, ds, length), v_cap)
    if fullsize:  # full-size class: resistance over the power-limited drive
        p = g[f + 13 :]
        v_target = min(_lookup(v_ref, s + g[f + 11] * vx, ds, length), v_cap)
        omega = x[5]
        vx_eff = max(vx, 1.0)
        # yaw-rate damping: the yaw rate the commanded path asks less the car's
        delta += g[f + 9] * g[4] * (vx * kappa_cmd - omega) / vx_eff
        drive = min(g[f + 2], g[f + 3] / math.sqrt(vx * vx + g[f + 4] * g[f + 4]))
        d = (g[f] * vx * vx + g[f + 1]) / drive + g[3] * (v_target - vx)
        # traction and brake limits: each axle asked for at most grip_use of its peak
        d_front, d_rear = _fullsize_axle_peaks(vx, p)
        # friction ellipse: the share of each axle's peak left along the car by the lateral
        # force the line's curvature here asks of it (front l_r / L, rear l_f / L of m a_y):
        # a traction and brake control on the ellipse
        a_y = vx * vx * _lookup(kappa_ref, s, ds, length)
        r_front, r_rear = _fullsize_long_room(a_y, d_front, d_rear, p)
        # traction rule: the drive fades out as the rear tyre's slip angle nears its peak
        alpha_peak = math.tan(0.5 * math.pi / p[P_CR]) / p[P_BR]
        alpha_r = abs(math.atan((omega * p[P_LR_FS] - vy) / vx_eff))
        onset = g[f + 10]
        fade = 1.0  # slip_onset >= 1: no traction rule
        if onset < 1.0:
            fade = min(max((1.0 - alpha_r / alpha_peak) / (1.0 - onset), 0.0), 1.0)
        d_hi = g[f + 5] * r_rear * d_rear * fade / drive
        brake = p[P_FBRAKE] * math.tanh(max(vx, 0.0) / p[P_VLOW_FS])
        d_lo = (
            -g[f + 6]
            * min(r_front * d_front / p[P_KBF], r_rear * d_rear / (1.0 - p[P_KBF]))
            / max(brake, 1e-9)
        )
        d = min(max(d, max(g[10], d_lo)), min(g[11], d_hi))
    else:
        d = (g[8] + g[9] * vx * vx) / max(g[6] - g[7] * vx, 1e-6) + g[3] * (v_target - vx)
    d = min(max(d, g[10]), g[11])
    d_norm = (2.0 * d - (g[11] + g[10])) / (g[11] - g[10])
    return d_norm, min(max(delta / g[12], -1.0), 1.0)
