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

if TYPE_CHECKING:
    from .raceline import Raceline


def understeer_gradient(v: VehicleParams) -> float:
    """Linear-range understeer gradient K_us [rad s^2/m] of the bicycle model:
    ``delta = L kappa + K_us v^2 kappa`` in steady cornering (cornering stiffness = B C D)."""
    ca_f, ca_r = v.Bf * v.Cf * v.Df, v.Br * v.Cr * v.Dr
    return v.m / (v.lf + v.lr) * (v.lr / ca_f - v.lf / ca_r)


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
    profile speed ``speed_preview`` s ahead (so it brakes before corners).

    By default it ignores other cars (it never yields). ``yield_gap`` [m] > 0 makes it leave
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
        vehicle: VehicleParams | None = None,
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
        for name, v, hi in (
            ("yield_gap", yield_gap, 0.3),
            ("yield_behind", yield_behind, 2.0),
            ("yield_ahead", yield_ahead, 2.0),
        ):
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and 0.0 <= v <= hi):
                raise ValueError(f"{name} must be a number in [0, {hi}] m, got {v!r}")
        if not (_is_int(n_preview) and n_preview >= 0):
            raise ValueError(f"n_preview must be a non-negative integer, got {n_preview!r}")
        self.yield_gap, self.yield_behind, self.yield_ahead = yield_gap, yield_behind, yield_ahead
        self.n_preview = n_preview
        self.vehicle = vehicle or VehicleParams()
        self.grip = grip
        self.speed_scale = speed_scale
        self.line_fraction = line_fraction
        self.preview_min = preview_min
        self.preview_time = preview_time
        self.speed_preview = speed_preview
        self.k_speed = k_speed
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
        self.raceline = rl = get_raceline(self.track, self.vehicle, self.raceline_config)
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

    def gains(self) -> np.ndarray:
        """Packed controller constants for :func:`follower_action`."""
        v = self.vehicle
        return np.array(
            [
                self.preview_min,
                self.preview_time,
                self.speed_preview,
                self.k_speed,
                v.lf + v.lr,
                self.k_us,
                v.C1,
                v.C2,
                v.C3,
                v.C4,
                v.d_min,
                v.d_max,
                v.delta_max,
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
        a = follower_action(
            np.asarray(observation[:6], dtype=np.float64),
            n_ref,
            self._mu_ref,
            self._kappa_ref,
            self._v_ref,
            self.track.ds,
            self.track.length,
            self._gains,
        )
        return np.array(a, dtype=np.float32)

    def yield_shift(self, observation: np.ndarray) -> float:
        """The lateral shift [m] of the follower's target that leaves ``yield_gap`` to every car
        in its yield window (0 when none is there or the line already keeps clear)."""
        t = self.track
        if t is None:
            raise RuntimeError("RacelineFollower.yield_shift() before reset(track, ...)")
        ego, others = split_observation(observation, self.n_preview)
        s, n = ego[0], ego[1]
        line = _lookup(self._n_ref, s, t.ds, t.length)
        target = line
        # the gap as observed (relative progress), not rebuilt from absolute s: at the window's
        # edge the rebuilt s_j - s can differ from it in the last bit
        gaps = np.asarray(observation, dtype=float)[6 : 6 * (len(others) + 1) : 6]
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
def follower_action(x, n_ref, mu_ref, kappa_ref, v_ref, ds, length, g):
    """The follower's control law (see :class:`RacelineFollower`) for state ``x`` (6,):
    normalised ``(throttle, steering)``. ``g`` from :meth:`RacelineFollower.gains`."""
    s, n, mu, vx, vy = x[0], x[1], x[2], x[3], x[4]
    preview = max(g[0], g[1] * vx)
    beta = math.atan2(vy, max(vx, 0.1))
    kappa_cmd = (
        _lookup(kappa_ref, s + 0.5 * preview, ds, length)
        + 2.0 / preview * (_lookup(mu_ref, s, ds, length) - (mu + beta))
        + 1.0 / preview**2 * (_lookup(n_ref, s, ds, length) - n)
    )
    delta = math.atan(g[4] * kappa_cmd) + g[5] * vx * vx * kappa_cmd
    v_target = _lookup(v_ref, s + g[2] * vx, ds, length)
    d = (g[8] + g[9] * vx * vx) / max(g[6] - g[7] * vx, 1e-6) + g[3] * (v_target - vx)
    d = min(max(d, g[10]), g[11])
    d_norm = (2.0 * d - (g[11] + g[10])) / (g[11] - g[10])
    return d_norm, min(max(delta / g[12], -1.0), 1.0)
