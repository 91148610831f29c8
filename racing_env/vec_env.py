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

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import spaces

from .batched_env import HeadToHeadBatch
from .extras import require

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv
else:  # stable-baselines3 missing: require names the extra to install
    VecEnv = require("stable_baselines3.common.vec_env.base_vec_env", "racing_env.vec_env").VecEnv


class HeadToHeadVecEnv(HeadToHeadBatch, VecEnv):
    """B races of one learner (``car_0``) against embedded opponents, as an SB3 ``VecEnv``.

    Arguments as :class:`racing_env.gym_env.HeadToHeadEnv` (``opponents``, ``track``,
    ``config``, the :class:`RaceConfig` keywords ``max_cycles``, ``laps``, ``start``,
    ``vehicle``, ``rules``, and the reward options ``offtrack_penalty`` and
    ``terminate_off_track``) plus ``n_envs`` (B). Spaces, rewards, episode ends and the
    per-step info dicts are those of ``HeadToHeadEnv`` plus ``TimeLimit.truncated``; on an
    episode end the info also holds ``terminal_observation`` and the race restarts at once (SB3's
    VecEnv convention). ``seed(s)`` seeds race ``b`` with ``s + b`` at the next reset;
    ``set_options`` takes ``{"start": ..., "order": [...]}`` as ``HeadToHeadEnv.reset`` does.
    Wrap it in SB3's ``VecMonitor`` to log ``ep_rew_mean`` and in ``VecNormalize`` to
    normalise observations (their scales are in ``HeadToHeadEnv``'s docstring).
    """

    metadata: dict[str, Any] = {"render_modes": []}
    observation_space: spaces.Box[np.float32]
    action_space: spaces.Box[np.float32]
    render_mode = None

    # __init__ is HeadToHeadBatch's, which ends in _set_up
    def _set_up(self) -> None:
        VecEnv.__init__(self, self.num_envs, self.observation_space, self.action_space)
        self._obs: np.ndarray | None = None

    # ------------------------------------------------------------------ resets
    def reset(self) -> np.ndarray:
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

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict]]:
        if self._obs is None:
            raise RuntimeError("step() before reset()")
        self._opponent_actions(self._obs, range(self.num_envs))
        obs, rew, term, trunc = self.core.step(self._actions)
        rew, term = self._learner_step(rew, term)
        trunc = trunc & ~term
        dones = term | trunc
        infos = self._infos(range(self.num_envs))
        for b in range(self.num_envs):
            infos[b]["TimeLimit.truncated"] = bool(trunc[b])
        for d in np.flatnonzero(dones):  # the races that ended
            infos[d]["terminal_observation"] = obs[d, 0].copy()
            self._reset_race(int(d), None, None)
        if dones.any():
            obs = self.core.observe()
            for d in np.flatnonzero(dones):
                self.reset_infos[d] = self._infos([d])[0]
        self._obs = obs
        return obs[:, 0].copy(), rew.astype(np.float32), dones, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: int | Iterable[int] | None = None) -> list[Any]:
        return [getattr(self, attr_name) for _ in self._get_indices(indices)]

    def set_attr(
        self, attr_name: str, value: Any, indices: int | Iterable[int] | None = None
    ) -> None:
        setattr(self, attr_name, value)

    def env_method(
        self,
        method_name: str,
        *method_args,
        indices: int | Iterable[int] | None = None,
        **method_kwargs,
    ) -> list[Any]:
        return [
            getattr(self, method_name)(*method_args, **method_kwargs)
            for _ in self._get_indices(indices)
        ]

    def env_is_wrapped(
        self, wrapper_class: type, indices: int | Iterable[int] | None = None
    ) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> list[None]:
        return [None for _ in range(self.num_envs)]
