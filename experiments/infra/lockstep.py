"""Races in lockstep: ``R`` races of ``N`` cars advanced together through one batched core.

A race run alone (:func:`experiments.potential.collect.simulate_race`,
:func:`experiments.evaluation.race.run_race`) steps its own
:class:`~racing_env.RacingParallelEnv`, one race and one kernel call per control period.
:func:`run_lockstep` runs ``R`` such races at once: per control period it takes every car's
observation of every live race from one :class:`~racing_env.BatchedRaces` core (the env's own
observation code: :meth:`BatchedRaces.observe`, whose row ``(b, i)`` is what the env hands car
``i``), asks the agents for their actions (:func:`decide`) and advances every race in one core
call.

**The same races.** Races are independent in the core's kernel (each is advanced by the same
compiled per-race step, :func:`racing_env.simulator._step_one_race`), every race is reset from
its own seed and order exactly as :meth:`RacingParallelEnv.reset` resets its race, and every car
has its own agent. So a race in a batch is bit for bit the race run alone, whatever the batch
size and its place in it (``tests/test_lockstep.py`` holds it: states and rewards
``np.array_equal``, ORCA and full size). Batches of :data:`racing_env.core.PARALLEL_MIN_RACES`
races or more are stepped by the multi-threaded kernel (same per-race code, one race per thread).

**Decisions.** :func:`decide` is the hook for batched decisions. Agents of a class with
``act_group(agents, observations (M, D)) -> (M, 2)`` (a group of one kind, each instance with
its own state: :meth:`agents.mpc_agent.MPCAgent.act_group`, whose MPC steps of all cars of all
races are solved in one compiled call, and the alpha agent's, which chooses each car's theta
first) and one instance with ``act_batch(observations (M, D)) -> (M, 2)`` in several slots (a
stateless policy such as :class:`agents.ppo_agent.PPOAgent`) are asked once per period for
all their cars of all races, rows in race-major order (:func:`live_slots`). Every other agent
decides car by car (``act(observation (D,)) -> (2,)``, the fallback every agent supports).
The bit-for-bit promise holds because a row's action is what ``act`` gives it alone
(``tests/test_compiled_solve.py`` for the MPC on one and two threads);
``batch_decisions=False`` asks every car alone. Mixed races (agents of any kinds, batched or
not) work.

**Ends.** A race ends at its own step, as the env's: truncated at ``max_cycles`` (shared by the
batch, the config being the same) or terminated when a car completes ``laps``. An ended race is
no longer decided nor recorded, while the others continue; the one core call still advances it
(with zero actions: the kernel steps every race of the batch, at a cost per race far below a
decision), and what it does after its end is not part of its result. The runner ends when every
race has ended.

The env's reward options (``offtrack_penalty``, ``terminate_off_track``) are not part of a race
config; lockstep races have the paper's reward and episode end.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from racing_env import BatchedRaces, RacingParallelEnv
from racing_env.agent_protocol import act_named
from racing_env.config import RaceConfig
from racing_env.track import Track


def race_setup(**env_kwargs) -> tuple[Track, RaceConfig]:
    """``(track, config)`` of the race a :class:`~racing_env.RacingParallelEnv` built with
    ``env_kwargs`` runs (``track``, ``n_cars``, ``max_cycles``, ``laps``, ``start``,
    ``vehicle``, ``rules``, ``config``, ``vehicle_class``, ``wake``): the env's own config, so a
    lockstep race is the env's race. Agents are reset on this ``track`` before
    :func:`run_lockstep`."""
    env = RacingParallelEnv(**env_kwargs)
    return env.track, env.config


@dataclass
class LockstepRace:
    """One race of a lockstep batch.

    ``agents``: one agent per car in car order, already reset (``reset(track, agent_id,
    seed)``) on ``track``. ``seed``: the seed of its start (as ``RacingParallelEnv.reset(seed)``;
    None draws from the batch's generator, not reproducible alone). ``order``: ``order[i]`` is
    car i's start region (0 = R1, the front-most; ``"regions"`` starts), None to draw it from
    ``seed``. ``track`` and ``config``: the race's, from :func:`race_setup`; every race of a
    batch must have the same (``ValueError`` naming the first difference otherwise).
    """

    agents: Sequence[Any]
    track: Track
    config: RaceConfig
    seed: int | None = None
    order: Sequence[int] | None = None


@dataclass
class LockstepResult:
    """What one race produced (T steps, the race's own; N cars).

    ``states`` (T + 1, N, 6) float64: every car's ``(s, n, mu, vx, vy, omega)`` after each step
    (row 0 the start; s unwrapped [m]). ``rewards`` (T, N) float64: the env's reward per step
    [m]. ``start_order`` (N,) int64 or None: the order given. ``fallbacks`` (N,) int32: MPC
    fallbacks during the race (0 for an agent without ``stats["fallbacks"]``). ``thetas``
    (N, dim) float64 or None: each car's ``theta.as_array(space)`` at the start when every agent
    has one. ``lap_times`` per car [s], ``contacts`` and ``off_tracks`` (N,) step counts,
    ``terminated``: a car completed ``laps`` (else truncated at ``max_cycles``).
    ``decision_ms`` (N,): each car's mean decision time per step [ms] (a batched decision's
    time shared equally by its cars).
    """

    states: np.ndarray
    rewards: np.ndarray
    start_order: np.ndarray | None
    fallbacks: np.ndarray
    thetas: np.ndarray | None
    lap_times: list[list[float]]
    contacts: np.ndarray
    off_tracks: np.ndarray
    terminated: bool
    decision_ms: np.ndarray

    @property
    def progress(self) -> np.ndarray:
        """(N,) each car's progress at the end [m] past the start line, the front-most car's
        start (``RaceResult.progress`` of the race run alone)."""
        return self.states[-1, :, 0] - self.states[0, :, 0].max()

    @property
    def steps(self) -> int:
        return len(self.rewards)


def check_same_race(races: Sequence[LockstepRace]) -> None:
    """``ValueError`` naming the first race whose track or config (field by field) differs from
    race 0's, or whose agent count is not its ``n_cars``; a batch shares one core."""
    if not races:
        raise ValueError("a lockstep batch needs at least one race")
    track, cfg = races[0].track, races[0].config
    for b, race in enumerate(races):
        if race.track is not track and (race.track.name, race.track.length) != (
            track.name,
            track.length,
        ):
            raise ValueError(
                f"race {b} is on track {race.track.name!r} ({race.track.length:.2f} m) but race 0 "
                f"on {track.name!r} ({track.length:.2f} m); a lockstep batch races one track"
            )
        if race.config != cfg:
            diff = [
                f"{f.name}={getattr(race.config, f.name)!r} (race 0: {getattr(cfg, f.name)!r})"
                for f in fields(RaceConfig)
                if getattr(race.config, f.name) != getattr(cfg, f.name)
            ]
            raise ValueError(
                f"race {b}'s config differs from race 0's in {'; '.join(diff)}; a lockstep "
                f"batch races one config"
            )
        if len(race.agents) != cfg.n_cars:
            raise ValueError(
                f"race {b} has {len(race.agents)} agents for {cfg.n_cars} cars; one agent per car"
            )


def live_slots(live: np.ndarray, n_cars: int) -> np.ndarray:
    """``(M, 2)`` int64 ``(race, car)`` of every car of the live races (``live`` (R,) bool), in
    race-major order: the row order of the observations an ``act_batch`` gets."""
    races = np.flatnonzero(live)
    return np.stack(
        [np.repeat(races, n_cars), np.tile(np.arange(n_cars), len(races))], axis=1
    ).astype(np.int64)


def decide(
    agents: Sequence[Sequence[Any]],
    obs: np.ndarray,
    live: np.ndarray,
    actions: np.ndarray,
    batch_decisions: bool = True,
    clock: np.ndarray | None = None,
) -> None:
    """The hook for batched decisions: every live car's action into ``actions`` (R, N, 2).

    ``agents[b][i]`` drives car i of race b; ``obs`` (R, N, D) float32 are the core's
    observations, ``live`` (R,) bool the races still running. With ``batch_decisions``, two
    kinds of agents decide once per period for all their live cars of all races, observations
    stacked (M, D) in race-major order (:func:`live_slots`), actions (M, 2) back:

    * a group of agents of one kind: agents whose class has ``act_group(agents, observations)``
      (a classmethod or staticmethod; ``agents`` the M instances, one per row, each with its
      own state) are decided in one call per class: the form for a kind of agent whose
      decisions of many cars can be computed together (MPC steps in one compiled call);
    * one agent instance with ``act_batch(observations)`` in several slots (a stateless
      policy: :class:`agents.ppo_agent.PPOAgent`) is called once for its slots.

    Every other agent decides car by car (``act(observation (D,)) -> (2,)``: the fallback, which
    every agent supports). An agent's error names it, its car and its race. ``clock`` (R, N),
    if given, gains each car's decision seconds (a batched call's time shared equally by its
    rows).
    """
    n_cars = obs.shape[1]
    groups: dict[tuple[str, int], tuple[Any, list[tuple[int, int]]]] = {}
    for b, i in live_slots(live, n_cars).tolist():
        agent = agents[b][i]
        if batch_decisions and callable(getattr(type(agent), "act_group", None)):
            groups.setdefault(("group", id(type(agent))), (type(agent), []))[1].append((b, i))
        elif batch_decisions and callable(getattr(agent, "act_batch", None)):
            groups.setdefault(("batch", id(agent)), (agent, []))[1].append((b, i))
        else:
            t0 = time.perf_counter()
            actions[b, i] = act_named(agent, obs[b, i], f"car_{i} of race {b}")
            if clock is not None:
                clock[b, i] += time.perf_counter() - t0
    for (kind, _), (owner, slots) in groups.items():  # batched decisions: one call per group
        t0 = time.perf_counter()
        rows = np.array(slots, dtype=np.int64)
        x = obs[rows[:, 0], rows[:, 1]]
        if kind == "batch":
            b0, i0 = slots[0]
            actions[rows[:, 0], rows[:, 1]] = act_named(
                owner, x, f"car_{i0} of race {b0}", batch=True
            )
        else:
            actions[rows[:, 0], rows[:, 1]] = owner.act_group([agents[b][i] for b, i in slots], x)
        if clock is not None:
            clock[rows[:, 0], rows[:, 1]] += (time.perf_counter() - t0) / len(slots)


def _fallbacks(agent: Any) -> int:
    stats = getattr(agent, "stats", None)
    return int(stats.get("fallbacks", 0)) if isinstance(stats, dict) else 0


def _thetas(agents: Sequence[Any]) -> np.ndarray | None:
    try:
        return np.array([a.theta.as_array(a.space) for a in agents], dtype=np.float64)
    except (AttributeError, ValueError):
        return None


def run_lockstep(
    races: Sequence[LockstepRace],
    batch_decisions: bool = True,
    timing: dict[str, float] | None = None,
) -> list[LockstepResult]:
    """Run ``races`` (R, each :class:`LockstepRace`, same track and config) in lockstep through
    one :class:`~racing_env.BatchedRaces` core; returns one :class:`LockstepResult` per race, in
    order, bit for bit what the race gives run alone in a :class:`~racing_env.RacingParallelEnv`
    (see the module docstring; ``batch_decisions`` as :func:`decide`).

    ``timing``: if given (a dict), seconds are added to its keys ``"act"`` (decisions), ``"step"`` (the
    core's step and observations) and ``"total"`` (the whole call; glue is the rest).
    Errors: ``ValueError`` for a batch of mixed tracks or configs or a bad start order (before
    anything runs); an agent's error names its car and race.
    """
    t_start = time.perf_counter()
    check_same_race(races)
    cfg, n, r = races[0].config, races[0].config.n_cars, len(races)
    core = BatchedRaces(races[0].track, cfg, n_races=r)
    for b, race in enumerate(races):  # each as RacingParallelEnv.reset(seed, {"order": ...})
        order = None if race.order is None else [int(o) for o in race.order]
        core.reset(seed=race.seed, races=[b], order=order)
    agents = [list(race.agents) for race in races]
    fallbacks0 = np.array([[_fallbacks(a) for a in row] for row in agents])
    thetas = [_thetas(row) for row in agents]
    steps = cfg.max_cycles
    states = np.empty((r, steps + 1, n, 6))
    rewards = np.empty((r, steps, n))
    states[:, 0] = core.state
    ended = np.zeros(r, dtype=np.int64)  # steps run by each race, set at its end
    terminated = np.zeros(r, dtype=bool)
    live = np.ones(r, dtype=bool)
    actions = np.zeros((r, n, 2))
    clock = np.zeros((r, n))  # decision seconds per car
    ends: dict[int, tuple] = {}  # per ended race: lap times, contacts, off-tracks
    obs = core.observe()
    t_act = t_step = 0.0
    t = 0
    while live.any():
        t0 = time.perf_counter()
        actions[~live] = 0.0
        decide(agents, obs, live, actions, batch_decisions, clock)
        t1 = time.perf_counter()
        obs, rew, term, trunc = core.step(actions)
        t2 = time.perf_counter()
        t_act += t1 - t0
        t_step += t2 - t1
        rewards[live, t] = rew[live]
        t += 1
        states[live, t] = core.state[live]
        for b in np.flatnonzero(live & (term | trunc)).tolist():
            ended[b], terminated[b], live[b] = t, term[b], False
            fallbacks0[b] = [_fallbacks(a) - f0 for a, f0 in zip(agents[b], fallbacks0[b])]
            ends[b] = (
                [list(x) for x in core.lap_times[b]],
                core.contacts[b].copy(),
                core.offtracks[b].copy(),
            )
    results = []
    for b in range(r):
        lap_times, contacts, off_tracks = ends[b]
        k = int(ended[b])
        given = races[b].order
        results.append(
            LockstepResult(
                states=states[b, : k + 1].copy(),
                rewards=rewards[b, :k].copy(),
                start_order=None if given is None else np.asarray(given, dtype=np.int64),
                fallbacks=fallbacks0[b].astype(np.int32),
                thetas=thetas[b],
                lap_times=lap_times,
                contacts=contacts,
                off_tracks=off_tracks,
                terminated=bool(terminated[b]),
                decision_ms=1e3 * clock[b] / max(k, 1),
            )
        )
    if timing is not None:
        for key, seconds in (
            ("act", t_act),
            ("step", t_step),
            ("total", time.perf_counter() - t_start),
        ):
            timing[key] = timing.get(key, 0.0) + seconds
    return results
