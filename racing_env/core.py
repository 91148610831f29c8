"""The one race core: ``B`` races of ``N`` cars on a track, stepped together.

:class:`BatchedRaces` is the batched path (data collection, RL training) and the engine inside
the PettingZoo and Gymnasium environments, which run it with ``n_races=1``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from .cache import notice
from .config import RaceConfig, StartConfig
from .simulator import TrackTables, advance, advance_parallel, observe, observe_parallel

PARALLEL_MIN_RACES = 16
"""Batches of at least this many races are stepped by the multi-threaded kernels."""
from .track import Track  # noqa: E402
from .tracks import make_track  # noqa: E402
from .vehicle import VehicleParams  # noqa: E402
from .vehicles.fullsize import FullSizeParams  # noqa: E402
from .wake import A_DRAG  # noqa: E402

if TYPE_CHECKING:
    from collections.abc import Sequence

S_CLIP = 1.0e4
"""Bound [m] of the relative progress entries of an observation for the ORCA car (333 laps of
a 30 m track); a class of another size has it times its length ratio (:func:`s_clip`)."""

#: Keys of the envs' per-car info dicts, as :meth:`BatchedRaces.infos` fills them.
INFO_KEYS = (
    "contact",
    "off_track",
    "laps",
    "progress",
    "substeps",
    "contacts",
    "off_tracks",
    "drag_factor",
    "downforce_factor",
)


def s_clip(vehicle: VehicleParams | FullSizeParams) -> float:
    """Bound [m] of the relative progress in an observation: :data:`S_CLIP` times the car's
    length over the ORCA car's (1e4 m for ORCA; 3.9e5 m, 67 laps of Monza, at full size)."""
    ratio = vehicle.length / VehicleParams().length
    return S_CLIP if ratio == 1.0 else S_CLIP * ratio


def top_speed(vehicle: VehicleParams | FullSizeParams, drag_factor: float = 1.0) -> float:
    """Top speed [m/s] of either class on a straight with its drag times ``drag_factor``."""
    if isinstance(vehicle, FullSizeParams):
        return vehicle.top_speed(drag_factor)
    if drag_factor == 1.0:
        return vehicle.top_speed
    return replace(vehicle, C4=vehicle.C4 * drag_factor).top_speed


def start_states(
    track: Track,
    n_cars: int,
    start: StartConfig,
    width: float,
    rng: np.random.Generator,
    order: Sequence[int] | np.ndarray | None = None,
) -> np.ndarray:
    """Initial states (n_cars, 6) for one race; see :class:`StartConfig` for the modes.

    ``order`` (regions mode): ``order[i]`` is the region index (0 = R1, front-most) of car i;
    default a random permutation.
    """
    x = np.zeros((n_cars, 6))
    wl, wr = track.widths(np.array([start.s0]))
    usable = max(float(min(wl[0], wr[0])) - width / 2.0, 0.0)
    if start.mode == "grid":
        for i in range(n_cars):
            row, col = divmod(i, 2)
            x[i, 0] = start.s0 - row * start.grid_gap - col * start.grid_gap / 2.0
            x[i, 1] = (0.5 if col == 0 else -0.5) * usable
    elif start.mode == "regions":
        span = n_cars * start.region_length + (n_cars - 1) * start.region_gap
        if span > 0.5 * track.length:
            raise ValueError(
                f"{n_cars} start regions span {span:.2f} m, over half the track "
                f"length {track.length:.2f} m; shorten region_length/region_gap"
            )
        order = rng.permutation(n_cars) if order is None else np.asarray(order)
        if sorted(order.tolist()) != list(range(n_cars)):
            raise ValueError(
                f"start order must be a permutation of 0..{n_cars - 1}, got {order.tolist()}"
            )
        for i in range(n_cars):
            front = start.s0 - order[i] * (start.region_length + start.region_gap)
            x[i, 0] = front - rng.uniform(0.0, start.region_length)
            x[i, 1] = rng.uniform(-1.0, 1.0) * start.lateral_jitter * usable
    else:  # random
        if n_cars * start.min_gap > track.length:
            raise ValueError(
                f"{n_cars} cars at least {start.min_gap} m apart do not fit on "
                f"a {track.length:.2f} m track"
            )
        # equal slots at a random rotation, jittered so that neighbours stay min_gap apart
        slot = track.length / n_cars
        jitter = 0.5 * max(slot - start.min_gap, 0.0)
        s = (
            rng.uniform(0.0, track.length)
            + slot * np.arange(n_cars)
            + rng.uniform(-jitter, jitter, n_cars)
        )
        x[:, 0] = (s % track.length)[rng.permutation(n_cars)]
        wl, wr = track.widths(x[:, 0])
        lim = np.maximum(np.minimum(wl, wr) - width / 2.0, 0.0)
        x[:, 1] = rng.uniform(-1.0, 1.0, n_cars) * start.lateral_jitter * lim
    x[:, 3] = start.speed
    return x


class BatchedRaces:
    """``n_races`` independent races of ``config.n_cars`` cars on one track.

    Arrays (B = n_races, N = n_cars, D = obs_dim):

    * ``state`` (B, N, 6): per car ``(s, n, mu, vx, vy, omega)``, s unwrapped [m].
    * :meth:`step` takes normalised actions (B, N, 2) in [-1, 1]: throttle (-1 full brake,
      +1 full throttle, mapped affinely onto [d_min, d_max]) and steering (mapped onto
      [-delta_max, delta_max], +1 steers left). Values outside [-1, 1], +-inf included, are
      clipped; NaN raises ``ValueError``.
    * Observations (B, N, D) float32, layout in :func:`racing_env.simulator.observe`.

    Each race keeps its own step counter, lap counts and lap times; the start/finish line of
    a race is the start position of its front-most car.
    """

    def __init__(
        self,
        track: Track | str = "default",
        config: RaceConfig | None = None,
        n_races: int = 1,
        seed: int | None = None,
    ):
        if not (isinstance(n_races, (int, np.integer)) and n_races >= 1):
            raise ValueError(f"n_races must be a positive integer, got {n_races!r}")
        notice()  # the cache-fallback warning, if any, once per process
        self.config = config or RaceConfig()
        cls = self.config.vehicle_class
        self.track = make_track(track, vehicle_class=cls)
        if self.track.vehicle_class != cls:
            raise ValueError(
                f"track {self.track.name!r} is sized for the {self.track.vehicle_class!r} "
                f"class but the race's vehicle is of the {cls!r} class; build the track with "
                f"make_track(..., vehicle_class={cls!r})"
            )
        self.n_races = int(n_races)
        self._tables = TrackTables.from_track(self.track, self.config.rules.wall_margin)
        self._params = self.config.vehicle.pack()
        self._rules = self.config.pack_rules()
        self._s_clip = s_clip(self.config.vehicle)
        self.rng = np.random.default_rng(seed)
        self._alloc()

    # ------------------------------------------------------------------ set-up
    def _alloc(self) -> None:
        b, n = self.n_races, self.config.n_cars
        self.state = np.zeros((b, n, 6))
        self.start = np.zeros((b, n, 6))
        self.t = np.zeros(b, dtype=np.int64)
        self.s_line = np.zeros(b)
        self.laps = np.zeros((b, n), dtype=np.int64)
        self.lap_times: list[list[list[float]]] = [[[] for _ in range(n)] for _ in range(b)]
        self.contacts = np.zeros((b, n), dtype=np.int64)
        self.offtracks = np.zeros((b, n), dtype=np.int64)
        self.reward = np.zeros((b, n))
        self.contact = np.zeros((b, n), dtype=np.int8)
        self.offtrack = np.zeros((b, n), dtype=np.int8)
        self.substeps = np.zeros((b, n), dtype=np.int32)
        self.wake = np.ones((b, n, 2))
        self._obs = np.zeros((b, n, self.obs_dim), dtype=np.float32)
        self._phys = np.zeros((b, n, 2))
        v = self.config.vehicle
        self._act_map = np.array(
            [0.5 * (v.d_max + v.d_min), 0.5 * (v.d_max - v.d_min), v.delta_max]
        )
        self._lap_event = np.full((b, n), -1.0)
        self._where = np.zeros(2, dtype=np.int64)

    @property
    def n_cars(self) -> int:
        return self.config.n_cars

    @property
    def obs_dim(self) -> int:
        return 6 * self.config.n_cars + self.config.n_preview

    def set_n_cars(self, n_cars: int) -> None:
        """Change the number of cars (takes effect now; call :meth:`reset` next)."""
        if n_cars != self.config.n_cars:
            self.config = self.config.with_(n_cars=n_cars)
            self._alloc()

    def reset(
        self,
        seed: int | None = None,
        races: Sequence[int] | np.ndarray | None = None,
        order: Sequence[int] | np.ndarray | None = None,
        start: StartConfig | None = None,
    ) -> np.ndarray:
        """Put races (default: all; or an index array) on the start line; returns observations.

        ``seed`` reseeds the race generator (same seed, same starts). ``order`` fixes the
        start regions of the cars (see :func:`start_states`); ``start`` overrides the config.
        A reset that raises (a bad order, cars that do not fit) leaves every race and the
        generator as they were.
        """
        idx = np.arange(self.n_races) if races is None else np.atleast_1d(races)
        start = start or self.config.start
        rng = self.rng if seed is None else np.random.default_rng(seed)
        saved = rng.bit_generator.state
        # every start first (each may raise), then the races change: a failed reset changes nothing
        try:
            starts = [
                start_states(self.track, self.n_cars, start, self.config.vehicle.width, rng, order)
                for _ in idx
            ]
        except BaseException:
            rng.bit_generator.state = saved  # a failed draw does not advance the race generator
            raise
        self.rng = rng
        for b, x in zip(idx, starts):
            self.state[b] = x
            self.start[b] = self.state[b]
            self.s_line[b] = self.state[b, :, 0].max()
            self.t[b] = 0
            self.laps[b] = 0
            self.lap_times[b] = [[] for _ in range(self.n_cars)]
            self.contacts[b] = 0
            self.offtracks[b] = 0
        self.reward[idx] = 0.0
        self.contact[idx] = 0
        self.offtrack[idx] = 0
        return self.observe()

    # ------------------------------------------------------------------ stepping
    def _advance(self, actions, normalised: bool):
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != self._phys.shape:
            raise ValueError(
                f"actions must have shape {self._phys.shape} (races, cars, 2), got {a.shape}"
            )
        kernel = advance_parallel if self.n_races >= PARALLEL_MIN_RACES else advance
        code = kernel(
            self.state,
            a,
            normalised,
            self._act_map,
            self._tables,
            self._params,
            self.config.dt,
            self._rules,
            self.t,
            self.s_line,
            self.laps,
            self.contacts,
            self.offtracks,
            self._lap_event,
            self.reward,
            self.contact,
            self.offtrack,
            self.substeps,
            self.wake,
            self._where,
        )
        if code:
            b, i = self._where
            if code == 1:
                what = "NaN" if normalised else "not finite"
                raise ValueError(f"action of car {i} in race {b} is {what}: {a[b, i].tolist()}")
            raise FloatingPointError(
                f"simulation produced a non-finite state for car {i} in race {b} "
                f"at step {self.t[b]}: {self.state[b, i].tolist()} "
                f"(action {a[b, i].tolist()})"
            )
        if self.laps.any():
            for b, i in np.argwhere(self._lap_event >= 0.0):
                self.lap_times[b][i].append(float(self._lap_event[b, i]))

    def step_physical(self, phys: np.ndarray) -> None:
        """Advance all races by one control period with physical inputs (B, N, 2) = (d, delta)."""
        self._advance(phys, normalised=False)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One control period for every race with normalised actions (B, N, 2).

        Actions are clipped to [-1, 1] (+-inf too); a NaN raises ``ValueError`` naming the race and car
        (and nothing is stepped). Returns ``(obs, reward, terminated, truncated)``: obs (B, N, D)
        float32, reward (B, N) (change of s_i - max_{j != i} s_j [m]), terminated (B,) (a car
        finished ``laps``), truncated (B,) (``max_cycles`` reached). Per-car flags of this step
        are in ``contact``, ``offtrack`` and ``substeps``; totals in ``contacts``, ``offtracks``.
        """
        self._advance(actions, normalised=True)
        return self.observe(), self.reward.copy(), self.terminated(), self.truncated()

    def terminated(self) -> np.ndarray:
        if self.config.laps is None:
            return np.zeros(self.n_races, dtype=bool)
        return self.laps.max(axis=1) >= self.config.laps

    def truncated(self) -> np.ndarray:
        return self.t >= self.config.max_cycles

    def observe(self) -> np.ndarray:
        kernel = observe_parallel if self.n_races >= PARALLEL_MIN_RACES else observe
        kernel(
            self.state,
            self._tables,
            self.config.preview_ds,
            self.config.n_preview,
            self._s_clip,
            self._obs,
        )
        return self._obs.copy()

    def progress(self) -> np.ndarray:
        """Distance driven since the start [m], (B, N)."""
        return self.state[:, :, 0] - self.start[:, :, 0]

    def infos(
        self, races: int | Sequence[int] | np.ndarray, cars: int | Sequence[int] | np.ndarray
    ) -> list[dict]:
        """The envs' info dicts (keys :data:`INFO_KEYS`) of the cars ``cars`` in races
        ``races`` (integers or index arrays, broadcast together), in that order."""
        r, c = np.broadcast_arrays(np.asarray(races), np.asarray(cars))
        cols = (
            self.contact[r, c].astype(bool).tolist(),
            self.offtrack[r, c].astype(bool).tolist(),
            self.laps[r, c].tolist(),
            (self.state[r, c, 0] - self.start[r, c, 0]).tolist(),
            self.substeps[r, c].tolist(),
            self.contacts[r, c].tolist(),
            self.offtracks[r, c].tolist(),
            self.wake[r, c, 0].tolist(),
            self.wake[r, c, 1].tolist(),
        )
        return [dict(zip(INFO_KEYS, col)) for col in zip(*cols)]

    def state_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of one car's state (6,): the documented physical envelope.

        ``n`` within the walls, ``mu`` wrapped to [-pi, pi], ``0 <= vx``, ``|vx|, |vy| <=
        1.5 * top speed + 1`` m/s, ``|omega| <= 100`` rad/s; ``s`` is unbounded (unwrapped).
        The top speed is the car's in the strongest tow the race's ``wake`` gives (drag factor
        ``(1 - A_DRAG)^wake``, right behind another car): 4.2 m/s for the ORCA car without a
        wake, 91 m/s for the full-size car at ``wake = 1`` (66 m/s in clean air).
        The fuzz (``alpha-racer fuzz``) checks every state against it.
        """
        tb, v = self._tables, self.config.vehicle
        wall = float(max(tb.wall_left.max(), tb.wall_right.max())) + 1e-6
        tow = (1.0 - A_DRAG) ** self.config.wake if self.config.wake > 0 else 1.0
        vmax = 1.5 * max(top_speed(v, tow), self.config.start.speed) + 1.0
        return (
            np.array([-np.inf, -wall, -np.pi, 0.0, -vmax, -100.0]),
            np.array([np.inf, wall, np.pi, vmax, vmax, 100.0]),
        )

    def observation_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of one car's observation (D,), float32, from :meth:`state_bounds`."""
        lo, hi = self.state_bounds()
        own_lo, own_hi = lo.copy(), hi.copy()
        own_lo[0], own_hi[0] = 0.0, self.track.length  # own s is wrapped
        rel_hi = np.concatenate([[self._s_clip], hi[1:] - lo[1:]])
        rel_hi[2] = np.pi  # wrapped difference
        kmax = float(np.abs(self._tables.kappa).max()) + 1e-6
        n, k = self.n_cars, self.config.n_preview
        high = np.concatenate([own_hi, np.tile(rel_hi, n - 1), np.full(k, kmax)])
        low = np.concatenate([own_lo, np.tile(-rel_hi, n - 1), np.full(k, -kmax)])
        return low.astype(np.float32), high.astype(np.float32)
