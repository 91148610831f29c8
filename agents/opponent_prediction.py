"""Where the nearby cars will be over the MPC's horizon: the predicted paths ``(M, K, 2)`` of
``(s, n)`` that the MPC's separation rows keep clear of (:func:`agents.mpc.opponent_paths`).

The paper predicts every car at constant progress rate and lateral offset (``predict=
"constant"``, the default). :class:`LinePrediction` (``predict="line"``) predicts it along the
track's racing line instead: at the line's speed profile, scaled by how fast the car goes now
against the line at its position, and settling onto the line's lateral offset from its own
over :data:`SETTLE_TIME`. A car that follows the racing line (the ``raceline`` agent) crosses
the track from edge to edge between corners; held at constant offset, it is predicted to stay
where it is, and a car behind it plans a pass into the space it is about to take.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .mpc import _grid_interp

if TYPE_CHECKING:
    from racing_env.raceline import Raceline
    from racing_env.track import Track

__all__ = ["PREDICTIONS", "SETTLE_TIME", "RATE_SCALE", "LinePrediction"]

PREDICTIONS = ("constant", "line")
"""The MPC agent's ``predict`` choices: the paper's constant velocity, or along the racing line."""
SETTLE_TIME = 0.5
"""[s] time constant with which a predicted car's offset from the racing line decays."""
RATE_SCALE = (0.5, 1.5)
"""Bounds of the factor between a car's progress rate now and the line's at its position."""


class LinePrediction:
    """Predicts cars along ``raceline`` on ``track``: :meth:`paths`.

    The line's progress rate ``ds/dt`` [m/s] along the centre line at every grid station is its
    speed ``vx`` divided by ``d s_line / d s_track`` (the line is longer where it swings wide);
    both it and the line's offset ``n`` are interpolated periodically on the track's grid.
    """

    def __init__(self, track: Track, raceline: Raceline):
        self.track = track
        ds_line = np.diff(np.append(raceline.s, raceline.length))
        ds_track = np.diff(np.append(raceline.s_track, track.length))
        self.rate = np.ascontiguousarray(raceline.vx * ds_track / ds_line)
        self.n = np.ascontiguousarray(raceline.n, dtype=float)

    def _at(self, table: np.ndarray, s: np.ndarray) -> np.ndarray:
        t = self.track
        return _grid_interp(table, np.ascontiguousarray(s, dtype=float), t.ds, t.length)

    def paths(
        self, s: np.ndarray, n: np.ndarray, s_dot: np.ndarray, K: int, dt: float
    ) -> np.ndarray:
        """``(M, K, 2)`` predicted ``(s, n)`` [m] at stages 1..K (``dt`` [s] apart) of cars at
        unwrapped progress ``s``, offset ``n`` and progress rate ``s_dot`` [m/s] (each (M,)).

        Progress: ``s_{k+1} = s_k + c * rate(s_k) * dt`` (the line's rate, midpoint rule) with
        ``c = s_dot / rate(s)`` now, clipped to :data:`RATE_SCALE`. Offset: the line's at
        ``s_k`` plus the car's offset from the line now, decayed by
        ``exp(-t_k / SETTLE_TIME)``."""
        s = np.asarray(s, dtype=float)
        n = np.asarray(n, dtype=float)
        rate0 = self._at(self.rate, s)
        c = np.clip(np.asarray(s_dot, dtype=float) / rate0, *RATE_SCALE)
        off = n - self._at(self.n, s)
        out = np.empty((s.size, K, 2))
        sk = s.copy()
        for k in range(K):
            mid = sk + 0.5 * dt * c * self._at(self.rate, sk)
            sk = sk + dt * c * self._at(self.rate, mid)
            out[:, k, 0] = sk
            out[:, k, 1] = self._at(self.n, sk) + off * np.exp(-(k + 1) * dt / SETTLE_TIME)
        return out
