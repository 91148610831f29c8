"""The built-in raceline-following controller.

It follows the agent protocol of :mod:`agents` (``reset(track, agent_id, seed)``,
``act(observation) -> action``) so it can drive opponents inside the Gymnasium env without
``racing_env`` importing ``agents``.
"""
from __future__ import annotations

import math

import numpy as np

from .track import Track
from .tracks import make_track
from .vehicle import VehicleParams


def understeer_gradient(v: VehicleParams) -> float:
    """Linear-range understeer gradient K_us [rad s^2/m] of the bicycle model:
    ``delta = L kappa + K_us v^2 kappa`` in steady cornering (cornering stiffness = B C D)."""
    ca_f, ca_r = v.Bf * v.Cf * v.Df, v.Br * v.Cr * v.Dr
    return v.m / (v.lf + v.lr) * (v.lr / ca_f - v.lf / ca_r)


class RacelineFollower:
    """Follows the minimum-curvature racing line at the speed profile of friction ``mu``.

    A path follower in the Frenet frame: the commanded path curvature is the racing line's
    curvature ahead plus feedback on the heading and lateral errors to the line, with a
    preview distance ``D = max(preview_min, preview_time * vx)``::

        kappa_cmd = kappa_ref + 2 / D * (mu_ref - (mu + beta)) + 1 / D^2 * (n_ref - n)
        delta     = atan(L kappa_cmd) + K_us vx^2 kappa_cmd

    (``beta`` the body slip angle, ``K_us`` the car's understeer gradient, so the steering
    is right at the grip the speed profile uses). ``line_fraction`` scales the racing line's
    offsets towards the centre line to keep a margin from the edges. Throttle is a
    feed-forward of rolling resistance and drag plus ``k_speed`` times the error to the
    profile speed ``speed_preview`` s ahead (so it brakes before corners). Ignores other cars.
    """

    def __init__(self, vehicle: VehicleParams | None = None, mu: float = 0.85,
                 speed_scale: float = 1.0, line_fraction: float = 0.9, preview_min: float = 0.5,
                 preview_time: float = 0.2, speed_preview: float = 0.3, k_speed: float = 2.0):
        if not (0.0 < speed_scale <= 1.5):
            raise ValueError(f"speed_scale must be in (0, 1.5], got {speed_scale}")
        if not (0.0 <= line_fraction <= 1.0):
            raise ValueError(f"line_fraction must be in [0, 1], got {line_fraction}")
        if preview_min <= 0 or preview_time < 0 or speed_preview < 0 or k_speed <= 0:
            raise ValueError("preview_min and k_speed must be positive, preview_time and "
                             f"speed_preview non-negative; got {preview_min}, {k_speed}, "
                             f"{preview_time}, {speed_preview}")
        self.vehicle = vehicle or VehicleParams()
        self.mu = mu
        self.speed_scale = speed_scale
        self.line_fraction = line_fraction
        self.preview_min = preview_min
        self.preview_time = preview_time
        self.speed_preview = speed_preview
        self.k_speed = k_speed
        self.k_us = understeer_gradient(self.vehicle)
        self.track: Track | None = None
        self.raceline = None
        self.agent_id = None

    def reset(self, track: "Track | str", agent_id: str = "car_0", seed: int | None = None) -> None:
        from .raceline import get_raceline
        self.track = make_track(track)
        self.raceline = rl = get_raceline(self.track, self.vehicle)
        rl.speed_at(0.0, mu=self.mu)            # fail now, with the library's message, if mu is out of range
        f = self.line_fraction
        # reference tables on the track grid: offset, its slope (heading to the centre line), curvature
        t = self.track
        self._n_ref = f * rl.offset_at(t.s_grid)
        self._mu_ref = np.arctan(np.gradient(np.concatenate([self._n_ref[-1:], self._n_ref, self._n_ref[:1]]),
                                             t.ds)[1:-1])
        self._kappa_ref = f * np.interp(t.s_grid, rl.s_track, rl.kappa, period=t.length) + (1 - f) * t.kappa
        self._v_ref = self.speed_scale * rl.speed_at(t.s_grid, mu=self.mu)
        self.agent_id = agent_id

    def _at(self, table: np.ndarray, s: float) -> float:
        t = self.track
        f = (s % t.length) / t.ds
        i = int(f)
        w = f - i
        return float(table[i % len(table)] * (1 - w) + table[(i + 1) % len(table)] * w)

    def act(self, observation) -> np.ndarray:
        """Normalised ``[throttle, steering]`` (float32, in [-1, 1]) from an env observation."""
        if self.track is None:
            raise RuntimeError("RacelineFollower.act() before reset(track, ...)")
        s, n, mu, vx, vy = (float(v) for v in observation[:5])
        v = self.vehicle
        preview = max(self.preview_min, self.preview_time * vx)
        beta = math.atan2(vy, max(vx, 0.1))
        kappa_cmd = (self._at(self._kappa_ref, s + 0.5 * preview)
                     + 2.0 / preview * (self._at(self._mu_ref, s) - (mu + beta))
                     + 1.0 / preview ** 2 * (self._at(self._n_ref, s) - n))
        delta = math.atan((v.lf + v.lr) * kappa_cmd) + self.k_us * vx * vx * kappa_cmd
        v_ref = self._at(self._v_ref, s + self.speed_preview * vx)
        d = (v.C3 + v.C4 * vx * vx) / max(v.C1 - v.C2 * vx, 1e-6) + self.k_speed * (v_ref - vx)
        d = min(max(d, v.d_min), v.d_max)
        d_norm = (2.0 * d - (v.d_max + v.d_min)) / (v.d_max - v.d_min)
        return np.array([d_norm, min(max(delta / v.delta_max, -1.0), 1.0)], dtype=np.float32)
