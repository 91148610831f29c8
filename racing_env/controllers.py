"""The built-in raceline-following controller (pure pursuit on the racing line, PI-free speed
tracking). It follows the agent protocol of :mod:`agents` (``reset(track, agent_id, seed)``,
``act(observation) -> action``) so it can drive opponents inside the Gymnasium env without
``racing_env`` importing ``agents``.
"""
from __future__ import annotations

import math

import numpy as np

from .track import Track
from .tracks import make_track
from .vehicle import VehicleParams


class RacelineFollower:
    """Pure pursuit of the minimum-curvature racing line at ``speed_scale`` times its speed.

    ``lookahead = max(lookahead_min, lookahead_time * vx)`` [m] ahead along the track; the
    steering angle is the pure-pursuit arc to the racing-line point there. Throttle is a
    feed-forward of rolling resistance and drag plus ``k_speed`` times the speed error to the
    racing-line speed ``preview_time`` s ahead (so it brakes before corners). It ignores other
    cars. Works with any number of cars: it reads only its own state from the observation.
    """

    def __init__(self, vehicle: VehicleParams | None = None, speed_scale: float = 0.9,
                 lookahead_min: float = 0.35, lookahead_time: float = 0.25,
                 preview_time: float = 0.35, k_speed: float = 2.0):
        if not (0.0 < speed_scale <= 1.5):
            raise ValueError(f"speed_scale must be in (0, 1.5], got {speed_scale}")
        if lookahead_min <= 0 or lookahead_time < 0 or preview_time < 0 or k_speed <= 0:
            raise ValueError("lookahead_min and k_speed must be positive, lookahead_time and "
                             f"preview_time non-negative; got {lookahead_min}, {k_speed}, "
                             f"{lookahead_time}, {preview_time}")
        self.vehicle = vehicle or VehicleParams()
        self.speed_scale = speed_scale
        self.lookahead_min = lookahead_min
        self.lookahead_time = lookahead_time
        self.preview_time = preview_time
        self.k_speed = k_speed
        self.track: Track | None = None
        self.raceline = None
        self.agent_id = None

    def reset(self, track: "Track | str", agent_id: str = "car_0", seed: int | None = None) -> None:
        from .raceline import get_raceline
        self.track = make_track(track)
        self.raceline = get_raceline(self.track, self.vehicle)
        self.agent_id = agent_id

    def act(self, observation) -> np.ndarray:
        """Normalised ``[throttle, steering]`` (float32, in [-1, 1]) from an env observation."""
        if self.track is None:
            raise RuntimeError("RacelineFollower.act() before reset(track, ...)")
        s, n, mu, vx = (float(v) for v in observation[:4])
        v = self.vehicle
        ahead = max(self.lookahead_min, self.lookahead_time * vx)
        s_t = s + ahead
        n_t = float(self.raceline.offset_at(s_t))
        x, y, phi = self.track.to_cartesian(s, n, mu)
        xt, yt = self.track.to_cartesian(s_t, n_t)
        dx, dy = float(xt - x), float(yt - y)
        alpha = math.atan2(dy, dx) - float(phi)
        dist = max(math.hypot(dx, dy), 1e-6)
        delta = math.atan(2.0 * (v.lf + v.lr) * math.sin(alpha) / dist)
        v_ref = self.speed_scale * float(self.raceline.speed_at(s + self.preview_time * vx))
        resist = v.C3 + v.C4 * vx * vx
        d = resist / max(v.C1 - v.C2 * vx, 1e-6) + self.k_speed * (v_ref - vx)
        d = min(max(d, v.d_min), v.d_max)
        d_norm = (2.0 * d - (v.d_max + v.d_min)) / (v.d_max - v.d_min)
        return np.array([d_norm, np.clip(delta / v.delta_max, -1.0, 1.0)], dtype=np.float32)
