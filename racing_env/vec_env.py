"""The batched learning env: ``HeadToHeadEnv`` x B as one stable-baselines3 ``VecEnv``.

:class:`HeadToHeadVecEnv` steps B races of :class:`racing_env.BatchedRaces` at once (one
compiled call per step instead of B env steps) and embeds the opponents like
:class:`racing_env.gym_env.HeadToHeadEnv`: race ``b`` of this VecEnv behaves exactly like a
``HeadToHeadEnv`` seeded with ``seed + b`` (same starts, observations, rewards, episode ends
and infos; a test checks this step for step), so it is a drop-in, faster replacement for
``DummyVecEnv([HeadToHeadEnv] * B)``.

Opponents with an ``act_batch(observations (B, D)) -> actions (B, 2)`` method (for example a
frozen neural policy, :class:`agents.ppo_agent.FrozenPolicy`) are called once per step for
all races; every other opponent (an agent, deep-copied; a spec string; or a factory) becomes one
agent per race, called per race.

Imports stable-baselines3 (``VecEnv``, the ``learn`` extra); ``import racing_env`` alone does not
load this module.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from .config import RaceConfig
from .core import BatchedRaces
from .extras import require
from .gym_env import _is_agent, default_opponents, make_opponent
from .parallel_env import _start_config
from .track import Track

VecEnv = require("stable_baselines3.common.vec_env.base_vec_env", "racing_env.vec_env").VecEnv


class HeadToHeadVecEnv(VecEnv):
    """B races of one learner (``car_0``) against embedded opponents, as an SB3 ``VecEnv``.

    Arguments as :class:`racing_env.gym_env.HeadToHeadEnv` (``opponents``, ``track``,
    ``config`` and the :class:`RaceConfig` keywords ``max_cycles``, ``laps``, ``start``,
    ``vehicle``, ``rules``) plus ``n_envs`` (B). Spaces, rewards, episode ends and the
    per-step info dicts are those of ``HeadToHeadEnv`` plus ``TimeLimit.truncated``; on an
    episode end the info also holds ``terminal_observation`` and the race restarts at once (SB3's
    VecEnv convention). ``seed(s)`` seeds race ``b`` with ``s + b`` at the next reset;
    ``set_options`` takes ``{"start": ..., "order": [...]}`` as ``HeadToHeadEnv.reset`` does.
    """

    metadata = {"render_modes": []}
    render_mode = None

    def __init__(self, n_envs: int = 8, opponents: Sequence | None = None,
                 track: "str | Track" = "default", config: RaceConfig | None = None, **kwargs):
        if not (isinstance(n_envs, (int, np.integer)) and n_envs >= 1):
            raise ValueError(f"n_envs must be a positive integer, got {n_envs!r}")
        if opponents is None:
            opponents = default_opponents()
        opponents = list(opponents)
        cfg = config or RaceConfig()
        changes = {}
        n_cars = kwargs.pop("n_cars", 1 + len(opponents))
        if n_cars != 1 + len(opponents):
            raise ValueError(f"n_cars = {n_cars} but {len(opponents)} opponents were given; "
                             f"n_cars must be 1 + number of opponents")
        changes["n_cars"] = n_cars
        for key in ("max_cycles", "laps", "vehicle", "rules"):
            if kwargs.get(key) is not None:
                changes[key] = kwargs.pop(key)
        if kwargs.get("start") is not None:
            changes["start"] = _start_config(kwargs.pop("start"), cfg.start)
        kwargs.pop("start", None)
        if kwargs:
            raise ValueError(f"unknown arguments {sorted(kwargs)}")
        cfg = cfg.with_(**changes)
        self.core = BatchedRaces(track, cfg, n_races=int(n_envs))
        self.track = self.core.track
        lo, hi = self.core.observation_bounds()
        super().__init__(int(n_envs), spaces.Box(lo, hi, dtype=np.float32),
                         spaces.Box(-1.0, 1.0, (2,), dtype=np.float32))
        self._install(opponents)
        self._rngs = [None] * self.num_envs          # per-race generators, as HeadToHeadEnv.np_random
        self._obs = None
        self._actions = np.zeros((self.num_envs, n_cars, 2))
        self.agent_ids = [f"car_{i}" for i in range(n_cars)]

    @property
    def config(self) -> RaceConfig:
        return self.core.config

    # ------------------------------------------------------------------ resets
    def _reset_race(self, b: int, seed: int | None, options: dict | None) -> None:
        if seed is not None or self._rngs[b] is None:
            self._rngs[b], _ = seeding.np_random(seed)
        race_seed = int(self._rngs[b].integers(2 ** 31))
        options = options or {}
        unknown = set(options) - {"start", "order"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; known: start, order")
        start = _start_config(options["start"], self.config.start) if "start" in options else None
        self.core.reset(seed=race_seed, races=[b], order=options.get("order"), start=start)
        for k, opp in enumerate(self.opponents):
            agent_id = self.agent_ids[k + 1]
            if self._batched[k]:
                opp.reset(self.track, agent_id, race_seed + k + 1)
            else:
                opp[b].reset(self.track, agent_id, race_seed + k + 1)

    def reset(self):
        for b in range(self.num_envs):
            self._reset_race(b, self._seeds[b], self._options[b])
        self._reset_seeds()
        self._reset_options()
        self._obs = self.core.observe()
        self.reset_infos = self._infos(range(self.num_envs))
        return self._obs[:, 0].copy()

    # ------------------------------------------------------------------ stepping
    def step_async(self, actions: np.ndarray) -> None:
        self._actions[:, 0] = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, 2)

    def step_wait(self):
        if self._obs is None:
            raise RuntimeError("step() before reset()")
        obs = self._obs
        for k, opp in enumerate(self.opponents):
            if self._batched[k]:
                self._actions[:, k + 1] = opp.act_batch(obs[:, k + 1])
            else:
                for b in range(self.num_envs):
                    self._actions[b, k + 1] = opp[b].act(obs[b, k + 1])
        obs, rew, term, trunc = self.core.step(self._actions)
        trunc = trunc & ~term
        dones = term | trunc
        infos = self._infos(range(self.num_envs))
        for b in range(self.num_envs):
            infos[b]["TimeLimit.truncated"] = bool(trunc[b])
        for b in np.flatnonzero(dones):
            infos[b]["terminal_observation"] = obs[b, 0].copy()
            self._reset_race(int(b), None, None)
        if dones.any():
            obs = self.core.observe()
            for b in np.flatnonzero(dones):
                self.reset_infos[b] = self._infos([b])[0]
        self._obs = obs
        return obs[:, 0].copy(), rew[:, 0].astype(np.float32), dones, infos

    def _infos(self, races) -> list[dict]:
        """The learner's info dicts of races ``races`` (keys as the parallel env's)."""
        return self.core.infos(np.fromiter(races, dtype=np.int64), 0)

    # ------------------------------------------------------------------ VecEnv plumbing
    def set_opponents(self, opponents: Sequence) -> None:
        """Replace the opponents (same number); they act from the next step, are reset at the
        next episode start of each race (call :meth:`reset` to restart every race now)."""
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
            if _is_agent(opp) and callable(getattr(opp, "act_batch", None)):
                built.append(opp)
                batched.append(True)
            else:
                built.append([make_opponent(opp, k) for _ in range(self.num_envs)])
                batched.append(False)
        self._batched = batched
        self.opponents = built

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        return [getattr(self, method_name)(*method_args, **method_kwargs)
                for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        return [None for _ in range(self.num_envs)]
