"""The registered env's ``vector_entry_point``: ``HeadToHeadEnv`` x B as one Gymnasium ``VectorEnv``.

``gymnasium.make_vec("alpha_racer/HeadToHead-v2", num_envs=B)`` (or with
``vectorization_mode="vector_entry_point"``) builds :class:`HeadToHeadVectorEnv`: the B races
are stepped by one compiled call (:class:`racing_env.BatchedRaces`) instead of B env steps,
and env ``b`` behaves exactly like ``gymnasium.make("alpha_racer/HeadToHead-v2")`` seeded as
Gymnasium's ``SyncVectorEnv`` seeds it (``seed + b``), autoreset included (``NEXT_STEP``:
the step after an episode end returns the new episode's first observation, reward 0).

Needs only the core install (no stable-baselines3: the batched races live in
:mod:`racing_env.batched_env`; the SB3 ``VecEnv`` is :mod:`racing_env.vec_env`, behind the
``learn`` extra). ``import racing_env`` alone does not load this module.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .batched_env import HeadToHeadBatch
from .config import RaceConfig
from .track import Track

if TYPE_CHECKING:
    from .core import BatchedRaces


class HeadToHeadVectorEnv(VectorEnv):
    """``num_envs`` races of one learner (``car_0``) against embedded opponents.

    Arguments as :class:`racing_env.gym_env.HeadToHeadEnv` (``opponents``: agent spec strings,
    factories or agents, each env getting opponents of its own; ``track``, ``config``,
    ``n_cars``, ``max_cycles``, ``laps``, ``start``, ``vehicle``, ``rules``) plus ``num_envs``
    and ``max_episode_steps`` (what ``TimeLimit`` does for the single env: episodes are also
    truncated after that many steps; ``gymnasium.make_vec`` passes the registered 500).

    ``reset(seed=s)`` seeds env ``b`` with ``s + b`` (or ``seed[b]`` for a list);
    ``reset(options=...)`` takes ``{"start": ..., "order": [...]}`` for every env. Infos are
    Gymnasium's vector infos (per key an array and a ``_key`` mask) of the single env's infos.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}
    render_mode = None

    def __init__(
        self,
        num_envs: int = 8,
        opponents: Sequence | None = None,
        track: str | Track | None = None,
        config: RaceConfig | None = None,
        max_episode_steps: int | None = None,
        **kwargs,
    ):
        self._batch = HeadToHeadBatch(
            num_envs, opponents=opponents, track=track, config=config, **kwargs
        )
        self.num_envs = self._batch.num_envs
        self.single_observation_space = self._batch.observation_space
        self.single_action_space = self._batch.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._time_limit = math.inf if max_episode_steps is None else int(max_episode_steps)
        self._all_obs: np.ndarray | None = None
        self._autoreset = np.zeros(self.num_envs, dtype=bool)

    @property
    def core(self) -> BatchedRaces:
        """The :class:`racing_env.BatchedRaces` of the B races."""
        return self._batch.core

    @property
    def opponents(self) -> list:
        return self._batch.opponents

    def reset(
        self, *, seed: int | Sequence[int | None] | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed if isinstance(seed, int) else None)
        if seed is None or isinstance(seed, int):
            seeds = [None if seed is None else seed + b for b in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds given for {self.num_envs} envs")
        for b in range(self.num_envs):
            self._batch._reset_race(b, seeds[b], options)
        self._autoreset[:] = False
        self._all_obs = self.core.observe()
        return self._all_obs[:, 0].copy(), self._infos()

    def step(
        self, actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict]:
        if self._all_obs is None:
            raise RuntimeError("step() called before reset(); call reset() first")
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, 2):
            raise ValueError(
                f"actions must have shape ({self.num_envs}, 2) (envs, [throttle, "
                f"steering]), got {a.shape}"
            )
        acts, obs, done = self._batch._actions, self._all_obs, self._autoreset
        acts[:, 0] = np.where(done[:, None], 0.0, a)  # envs being reset ignore their action
        self._batch._opponent_actions(obs, np.flatnonzero(~done))
        _, rew, term, trunc = self.core.step(acts)
        rew, term = self._batch._learner_step(rew, term)
        trunc = (trunc & ~term) | (self.core.t >= self._time_limit)
        for b in np.flatnonzero(done):
            self._batch._reset_race(int(b), None, None)
        rew[done], term[done], trunc[done] = 0.0, False, False
        self._autoreset = term | trunc
        self._all_obs = self.core.observe()
        return self._all_obs[:, 0].copy(), rew, term, trunc, self._infos()

    def _infos(self) -> dict:
        infos: dict = {}
        for b, info in enumerate(self._batch._infos(range(self.num_envs))):
            infos = self._add_info(infos, info, b)
        return infos

    def close_extras(self, **kwargs) -> None:
        self._batch.close()
