"""Per-(race line, track, friction) lookup tables of the MPC reference, and the horizon's time
steps: :func:`agents.reference.reference_trajectory` reads everything it needs about a race line
from a :class:`_Tables` (the race line's time, Frenet velocities and lateral offset, the track's
curvature and edges on the track grid, repeated over two laps, and the car's full-throttle run
from rest, :func:`_run_up`), computed once per race line and kept in a small cache
(:func:`clear_cache` forgets it). :func:`_interp1` is the scalar look-up in those tables,
:func:`_steps` the cached step times ``dt * (0..K)`` of a horizon checked by
:func:`_check_horizon`. :mod:`agents.reference` re-exports these names.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["clear_cache"]

#: The braking limit's cap on straights (:meth:`_Tables.braking_sdot2`), a multiple of the
#: car's top speed: above the tow's +15% at one car length (docs/fullsize.md, the wake).
TOW_SPEED_CAP = 1.2


class _Tables:
    """Per-(race line, track, friction) lookup tables on the track grid, repeated over two laps
    plus one point (index 2M = index 0 two laps on) so that a horizon starting anywhere on a lap
    interpolates without wrapping (``st2``, ``tt2``, ``sdot2``, ``ndot2``, ``wl2``, ``wr2``); single-lap
    tables plus one point (``nrl``, ``kap``, ``wl``, ``wr``) for scalar look-ups."""

    __slots__ = (
        "L",
        "T",
        "M",
        "inv_ds",
        "st",
        "tt",
        "st2",
        "tt2",
        "sdot2",
        "ndot2",
        "wl2",
        "wr2",
        "nrl",
        "nrl2",
        "kap",
        "wl",
        "wr",
        "w_const",
        "refs",
        "run_t",
        "run_v",
        "run_x",
        "sfac2",
        "friction",
        "_sbrk2",
        "_vx",
        "_brake_points",
    )

    def __init__(self, raceline, track, friction):
        L = float(track.length)
        if abs(float(raceline.track_length) - L) > 1e-6 * max(L, 1.0):
            raise ValueError(
                f"raceline is for a track of length {raceline.track_length} m, "
                f"but the track is {L} m long"
            )
        st = np.asarray(raceline.s_track, dtype=float)
        M = len(st)
        if M < 2 or np.max(np.abs(st - np.arange(M) * (L / M))) > 1e-6 * L:
            raise ValueError("raceline.s_track must be the track's uniform grid i * L / M")
        vx = np.asarray(raceline.profile(friction)[0], dtype=float)
        n = np.asarray(raceline.n, dtype=float)
        kap_c = np.asarray(track.kappa, dtype=float)
        psi_c = np.asarray(track.psi, dtype=float)
        if not (len(kap_c) == len(psi_c) == M == len(vx) == len(n)):
            raise ValueError("raceline and track grids differ in size")
        # race-line heading relative to the centre line, and its Frenet velocities
        mu_rl = np.angle(np.exp(1j * (np.asarray(raceline.psi, dtype=float) - psi_c)))
        den = 1.0 - n * kap_c
        if np.any(den <= 0):
            raise ValueError("race line lies beyond the centre line's radius of curvature")
        sdot = vx * np.cos(mu_rl) / den
        ndot = vx * np.sin(mu_rl)
        # time along the race line (constant acceleration between grid points, as lap_time_of)
        seg = np.diff(np.append(np.asarray(raceline.s, dtype=float), raceline.length))
        dt_seg = 2.0 * seg / np.maximum(vx + np.roll(vx, -1), 1e-12)
        ext = lambda a: np.append(a, a[0])
        ext2 = lambda a: np.concatenate([a, a, a[:1]])
        wl = np.asarray(track.w_left, dtype=float)
        wr = np.asarray(track.w_right, dtype=float)
        self.L, self.M = L, M
        self.inv_ds = M / L
        grid = np.arange(2 * M + 1) * (L / M)
        self.st = grid[: M + 1]
        self.st2 = grid
        tt = np.concatenate([[0.0], np.cumsum(dt_seg)])
        self.tt = tt
        self.T = float(tt[-1])
        self.tt2 = np.concatenate([tt[:-1], tt + self.T])
        self.sdot2, self.ndot2, self.nrl2 = ext2(sdot), ext2(ndot), ext2(n)
        self.sfac2 = ext2(np.cos(mu_rl) / den)  # centre-line progress rate per path speed
        self.wl2, self.wr2 = ext2(wl), ext2(wr)
        self.nrl, self.kap, self.wl, self.wr = ext(n), ext(kap_c), ext(wl), ext(wr)
        const = np.ptp(wl) == 0 and np.ptp(wr) == 0
        self.w_const = (float(wl[0]), float(wr[0])) if const else None
        self.run_t, self.run_v, self.run_x = _run_up(
            friction if friction is not None else float(raceline.mu_nominal),
            vehicle_class=str(getattr(track, "vehicle_class", "orca")),
        )
        self.friction = friction if friction is not None else float(raceline.mu_nominal)
        self._sbrk2 = None  # the braking limit, at the first braking_sdot2()
        self._vx = vx
        self._brake_points = None  # at the first brake_points()
        # (not set read-only: np.interp copies read-only tables on every call)
        self.refs = (raceline, track)  # keep them alive so their ids stay unique

    def braking_sdot2(self) -> np.ndarray:
        """The race line's braking limit (:func:`racing_env.raceline.speed.braking_limit`,
        straights capped at :data:`TOW_SPEED_CAP` times the top speed) as centre-line progress
        rate [m/s] on the two-lap grid (like ``sdot2``); computed at the first call."""
        if self._sbrk2 is None:
            from racing_env.envelope import ggv
            from racing_env.raceline.speed import braking_limit
            from racing_env.vehicles import vehicle_class as _class

            raceline, track = self.refs
            vehicle = _class(str(getattr(track, "vehicle_class", "orca")))()
            s = np.asarray(raceline.s, dtype=float)
            ds = np.diff(np.append(s, raceline.length))
            cap = TOW_SPEED_CAP * ggv(vehicle).top_speed
            vb = braking_limit(np.asarray(raceline.kappa), ds, self.friction, vehicle, cap)
            self._sbrk2 = np.concatenate([vb, vb, vb[:1]]) * self.sfac2
        return self._sbrk2

    def brake_points(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The race line's braking points: ``(s, s_apex, side)``, each (P,), sorted by ``s``
        in [0, L): where the speed profile starts to fall (a local maximum) and falls by at
        least :data:`BRAKE_DROP` of its speed before it rises again, the centre-line ``s`` of
        the lowest speed after it (the apex) and the side of the corner there (+1 left, -1
        right: the sign of the centre line's curvature at the apex). Computed at the first
        call."""
        if self._brake_points is None:
            v = np.asarray(self._vx, dtype=float)
            M = len(v)
            falls = np.roll(v, -1) < v  # v[i + 1] < v[i]
            starts = np.flatnonzero(falls & ~np.roll(falls, 1))
            s_b, s_a, side = [], [], []
            ds = self.L / M
            kap = self.kap[:M]
            for i in starts:
                j = i
                while falls[j % M] and j < i + M:
                    j += 1
                if v[i] - v[j % M] >= BRAKE_DROP * v[i]:
                    s_b.append(i * ds)
                    s_a.append((j % M) * ds)
                    side.append(1.0 if kap[j % M] >= 0 else -1.0)
            order = np.argsort(s_b)
            self._brake_points = (
                np.asarray(s_b)[order],
                np.asarray(s_a)[order],
                np.asarray(side)[order],
            )
        return self._brake_points

    def next_brake(self, s_w: float) -> tuple[float, float, float]:
        """``(distance [m], apex distance [m], side)`` from ``s_w`` in [0, L) to the next
        braking point of :meth:`brake_points` (wrapping over the lap; ``(inf, inf, 0)`` on a
        line with none)."""
        s_b, s_a, side = self.brake_points()
        if not len(s_b):
            return math.inf, math.inf, 0.0
        k = int(np.searchsorted(s_b, s_w))
        wrap = k == len(s_b)
        k = 0 if wrap else k
        d = float(s_b[k]) + (self.L if wrap else 0.0) - s_w
        d_apex = (float(s_a[k]) - float(s_b[k])) % self.L + d
        return d, d_apex, float(side[k])


#: A braking point of :meth:`_Tables.brake_points` takes at least this share off the speed
#: profile before the next rise (a lift of a few percent in a fast kink is no braking zone).
BRAKE_DROP = 0.05


def _run_up(mu: float, dt: float = 0.005, t_max: float = 60.0, vehicle_class: str = "orca"):
    """The car's full-throttle run from rest on a straight under the g-g-v envelope scaled by
    ``mu``: times ``t`` [s], speeds ``v`` [m/s] (strictly increasing) and distances ``x`` [m],
    each shape (P,). The drive limit depends on speed only, so the run from any speed ``v0``
    is this one's tail from the time it passes ``v0``. The envelope is the default car's of
    ``vehicle_class`` (the track's); the full-size run takes ``t_max = 120`` s steps of 0.02 s."""
    from racing_env.envelope import ggv
    from racing_env.vehicles import vehicle_class as _class

    if vehicle_class == "orca":
        env = ggv()
    else:
        env = ggv(_class(vehicle_class)())
        dt, t_max = max(dt, 0.02), max(t_max, 120.0)
    v_grid = np.linspace(0.0, env.top_speed, 400)
    a_grid = np.maximum(env.longitudinal_limits(v_grid, 0.0, mu)[0], 0.0)
    t, v, x = [0.0], [0.0], [0.0]
    while t[-1] < t_max:
        a = float(np.interp(v[-1], v_grid, a_grid))
        if a < 1e-3:  # at the top speed
            break
        v_new = v[-1] + a * dt
        x.append(x[-1] + 0.5 * (v[-1] + v_new) * dt)
        v.append(v_new)
        t.append(t[-1] + dt)
    return np.array(t), np.array(v), np.array(x)


_CACHE: dict = {}
_CACHE_MAX = 32


def _tables(raceline, track, friction) -> _Tables:
    key = (id(raceline), id(track), friction)
    tab = _CACHE.get(key)
    if tab is None:
        if len(_CACHE) >= _CACHE_MAX:
            _CACHE.clear()
        tab = _CACHE[key] = _Tables(raceline, track, friction)
    return tab


def clear_cache() -> None:
    """Forget the cached per-race-line tables (call after mutating a race line in place)."""
    _CACHE.clear()


_STEPS: dict = {}


def _check_horizon(K, dt):
    if isinstance(K, bool) or int(K) != K or int(K) < 1:
        raise ValueError(f"K must be an integer >= 1, got {K!r}")
    dt_f = float(dt)
    if not (math.isfinite(dt_f) and dt_f > 0):
        raise ValueError(f"dt must be a positive finite number [s], got {dt!r}")
    return int(K), dt_f


def _steps(K: int, dt: float):
    key = (K, dt)
    v = _STEPS.get(key)
    if v is None:
        if len(_STEPS) > 64:
            _STEPS.clear()
        a = dt * np.arange(K + 1)
        a.setflags(write=False)
        b = a[1:]
        v = _STEPS[key] = (a, b)
    return v


def _interp1(table: np.ndarray, s_w: float, inv_ds: float) -> float:
    """Linear interpolation of an extended grid table at one wrapped s in [0, L).

    Not :func:`racing_env.interp.periodic_lookup`: these tables hold M + 1 entries whose last
    is the lap's end, not a repeat of the first (the race-line time ``tt`` ends at the lap time
    T), and the look-up runs in plain Python in the reference's per-opponent loop."""
    f = s_w * inv_ds
    i = int(f)
    if i >= len(table) - 1:
        return float(table[-1])
    t = f - i
    return float(table[i]) * (1.0 - t) + float(table[i + 1]) * t
