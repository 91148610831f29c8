"""Gymnasium single-agent env: one learner races opponents that are given as agents."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from .agent_protocol import act_named, is_agent
from .config import RaceConfig, StartConfig
from .parallel_env import (
    RacingParallelEnv,
    _check_learner_reset_options,
    _check_reset_options,
    check_reward_options,
)
from .track import Track

OpponentSpec = Any
"""An opponent as the envs accept it: an agent spec string (``"mpc:zeta=0.9"``, built by
:func:`agents.make_agent_spec`), a factory (a callable without ``act`` returning an agent), or
an agent instance (an object with ``reset(track, agent_id, seed)`` and ``act(observation)``)."""


def make_opponent(spec: OpponentSpec, k: int = 0) -> Any:
    """A fresh opponent agent of its own from ``spec`` (see :data:`OpponentSpec`): a spec string
    is built through the agents registry, a factory is called, an instance is deep-copied, so
    that no two envs share an opponent's state. ``k`` (the opponent's index) names it in errors."""
    if isinstance(spec, str):
        import agents  # lazily: racing_env does not depend on agents at import

        return agents.make_agent_spec(spec)
    if is_agent(spec):
        return copy.deepcopy(spec)
    if callable(spec):
        agent = spec()
        if not is_agent(agent):
            raise ValueError(
                f"opponent {k}: factory {spec!r} returned {agent!r}, which lacks "
                f"reset(track, agent_id, seed) and act(observation) methods"
            )
        return agent
    raise ValueError(
        f"opponent {k} ({spec!r}) must be an agent spec string, a factory, or an agent "
        f"with reset(track, agent_id, seed) and act(observation) methods"
    )


def default_opponents() -> list:
    """Two :class:`racing_env.controllers.RacelineFollower` s (envelope scales 0.75 and 0.8)."""
    from .controllers import RacelineFollower

    return [RacelineFollower(grip=0.75), RacelineFollower(grip=0.8)]


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
    Scales (default track and car): own ``s`` 0..38.9 m, ``n`` within +-0.4 m, ``vx`` 0..4.2
    m/s, ``vy`` and ``omega`` mostly within +-1 m/s and +-6 rad/s, relative ``s`` a few metres,
    curvature within +-1.3 1/m. The ``Box`` bounds are the envelope, not a scale: normalise
    with running statistics (SB3's ``VecNormalize``; ``VecMonitor`` logs ``ep_rew_mean``).

    **Reward**: ``car_0``'s relative progress per step, the change of ``s_0 - max_{j>0} s_j`` [m]
    (the paper's reward, the default), minus ``offtrack_penalty`` [m] on every step the
    learner's off-track rule applies (default 0: off track then costs only the rule's
    slow-down, and a learner may learn to ride outside the edge).

    **Starting state**: as :class:`RacingParallelEnv` (``start``: ``"regions"`` by default, or
    ``"grid"``, ``"random"``, a :class:`racing_env.StartConfig`); ``reset(seed)`` draws the
    race's seed from the env's ``np_random``, opponent k is reset with that seed + k + 1.

    **Episode end**: ``terminated`` when a car completes ``laps`` (if set), or, with
    ``terminate_off_track=True`` (default False, the paper's rule), when the learner goes off
    track; ``truncated`` after ``max_cycles`` steps (default 500 = 50 s).

    **Arguments**: ``opponents``: a sequence, one per opponent car, of agent spec strings
    (``"mpc:zeta=0.9"``, built by :func:`agents.make_agent_spec`), factories (callables
    returning an agent) or agents (objects with ``reset(track, agent_id, seed)`` and
    ``act(observation) -> action``, deep-copied): every env gets opponents of its own, so the
    copies made by ``gymnasium.make_vec`` or SB3's ``make_vec_env`` never share state. Default
    two :class:`racing_env.controllers.RacelineFollower` s on the speed profiles of friction
    0.75 and 0.8. ``n_cars`` defaults to ``1 + len(opponents)``. Other keywords (``track``,
    ``max_cycles``, ``laps``, ``start``, ``vehicle``, ``rules``, ``config``, ``render_mode``)
    go to :class:`RacingParallelEnv`. ``offtrack_penalty`` (0.0, m per step off track) and
    ``terminate_off_track`` (False) apply to the learner only (opponents are not learning).
    ``reset(options=...)`` accepts ``start`` and ``order``.

    **Attributes**: ``observation_space`` and ``action_space`` (the ``Box`` es above, ``car_0``'s
    spaces of the underlying :class:`RacingParallelEnv`, ``self.race``); ``opponents`` (the
    opponent agents, in car order from ``car_1``); ``learner`` (``"car_0"``).

    **Info**: the learner's per-step info of the parallel env.

    **Version History**: as :class:`RacingParallelEnv` (v2: contact keeps the bodies apart;
    v1, contact over the whole control period, applied at the first moment of contact, and v0,
    contact only at the end of each step, are not registered any more).
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(
        self,
        opponents: Sequence | None = None,
        track: str | Track | None = None,
        render_mode: str | None = None,
        config: RaceConfig | None = None,
        start: str | StartConfig | None = None,
        offtrack_penalty: float = 0.0,
        terminate_off_track: bool = False,
        **kwargs,
    ):
        if opponents is None:
            opponents = default_opponents()
        if isinstance(opponents, str) or is_agent(opponents):
            raise ValueError(
                f"opponents must be a sequence (one per opponent car), got {opponents!r}"
            )
        self.offtrack_penalty, self.terminate_off_track = check_reward_options(
            offtrack_penalty, terminate_off_track
        )
        self.opponents = [make_opponent(o, k) for k, o in enumerate(opponents)]
        n_cars = kwargs.pop("n_cars", 1 + len(self.opponents))
        if n_cars != 1 + len(self.opponents):
            raise ValueError(
                f"n_cars = {n_cars} but {len(self.opponents)} opponents were given; "
                f"n_cars must be 1 + number of opponents"
            )
        self.race = RacingParallelEnv(
            track=track,
            n_cars=n_cars,
            render_mode=render_mode,
            config=config,
            start=start,
            **kwargs,
        )
        self.render_mode = render_mode
        self.learner = self.race.possible_agents[0]
        self.observation_space = self.race.observation_space(self.learner)
        self.action_space = self.race.action_space(self.learner)
        self._last_obs: dict[str, np.ndarray] | None = None

    def reset(
        self, *, seed: int | None = None, options: dict | None = None
    ) -> tuple[np.ndarray, dict]:
        """Start a new race against freshly reset opponents.

        Parameters
        ----------
        seed : int, optional
            Seeds the env's ``np_random``, from which the race's seed is drawn (the start
            positions; opponent k is reset with that seed + k + 1). None continues the stream.
        options : dict, optional
            ``start`` (``"regions"``, ``"grid"``, ``"random"`` or a :class:`StartConfig`, for
            this race only) and ``order`` (``order[i]``: start region of car i, 0 = R1).

        Returns
        -------
        observation : numpy.ndarray
            The learner's first observation (see ``observation_space``).
        info : dict
            The learner's info dict (as :meth:`RacingParallelEnv.reset` gives it).

        Raises
        ------
        ValueError
            On a bad option (unknown key, start mode, order, or ``n_cars``: the car count is
            fixed by the opponents). Options are checked first: after the error the env, its
            random stream included, is as it was.
        """
        options = _check_learner_reset_options(options, self.race.core.n_cars)
        checked = _check_reset_options(options, self.race.core)  # before np_random moves
        super().reset(seed=seed)
        race_seed = int(self.np_random.integers(2**31))
        obs, infos = self.race._reset_checked(race_seed, *checked)
        for k, opp in enumerate(self.opponents):
            opp.reset(self.race.track, self.race.possible_agents[k + 1], race_seed + k + 1)
        self._last_obs = obs
        return obs[self.learner], infos[self.learner]

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        """Advance by one control period (0.1 s): the learner's action, the opponents' own.

        Parameters
        ----------
        action : array_like
            ``[throttle, steering]`` in ``[-1, 1]`` (see ``action_space``; clipped).

        Returns
        -------
        observation : numpy.ndarray
            The learner's new observation.
        reward : float
            The change of ``s_0 - max_{j>0} s_j`` [m], minus ``offtrack_penalty`` when the
            learner is off track.
        terminated : bool
            ``laps`` completed by the first car, or the learner off track with
            ``terminate_off_track``.
        truncated : bool
            ``max_cycles`` steps reached.
        info : dict
            The learner's info (``contact``, ``off_track``, ``laps``, ``progress``,
            ``substeps``, ``contacts``, ``off_tracks``).

        Raises
        ------
        RuntimeError
            Before :meth:`reset`, or after the episode ended.
        ValueError
            A NaN action or one of another shape than ``(2,)``.
        """
        if self._last_obs is None:
            raise RuntimeError("step() called before reset(); call reset() first")
        actions = {self.learner: np.asarray(action, dtype=np.float32)}
        for k, opp in enumerate(self.opponents):
            agent = self.race.possible_agents[k + 1]
            actions[agent] = act_named(opp, self._last_obs[agent], agent)
        obs, rew, term, trunc, infos = self.race.step(actions)
        self._last_obs = obs
        a = self.learner
        reward, terminated, truncated = rew[a], term[a], trunc[a]
        if self.offtrack_penalty or self.terminate_off_track:
            if infos[a]["off_track"]:
                reward = reward - self.offtrack_penalty
                if self.terminate_off_track and not terminated:
                    terminated, truncated = True, False
                    self.race.agents = []
        return obs[a], reward, terminated, truncated, infos[a]

    def state(self) -> np.ndarray:
        """The global joint state: :meth:`RacingParallelEnv.state` of the race.

        Returns
        -------
        numpy.ndarray
            float32 ``(6 N,)``, every car's ``(s, n, mu, vx, vy, omega)``, ``s`` unwrapped.

        Raises
        ------
        RuntimeError
            Before the first :meth:`reset`.
        """
        return self.race.state()

    def render(self) -> np.ndarray | None:
        """Draw the race (:meth:`RacingParallelEnv.render`).

        Returns
        -------
        numpy.ndarray or None
            ``render_mode="rgb_array"``: the frame ``(H, W, 3)`` uint8; ``"human"``: None
            (shown in a window); no render mode: warns and returns None.

        Raises
        ------
        RuntimeError
            Before the first :meth:`reset`.
        """
        return self.race.render()

    def close(self) -> None:
        """Close the ``"human"`` window if one is open."""
        self.race.close()


class FullSizeEnv(HeadToHeadEnv):
    """Full-size single-seaters on a real circuit: :class:`HeadToHeadEnv` with
    ``vehicle_class="fullsize"``, registered as ``alpha_racer/FullSize-v0``.

    The cars are TUM FTM's race car (:class:`racing_env.vehicles.fullsize.FullSizeParams`:
    1200 kg, 230 kW, downforce, load-dependent tyres, top speed 66.4 m/s in clean air) on
    Monza at full scale (5.79 km, 7.5-12.4 m wide) by default, with the wake on (strength 1:
    a car behind another has less drag, up to +15% top speed at one length, and less
    downforce, so less grip in corners; :mod:`racing_env.wake`). The rules, the start regions
    and the curvature preview are the paper's scaled to the car's size
    (:func:`racing_env.scaling.scaled_configs`): contact box 4.7 m x 2.0 m, walls 5 m beyond
    the edges, start regions 15.7 m long and 23.5 m apart from ``s0`` = 117.5 m, preview
    every 9.8 m.

    **Action space**: ``Box(-1, 1, (2,), float32)``, ``[throttle, steering]``: throttle +1 full
    power (power-limited drive, 7 kN cap), -1 full brake (20 kN, 60% front), steering onto
    +-0.35 rad.

    **Observation space**: ``car_0``'s observation, ``Box`` float32 of ``6 N + n_preview``, the
    layout of :class:`racing_env.RacingParallelEnv` in SI units at full scale: own ``s`` in
    [0, 5791) m, ``n`` within the walls (+-11.3 m at Monza), ``mu``, ``vx`` 0..91 m/s (bound
    137 m/s: 1.5 x the top speed in the strongest tow + 1), ``vy``, ``omega`` (+-100 rad/s),
    the other cars relative to it (``s`` clipped at +-3.9e5 m), curvature within +-0.1 1/m.
    Normalise with running statistics, not with the bounds.

    **Reward**, **starting state**, **episode end** (truncated after ``max_cycles`` = 500
    steps, 50 s: about half a lap of Monza; pass ``max_cycles`` and ``max_episode_steps`` to
    race longer, or ``laps``) and **info** (with ``drag_factor`` and ``downforce_factor``, the
    learner's wake factors of the step): as :class:`HeadToHeadEnv`.

    **Arguments**: those of :class:`HeadToHeadEnv` (``opponents``, default two raceline
    followers on the class's racing line; ``track``, default ``"tumftm:Monza"``, any name is
    built at full scale: ``"tumftm:NAME"``, ``"random:SEED"``, a CSV path; ``config``,
    ``n_cars``, ``max_cycles``, ``laps``, ``start``, ``vehicle`` (a ``FullSizeParams``),
    ``rules``, ``render_mode``, ``offtrack_penalty``, ``terminate_off_track``) and ``wake``
    (strength, default 1; 0 turns the wake off). A track, vehicle or config of the ORCA class
    is a ``ValueError``.

    **Version History**: v0, initial version (the world of ``HeadToHead-v2`` at full size).
    """

    def __init__(
        self,
        opponents: Sequence | None = None,
        track: str | Track | None = "tumftm:Monza",
        render_mode: str | None = None,
        config: RaceConfig | None = None,
        start: str | StartConfig | None = None,
        offtrack_penalty: float = 0.0,
        terminate_off_track: bool = False,
        **kwargs,
    ):
        kwargs.setdefault("vehicle_class", "fullsize")
        super().__init__(
            opponents,
            track,
            render_mode,
            config,
            start,
            offtrack_penalty,
            terminate_off_track,
            **kwargs,
        )
