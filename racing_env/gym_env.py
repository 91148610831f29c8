"""Gymnasium single-agent env: one learner races opponents that are given as agents."""
from __future__ import annotations

import copy
from typing import Any, Callable, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .config import RaceConfig, StartConfig
from .parallel_env import RacingParallelEnv
from .track import Track


OpponentSpec = Any
"""An opponent as the envs accept it: an agent spec string (``"mpc:zeta=0.9"``, built by
:func:`agents.make_agent_spec`), a factory (a callable without ``act`` returning an agent), or
an agent instance (an object with ``reset(track, agent_id, seed)`` and ``act(observation)``)."""


def _is_agent(obj) -> bool:
    """An agent instance (a class with ``act`` and ``reset`` is a factory, not an agent)."""
    return not isinstance(obj, type) and callable(getattr(obj, "act", None)) and callable(getattr(obj, "reset", None))


def make_opponent(spec: OpponentSpec, k: int = 0):
    """A fresh opponent agent of its own from ``spec`` (see :data:`OpponentSpec`): a spec string
    is built through the agents registry, a factory is called, an instance is deep-copied, so
    that no two envs share an opponent's state. ``k`` (the opponent's index) names it in errors."""
    if isinstance(spec, str):
        import agents                 # lazily: racing_env does not depend on agents at import
        return agents.make_agent_spec(spec)
    if _is_agent(spec):
        return copy.deepcopy(spec)
    if callable(spec):
        agent = spec()
        if not _is_agent(agent):
            raise ValueError(f"opponent {k}: factory {spec!r} returned {agent!r}, which lacks "
                             f"reset(track, agent_id, seed) and act(observation) methods")
        return agent
    raise ValueError(f"opponent {k} ({spec!r}) must be an agent spec string, a factory, or an agent "
                     f"with reset(track, agent_id, seed) and act(observation) methods")


def default_opponents() -> list:
    """Two :class:`racing_env.controllers.RacelineFollower` s (envelope scales 0.75 and 0.8)."""
    from .controllers import RacelineFollower
    return [RacelineFollower(mu=0.75), RacelineFollower(mu=0.8)]


class HeadToHeadEnv(gym.Env):
    """The learner drives ``car_0``; every other car is driven by an opponent agent.

    Registered as ``alpha_racer/HeadToHead-v2`` (``spec.max_episode_steps`` = 500, the
    default ``max_cycles``: ``gymnasium.make``'s ``TimeLimit`` truncates at the same step as the
    env; to race longer pass both ``max_episode_steps`` and ``max_cycles``), with a
    ``vector_entry_point`` (:class:`racing_env.gym_vector.HeadToHeadVectorEnv`) for
    ``gymnasium.make_vec``.

    **Action space**: ``Box(-1, 1, (2,), float32)``, ``[throttle, steering]`` as in
    :class:`racing_env.RacingParallelEnv`.

    **Observation space**: ``car_0``'s observation in :class:`RacingParallelEnv` (own Frenet
    state, opponents relative to it, curvature preview), ``Box`` float32 of ``6 N + n_preview``.

    **Reward**: ``car_0``'s relative progress per step, the change of ``s_0 - max_{j>0} s_j`` [m].

    **Starting state**: as :class:`RacingParallelEnv` (``start``: ``"regions"`` by default, or
    ``"grid"``, ``"random"``, a :class:`racing_env.StartConfig`); ``reset(seed)`` draws the
    race's seed from the env's ``np_random``, opponent k is reset with that seed + k + 1.

    **Episode end**: ``terminated`` when a car completes ``laps`` (if set); ``truncated`` after
    ``max_cycles`` steps (default 500 = 50 s).

    **Arguments**: ``opponents``: a sequence, one per opponent car, of agent spec strings
    (``"mpc:zeta=0.9"``, built by :func:`agents.make_agent_spec`), factories (callables
    returning an agent) or agents (objects with ``reset(track, agent_id, seed)`` and
    ``act(observation) -> action``, deep-copied): every env gets opponents of its own, so the
    copies made by ``gymnasium.make_vec`` or SB3's ``make_vec_env`` never share state. Default
    two :class:`racing_env.controllers.RacelineFollower` s on the speed profiles of friction
    0.75 and 0.8. ``n_cars`` defaults to ``1 + len(opponents)``. Other keywords (``track``,
    ``max_cycles``, ``laps``, ``start``, ``vehicle``, ``rules``, ``config``, ``render_mode``)
    go to :class:`RacingParallelEnv`. ``reset(options=...)`` accepts ``start`` and ``order``.

    **Info**: the learner's per-step info of the parallel env.

    **Version History**: as :class:`RacingParallelEnv` (v2: contact keeps the bodies apart;
    v1, contact over the whole control period, applied at the first moment of contact, and v0,
    contact only at the end of each step, are not registered any more).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(self, opponents: Sequence | None = None, track: "str | Track" = "default",
                 render_mode: str | None = None, config: RaceConfig | None = None,
                 start: "str | StartConfig | None" = None, **kwargs):
        if opponents is None:
            opponents = default_opponents()
        if isinstance(opponents, str) or _is_agent(opponents):
            raise ValueError(f"opponents must be a sequence (one per opponent car), got {opponents!r}")
        self.opponents = [make_opponent(o, k) for k, o in enumerate(opponents)]
        n_cars = kwargs.pop("n_cars", 1 + len(self.opponents))
        if n_cars != 1 + len(self.opponents):
            raise ValueError(f"n_cars = {n_cars} but {len(self.opponents)} opponents were given; "
                             f"n_cars must be 1 + number of opponents")
        self.race = RacingParallelEnv(track=track, n_cars=n_cars, render_mode=render_mode,
                                      config=config, start=start, **kwargs)
        self.render_mode = render_mode
        self.learner = self.race.possible_agents[0]
        self.observation_space = self.race.observation_space(self.learner)
        self.action_space = self.race.action_space(self.learner)
        self._last_obs = None

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        race_seed = int(self.np_random.integers(2 ** 31))
        obs, infos = self.race.reset(seed=race_seed, options=options)
        for k, opp in enumerate(self.opponents):
            opp.reset(self.race.track, self.race.possible_agents[k + 1], race_seed + k + 1)
        self._last_obs = obs
        return obs[self.learner], infos[self.learner]

    def step(self, action):
        actions = {self.learner: np.asarray(action, dtype=np.float32)}
        for k, opp in enumerate(self.opponents):
            agent = self.race.possible_agents[k + 1]
            actions[agent] = opp.act(self._last_obs[agent])
        obs, rew, term, trunc, infos = self.race.step(actions)
        self._last_obs = obs
        a = self.learner
        return obs[a], rew[a], term[a], trunc[a], infos[a]

    def render(self):
        return self.race.render()

    def close(self):
        self.race.close()
