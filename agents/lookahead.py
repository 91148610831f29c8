"""The look-ahead agent: an MPC that chooses its theta by simulating its candidates from the
state it observes, the other cars driven by a model of them (issue 48, "a look-ahead of its
own").

The room's oracle (:mod:`experiments.evaluation.oracle`) copies the race and the other cars'
own agents. This agent has neither: its observation holds every car's state (its own
``s, n, mu, vx, vy, omega`` and the others' relative to it, :func:`racing_env.simulator.observe`;
the wake and the contact rule follow from the positions), and it assumes how the others
drive. Every ``every`` control periods it puts the cars in a world of its own (an env of the
track's class) where they stand, drives each candidate theta there for ``horizon`` seconds
against MPC cars of its model, and keeps the candidate with the best relative progress (its
progress minus the best other car's) until the next choice. Its models of the others act on
their observations at every period, their actions unused, so that they are warm where the
others' agents are.

Cost: ``M`` candidates times ``horizon / dt`` periods of every car at every choice, on top of
the race: the oracle's, at the same settings.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from racing_env.observation import cars_in_observation, split_observation
from racing_env.parallel_env import RacingParallelEnv, relative_progress
from racing_env.track import Track

from .base import median_p99, register_agent
from .mpc_agent import MPCAgent, copy_sharing_lines
from .reference import WAKE_NAMES
from .theta import Theta, check_moves, moved_thetas

__all__ = ["LookaheadAgent", "MODELS", "world_state"]

#: How the agent models the other cars: MPC cars of its own base theta (``"self"``: it
#: assumes they drive as it does) or of the track's best fixed theta (``"best"``: the published
#: control of the track and class, ``alpha-racer control``).
MODELS = ("self", "best")


def world_state(observation: np.ndarray, n_preview: int, car: int) -> np.ndarray:
    """Every car's state (N, 6) ``(s, n, mu, vx, vy, omega)`` from car ``car``'s observation
    (``6 N + n_preview``, :func:`racing_env.observation.split_observation`): its own row as
    observed (``s`` on its lap), the others' on unwrapped progress from it, in car order."""
    ego, others = split_observation(observation, n_preview)
    if not 0 <= car <= len(others):
        raise ValueError(
            f"car must be an index of the {len(others) + 1} cars observed, got {car!r}"
        )
    return np.insert(others, car, ego, axis=0)


@register_agent("lookahead")
class LookaheadAgent(MPCAgent):
    """An MPC choosing its theta every ``every`` periods by a look-ahead of its own (module
    docstring). The theta keywords, ``theta="best"`` and the other MPC settings are the base's,
    as for :class:`~agents.mpc_agent.MPCAgent`; the candidates are the base and its first
    ``moves`` one-parameter moves (:data:`agents.theta.MOVES`), a move that leaves the driven
    theta unchanged left out. ``horizon`` [s]: how long each candidate is simulated;
    ``model`` (:data:`MODELS`): how the others are assumed to drive; ``wake``: the wake
    strength of the world it simulates (default: the class's, as the env's). ``stats`` adds
    ``candidate_share`` and the choices' time (``choice_ms_median``, ``choice_ms_p99``)."""

    param_notes = {
        **MPCAgent.param_notes,
        "model": "the others in its look-ahead: MPC cars of its own base theta ('self') or of "
        "the track's best fixed theta ('best')",
    }

    def __init__(
        self,
        moves: int = 8,
        horizon: float = 6.0,
        every: int = 10,
        model: str = "self",
        wake: float | None = None,
        **mpc: Any,
    ):
        super().__init__(**mpc)
        self.moves = check_moves(moves)
        if isinstance(horizon, bool) or not (
            isinstance(horizon, (int, float)) and 0 < horizon <= 60
        ):
            raise ValueError(f"horizon must be a time in (0, 60] s, got {horizon!r}")
        self.horizon = float(horizon)
        if isinstance(every, bool) or not (isinstance(every, int) and every >= 1):
            raise ValueError(f"every must be a positive number of periods, got {every!r}")
        self.every = every
        if model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {model!r}")
        self.model = model
        if wake is not None and not (np.isfinite(wake) and wake >= 0):
            raise ValueError(f"wake must be a non-negative strength, got {wake!r}")
        self.wake = wake
        self._settings = dict(mpc)  # the base's MPC settings, for the models of the others
        self.thetas: list[Theta] = []
        self._world: Any = None  # the env it simulates in, built at the first decision
        self._others: list[MPCAgent] = []
        self._copy = False  # a copy driving a look-ahead: a plain MPC
        self._periods = 0
        self._counts = np.zeros(0, dtype=np.int64)
        self._choice_ms: list[float] = []

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        super().reset(track, agent_id, seed)
        base = self.theta
        self.thetas = []
        for theta in moved_thetas(base, self.moves):
            if all(self.capped(theta) != self.capped(t) for t in self.thetas):
                self.thetas.append(theta)
        self.theta = base
        self._seed = seed
        self._world = None
        self._others = []
        self._periods = 0
        self._counts = np.zeros(len(self.thetas), dtype=np.int64)
        self._choice_ms = []

    def _build_world(self, n_cars: int) -> None:
        """The env it simulates in and the models of the other cars, reset on its track."""
        assert self.track is not None  # reset() sets it
        self._world = RacingParallelEnv(
            track=self.track,
            n_cars=n_cars,
            max_cycles=2**62,
            vehicle_class=self.track.vehicle_class,
            wake=self.wake,
        )
        self._world.reset(seed=0)
        self._me = self._world.possible_agents.index(self.agent_id)
        self._other_ids = [a for a in self._world.possible_agents if a != self.agent_id]
        self._n_ahead = max(1, int(round(self.horizon / self._world.config.dt)))
        settings: dict[str, Any] = dict(self._settings)
        if self.model == "best":
            for name in (*WAKE_NAMES, "zeta_max"):
                settings.pop(name, None)
            settings["theta"] = "best"
        else:  # its own base theta, without its own ceiling
            settings.pop("zeta_max", None)
        self._others = []
        for k, aid in enumerate(self._world.possible_agents):
            if aid in self._other_ids:
                other = MPCAgent(**settings)
                other.reset(self.track, aid, None if self._seed is None else self._seed + k)
                self._others.append(other)

    def _observe_world(self, observation: np.ndarray) -> dict:
        """Put its world's cars where the observation says; every car's observation there.
        (The world itself never steps, its copies do: its clock and live agents stay as reset.)"""
        core = self._world.core
        core.state[0] = world_state(observation, self.n_preview, self._me)
        core.s_line[0] = core.state[0, :, 0].max()
        obs = core.observe()[0]
        return {aid: obs[k] for k, aid in enumerate(self._world.possible_agents)}

    def _before_solve(self, observation: np.ndarray) -> None:
        if self._copy:
            return
        if self._world is None:
            self._build_world(cars_in_observation(len(observation), self.n_preview))
        seen = self._observe_world(observation)
        if self._periods % self.every == 0 and len(self.thetas) > 1:
            t0 = time.perf_counter()
            scores = [self._rollout(seen, theta) for theta in self.thetas]
            best = int(np.argmax(scores))  # the first of equals: the base on a tie
            self.theta = self.thetas[best]
            self._counts[best] += 1
            self._choice_ms.append(1e3 * (time.perf_counter() - t0))
        for other, aid in zip(self._others, self._other_ids):
            other.act(seen[aid])  # kept warm on the race; its action is not driven
        self._periods += 1

    def _rollout(self, seen: dict, theta: Theta) -> float:
        """Its relative progress [m] after ``horizon`` seconds of its world from the observed
        state, itself driving ``theta``, the others its models of them."""
        world, others = self._world, self._others
        self._world, self._others = None, []  # not copied into its own driver
        try:
            me, world2, others2, obs = copy_sharing_lines(
                (self, world, others, seen), [self, *others]
            )
        finally:
            self._world, self._others = world, others
        me._copy, me.theta = True, theta
        drivers = list(others2)
        drivers.insert(self._me, me)
        for _ in range(self._n_ahead):
            actions = {aid: d.act(obs[aid]) for d, aid in zip(drivers, world2.possible_agents)}
            obs = world2.step(actions)[0]
        return relative_progress(world2, self._me)

    @property
    def stats(self) -> dict:
        total = max(1, int(self._counts.sum()))
        out = {**super().stats, "candidate_share": [round(c / total, 4) for c in self._counts]}
        if self._choice_ms:
            out["choice_ms_median"], out["choice_ms_p99"] = median_p99(self._choice_ms)
        return out
