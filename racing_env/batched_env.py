"""B head-to-head races of one learner against embedded opponents, without stable-baselines3.

:class:`HeadToHeadBatch` is the part shared by the two vectorised envs: the Gymnasium
``VectorEnv`` of ``gymnasium.make_vec`` (:class:`racing_env.gym_vector.HeadToHeadVectorEnv`,
core install only) and the stable-baselines3 ``VecEnv``
(:class:`racing_env.vec_env.HeadToHeadVecEnv`, the ``learn`` extra). It builds the
:class:`racing_env.BatchedRaces` core, the spaces and the opponents, and resets one race at a
time exactly as :class:`racing_env.gym_env.HeadToHeadEnv` resets its race.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from .agent_protocol import act_named, is_agent
from .class_config import class_race
from .config import RaceConfig
from .core import BatchedRaces
from .gym_env import default_opponents, make_opponent
from .parallel_env import _check_learner_reset_options, _start_config, check_reward_options
from .track import Track


class HeadToHeadBatch:
    """``n_envs`` races of ``car_0`` (the learner) against embedded opponents, one core.

    Arguments as :class:`racing_env.gym_env.HeadToHeadEnv`: ``opponents`` (spec strings,
    factories or agents; default two raceline followers), ``track``, ``config`` and the
    :class:`RaceConfig` keywords ``n_cars``, ``max_cycles``, ``laps``, ``start``, ``vehicle``,
    ``rules``, plus the learner's reward options ``offtrack_penalty`` and
    ``terminate_off_track`` and the class options ``vehicle_class`` and ``wake`` (see
    ``HeadToHeadEnv``).
    """

    def __init__(
        self,
        n_envs: int = 8,
        opponents: Sequence | None = None,
        track: str | Track | None = None,
        config: RaceConfig | None = None,
        **kwargs,
    ):
        if not (isinstance(n_envs, (int, np.integer)) and n_envs >= 1):
            raise ValueError(f"n_envs must be a positive integer, got {n_envs!r}")
        if opponents is None:
            opponents = default_opponents()
        opponents = list(opponents)
        cfg, track = class_race(
            kwargs.pop("vehicle_class", None),
            track,
            config,
            kwargs.get("vehicle"),
            kwargs.pop("wake", None),
        )
        changes = {}
        n_cars = kwargs.pop("n_cars", 1 + len(opponents))
        if n_cars != 1 + len(opponents):
            raise ValueError(
                f"n_cars = {n_cars} but {len(opponents)} opponents were given; "
                f"n_cars must be 1 + number of opponents"
            )
        changes["n_cars"] = n_cars
        for key in ("max_cycles", "laps", "vehicle", "rules"):
            if kwargs.get(key) is not None:
                changes[key] = kwargs.pop(key)
        if kwargs.get("start") is not None:
            changes["start"] = _start_config(kwargs.pop("start"), cfg.start)
        kwargs.pop("start", None)
        self.offtrack_penalty, self.terminate_off_track = check_reward_options(
            kwargs.pop("offtrack_penalty", 0.0), kwargs.pop("terminate_off_track", False)
        )
        if kwargs:
            raise ValueError(f"unknown arguments {sorted(kwargs)}")
        cfg = cfg.with_(**changes)
        self.num_envs = int(n_envs)
        self.core = BatchedRaces(track, cfg, n_races=self.num_envs)
        self.track = self.core.track
        lo, hi = self.core.observation_bounds()
        self.observation_space = spaces.Box(lo, hi, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        self._install(opponents)
        # per-race generators, as HeadToHeadEnv.np_random
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._actions = np.zeros((self.num_envs, n_cars, 2))
        self.agent_ids = [f"car_{i}" for i in range(n_cars)]
        self._set_up()

    def _set_up(self) -> None:
        """The end of ``__init__``, where a subclass finishes its own set-up on the built races
        and spaces (the stable-baselines3 ``VecEnv`` its base class's); nothing here."""

    @property
    def config(self) -> RaceConfig:
        return self.core.config

    def _reset_race(self, b: int, seed: int | None, options: dict | None) -> None:
        """Reset race ``b`` as ``HeadToHeadEnv.reset(seed=seed, options=options)`` resets its
        race (the options are checked before anything changes)."""
        options = _check_learner_reset_options(options, self.core.n_cars)
        start = _start_config(options["start"], self.config.start) if "start" in options else None
        rng = self._rngs[b]
        if seed is not None or rng is None:
            rng, _ = seeding.np_random(seed)
            self._rngs[b] = rng
        race_seed = int(rng.integers(2**31))
        self.core.reset(seed=race_seed, races=[b], order=options.get("order"), start=start)
        for k, opp in enumerate(self.opponents):
            agent_id = self.agent_ids[k + 1]
            if self._batched[k]:
                opp.reset(self.track, agent_id, race_seed + k + 1)
            else:
                opp[b].reset(self.track, agent_id, race_seed + k + 1)

    def _opponent_actions(self, obs: np.ndarray, races) -> None:
        """Every opponent's actions of this step, from the observations ``obs`` (B, N, D), into
        ``_actions[:, 1:]``: a batched opponent's for all races at once (``act_batch``), every
        other's race by race for the races ``races``. An error raised in an agent is raised
        again naming it and its car (:func:`racing_env.agent_protocol.act_named`)."""
        for k, opp in enumerate(self.opponents):
            car = self.agent_ids[k + 1]
            if self._batched[k]:
                self._actions[:, k + 1] = act_named(opp, obs[:, k + 1], car, batch=True)
            else:
                for b in races:
                    self._actions[b, k + 1] = act_named(opp[b], obs[b, k + 1], car)

    def _learner_step(self, rew: np.ndarray, term: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The learner's reward (B,) and termination (B,) of this step, with the off-track
        options applied (both unchanged by default)."""
        rew = rew[:, 0].copy()
        if self.offtrack_penalty or self.terminate_off_track:
            off = self.core.offtrack[:, 0].astype(bool)
            rew = rew - self.offtrack_penalty * off
            if self.terminate_off_track:
                term = term | off
        return rew, term

    def _infos(self, races) -> list[dict]:
        """The learner's info dicts of races ``races`` (keys as the parallel env's)."""
        return self.core.infos(np.fromiter(races, dtype=np.int64), 0)

    def set_opponents(self, opponents: Sequence) -> None:
        """Replace the opponents (same number); they act from the next step, are reset at the
        next episode start of each race (call ``reset`` to restart every race now)."""
        opponents = list(opponents)
        if len(opponents) != len(self.opponents):
            raise ValueError(f"{len(opponents)} opponents given, the env has {len(self.opponents)}")
        self._install(opponents)

    def _install(self, opponents: list) -> None:
        """Build the opponents (specs, factories or agents; see
        :data:`racing_env.gym_env.OpponentSpec`): a batched agent instance (``act_batch``) acts
        for all races at once as it is; every other opponent gets one agent of its own per race."""
        built, batched = [], []
        for k, opp in enumerate(opponents):
            if is_agent(opp) and callable(getattr(opp, "act_batch", None)):
                built.append(opp)
                batched.append(True)
            else:
                built.append([make_opponent(opp, k) for _ in range(self.num_envs)])
                batched.append(False)
        self._batched = batched
        self.opponents = built

    def close(self) -> None:
        """Nothing to release (the core holds arrays only)."""
