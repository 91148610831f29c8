"""What a league races: the :class:`LeagueConfig` and the schedule (deterministic from the
config; :mod:`experiments.evaluation.league` describes it), whole rounds of balanced groups
from rotated start regions, numbered on when agents join."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np

from experiments.infra.artifacts import (
    check_track_specs,
)
from experiments.infra.checks import check_counts


@dataclass(frozen=True)
class LeagueConfig:
    """One league: ``agents`` (distinct agent specs, each one player of the rating) race in
    groups of ``cars`` on each of ``tracks`` for ``steps`` control periods of 0.1 s; the
    schedule (module docstring) repeats ``rounds`` times. ``max_groups`` caps the groups per
    round (above it the groups are a balanced sample); ``seed`` fixes the sample, the start
    positions and the agents' seeds."""

    agents: tuple[str, ...]
    tracks: tuple[str, ...] = ("default",)
    cars: int = 3
    rounds: int = 1
    steps: int = 500
    seed: int = 0
    max_groups: int = 60

    def __post_init__(self):
        from racing_env.config import MAX_CARS

        object.__setattr__(self, "agents", tuple(self.agents))
        object.__setattr__(self, "tracks", tuple(self.tracks))
        check_counts(self, ("rounds", "steps", "max_groups"))
        check_counts(self, ("seed",), minimum=0)
        if not (isinstance(self.cars, int) and 2 <= self.cars <= MAX_CARS):
            raise ValueError(
                f"cars per race must be an integer in 2..{MAX_CARS}, got {self.cars!r}"
            )
        if not all(isinstance(a, str) and a for a in self.agents):
            raise ValueError(f"agents must be agent spec strings, got {list(self.agents)}")
        twice = sorted({a for a in self.agents if self.agents.count(a) > 1})
        if twice:
            raise ValueError(
                f"agent specs must be distinct (each is one player of the rating); "
                f"given more than once: {', '.join(twice)}"
            )
        if len(self.agents) < self.cars:
            raise ValueError(
                f"{self.cars} cars per race need at least {self.cars} agent specs, "
                f"got {len(self.agents)}: {', '.join(self.agents) or 'none'}"
            )
        check_track_specs(self.tracks)

    def race_seed(self, k: int) -> int:
        """Seed of race k: its start positions and (through ``run_race``) its agents."""
        return int(np.random.SeedSequence([self.seed, k]).generate_state(1)[0])


@dataclass(frozen=True)
class ScheduledRace:
    """Race ``index`` of a league: ``agents`` (specs, car order), each car's start region
    ``order[i]`` (0 = R1), on ``track``, in ``round`` and start ``rotation``, with ``seed``."""

    index: int
    round: int
    rotation: int
    track: str
    agents: tuple[str, ...]
    order: tuple[int, ...]
    seed: int


def balanced_groups(
    n_agents: int, cars: int, max_groups: int, rng: np.random.Generator
) -> list[tuple[int, ...]]:
    """Groups of ``cars`` distinct agent indices (sorted tuples) in which every agent of
    ``range(n_agents)`` appears equally often.

    One block: a random permutation of the agents repeated ``L = cars / gcd(n_agents, cars)``
    times and cut into ``lcm(n_agents, cars) / cars`` consecutive windows of ``cars``; each
    agent is in ``L`` windows, and a window of ``cars <= n_agents`` consecutive places of a
    cyclic permutation never repeats an agent. As many blocks (each of a fresh permutation)
    as fit in ``max_groups``, at least one.
    """
    if not 1 <= cars <= n_agents:
        raise ValueError(f"groups of {cars} need 1 <= cars <= agents ({n_agents})")
    block = math.lcm(n_agents, cars) // cars
    groups = []
    for _ in range(max(1, max_groups // block)):
        ring = np.tile(rng.permutation(n_agents), cars // math.gcd(n_agents, cars))
        groups += [tuple(sorted(int(a) for a in w)) for w in ring.reshape(block, cars)]
    return groups


def round_groups(config: LeagueConfig, rnd: int) -> list[tuple[int, ...]]:
    """The groups (sorted tuples of indices into ``config.agents``) of round ``rnd``: every
    subset when there are at most ``max_groups``, else :func:`balanced_groups` drawn from
    ``(seed, rnd)``."""
    k, n = len(config.agents), config.cars
    if math.comb(k, n) <= config.max_groups:
        return list(itertools.combinations(range(k), n))
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, rnd, 1]))
    return balanced_groups(k, n, config.max_groups, rng)


def schedule(config: LeagueConfig, stages=None) -> list[ScheduledRace]:
    """Every race of the league, in schedule order (the module docstring); pure.

    ``stages``: the numbers of agents the league had as agents joined it (``[3, 4]``: three
    agents raced first, the fourth joined later; default one stage of all agents). The races
    of the first stage are those of a league of its agents alone, unchanged by later joins;
    each later stage adds only the groups that hold at least one of its new agents (every
    such group while there are at most ``max_groups``, else a sample of ``max_groups`` drawn
    from the seed), with the same rounds, rotations and tracks, numbered on from the races
    before them."""
    stages = [len(config.agents)] if stages is None else list(stages)
    if (
        stages[-1] != len(config.agents)
        or any(b <= a for a, b in zip(stages, stages[1:]))
        or stages[0] < config.cars
    ):
        raise ValueError(
            f"league stages must grow from at least {config.cars} to "
            f"{len(config.agents)} agents, got {stages}"
        )
    races = []
    n = config.cars
    first = replace(config, agents=config.agents[: stages[0]])
    for rnd in range(config.rounds):
        _add_round(races, config, rnd, round_groups(first, rnd), (config.seed, rnd, 2))
    for before, now in zip(stages, stages[1:]):
        for rnd in range(config.rounds):
            groups = [g for g in itertools.combinations(range(now), n) if g[-1] >= before]
            if len(groups) > config.max_groups:
                rng = np.random.default_rng(np.random.SeedSequence([config.seed, rnd, 3, before]))
                groups = [
                    groups[i]
                    for i in sorted(rng.choice(len(groups), config.max_groups, replace=False))
                ]
            _add_round(races, config, rnd, groups, (config.seed, rnd, 2, before))
    return races


def _add_round(races: list, config: LeagueConfig, rnd: int, groups, shuffle_key) -> None:
    """Append round ``rnd`` of ``groups`` (every rotation on every track, shuffled by
    ``shuffle_key``) to ``races``, numbered on."""
    n = config.cars
    slots = [(rot, track, g) for rot in range(n) for track in config.tracks for g in groups]
    shuffle = np.random.default_rng(np.random.SeedSequence(list(shuffle_key)))
    for i in shuffle.permutation(len(slots)):
        rot, track, g = slots[i]
        k = len(races)
        races.append(
            ScheduledRace(
                index=k,
                round=rnd,
                rotation=rot,
                track=track,
                agents=tuple(config.agents[a] for a in g),
                order=tuple((j + rot) % n for j in range(n)),
                seed=config.race_seed(k),
            )
        )
