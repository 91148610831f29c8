"""Many races at once: :func:`run_races` races :class:`RaceSpec` s in lockstep batches
(:func:`experiments.infra.lockstep.run_lockstep`), each race bit for bit the race
:func:`~experiments.evaluation.race.run_race` runs alone: the same env, seed, start order and
agents, reset as :func:`~experiments.evaluation.race.start_race` resets them. What the bulk
commands (``bench``, ``strategy``, ``policy-map``, ``league``, ...) hand a pool task."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from agents import check_field_size, make_agent_spec
from experiments.evaluation.race import agent_seed
from experiments.infra.lockstep import LockstepRace, LockstepResult, race_setup, run_lockstep
from racing_env.config import RaceConfig


@dataclass(frozen=True)
class RaceSpec:
    """One race as :func:`~experiments.evaluation.race.run_race` takes it: agent specs (one per
    car), seed, start order (``order[i]`` car i's start region, None: drawn from the seed) and
    the env's settings."""

    agents: tuple[str, ...]
    seed: int
    order: tuple[int, ...] | None = None
    track: str = "default"
    max_cycles: int = 500
    start: str = "regions"
    vehicle_class: str | None = None
    wake: float | None = None

    def env_kwargs(self) -> dict:
        return dict(
            track=self.track,
            n_cars=len(self.agents),
            max_cycles=self.max_cycles,
            start=self.start,
            vehicle_class=self.vehicle_class,
            wake=self.wake,
        )


@dataclass
class RaceOutcome:
    """A race of :func:`run_races`: its lockstep result, its agents (after the race, with
    their ``stats``) and its env's config (``dt``, the contact box)."""

    result: LockstepResult
    agents: list[Any]
    config: RaceConfig


def run_races(specs: Sequence[RaceSpec]) -> list[RaceOutcome]:
    """Race ``specs``, one lockstep batch per group of races with the same env settings (track,
    field, steps, start, class, wake), and return their outcomes in order. Errors: an agent
    that cannot race the field (``check_field_size``) before anything runs; an agent's error
    names its car and its race in the batch."""
    out: list[RaceOutcome | None] = [None] * len(specs)
    groups: dict[tuple, list[int]] = {}
    for i, spec in enumerate(specs):
        groups.setdefault(tuple(sorted(spec.env_kwargs().items())), []).append(i)
    for rows in groups.values():
        track, config = race_setup(**specs[rows[0]].env_kwargs())
        races = []
        for i in rows:
            spec = specs[i]
            agents = [make_agent_spec(s) for s in spec.agents]
            for k, (agent, name) in enumerate(zip(agents, spec.agents)):
                check_field_size(agent, len(agents), f"car_{k}", name)
                agent.reset(track, f"car_{k}", agent_seed(spec.seed, k))
            order = None if spec.order is None else list(spec.order)
            races.append(LockstepRace(agents, track, config, spec.seed, order))
        for i, race, result in zip(rows, races, run_lockstep(races)):
            out[i] = RaceOutcome(result, list(race.agents), config)
    return out  # type: ignore[return-value]
