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
from numba import njit

from racing_env.interp import periodic_lookup as _lookup

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
        self._decays: dict = {}

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
        s, n, s_dot = (np.asarray(a, dtype=float).reshape(-1) for a in (s, n, s_dot))
        if not s.size == n.size == s_dot.size:
            raise ValueError(
                f"s, n and s_dot must hold one value per car, got sizes {s.size}, {n.size} "
                f"and {s_dot.size}"
            )
        rate0 = self._at(self.rate, s)
        c = np.clip(s_dot / rate0, *RATE_SCALE)
        off = n - self._at(self.n, s)
        t = self.track
        return _line_paths(self.rate, self.n, s, off, c, self._decay(K, dt), dt, t.ds, t.length)

    def _decay(self, K: int, dt: float) -> np.ndarray:
        """``exp(-t_k / SETTLE_TIME)`` at the stages ``t_k = k dt``, k = 1..K (cached)."""
        key = (K, dt)
        if key not in self._decays:
            self._decays[key] = np.array([np.exp(-(k + 1) * dt / SETTLE_TIME) for k in range(K)])
        return self._decays[key]


@njit(cache=True)
def _line_paths(rate, n_line, s, off, c, decay, dt, ds, length):
    """:meth:`LinePrediction.paths`' stages, compiled: ``(M, K, 2)`` from the line's progress
    rate and offset tables, the cars' progress ``s``, offsets from the line ``off`` and rate
    factors ``c`` (M,), the offsets' decay (K,)."""
    M, K = s.shape[0], decay.shape[0]
    out = np.empty((M, K, 2))
    for m in range(M):
        sk = s[m]
        for k in range(K):
            mid = sk + 0.5 * dt * c[m] * _lookup(rate, sk, ds, length)
            sk = sk + dt * c[m] * _lookup(rate, mid, ds, length)
            out[m, k, 0] = sk
            out[m, k, 1] = _lookup(n_line, sk, ds, length) + off[m] * decay[k]
    return out
