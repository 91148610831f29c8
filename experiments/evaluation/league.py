"""Round-robin league of any set of agents, rated with openskill: ``alpha-racer league``.

**Schedule** (:func:`schedule`, deterministic from the config). A *group* is a set of
``cars`` distinct agents that race each other. With ``C(k, cars)`` (k agents) at most
``max_groups``, the groups are every ``cars``-subset of the agents, the same in every round.
Otherwise each round draws its own balanced sample (:func:`balanced_groups`): whole blocks of
a random cyclic arrangement of the agents cut into windows of ``cars``, so every agent is in
the same number of groups (pairs meet about equally often, not exactly). Every group races on
every track ``cars`` times, the start regions rotated: in rotation r car j (the group's j-th
agent) starts from region ``(j + r) mod cars`` (0 = R1, the front one), so each agent starts
from each region once per group, track and round. Races are numbered round by round, the
races of a round in a seeded random order (the online rating weighs races unequally, so no
agent, region or track may come systematically first); race k's start positions and agents'
seeds come from ``(seed, k)``. The schedule repeats ``rounds`` times with new seeds.

**Result and rating.** A race is decided by total progress (unwrapped s), as in
``alpha-racer bench``: rank 1 is the most progress, exact ties go to the lower car index.
The finishing orders are rated with openskill's Plackett-Luce model (:func:`rate`), every
agent a team of one, the races replayed in schedule order, so the ratings depend neither on
the worker count nor on the order in which races finished. The model's dynamics ``tau`` is 0:
the agents do not learn between races, so their skill is a constant to estimate, not a drift
to follow. The leaderboard is sorted by the conservative ordinal ``mu - 3 sigma``.

Output directory:

* ``manifest.json``: schema version and the :class:`LeagueConfig`; a directory of another
  config is refused.
* ``races.jsonl``: one JSON line per finished race (written by the driver as the race
  arrives, flushed and fsynced; a killed run resumes with the missing races, and a torn last
  line is dropped).
* ``leaderboard.json``, ``leaderboard.md``: :func:`leaderboard` (ratings, wins with Wilson
  95% intervals, mean finish, progress, off-track steps, decision time, the strategy metrics
  of :mod:`experiments.evaluation.metrics` (passes, passes through contact, wins from behind, time
  within 1 m behind); the pairwise matrix). A league stores no states: records written
  before the strategy metrics existed lack them, and the leaderboard says so.
* ``ratings.png`` (:func:`plot_ratings`) and ``pairwise.png`` (:func:`plot_pairwise`).
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.evaluation import metrics as race_metrics
from experiments.evaluation.bench_config import check_agent_specs
from experiments.evaluation.leaderboard import (
    leaderboard,
    leaderboard_markdown,
    plot_pairwise,
    plot_ratings,
)
from experiments.evaluation.league_schedule import LeagueConfig, ScheduledRace, schedule
from experiments.infra.artifacts import (
    ResumableRun,
    as_stored,
    env_version,
    write_json,
    write_text,
)
from experiments.infra.parallel import Pool

SCHEMA_VERSION = 1
TIMING_KEYS = ("decision_ms", "seconds")
"""Record fields that are wall-clock measurements (they differ between identical reruns)."""


# ---------------------------------------------------------------------------- schedule


# ---------------------------------------------------------------------------- one race
def _import_once(imports) -> None:
    """Import those of the user's agent modules (names, or ``.py`` paths) that this process
    has not imported: a forked worker has them from the driver, a spawned or Ray one not."""
    import sys

    todo = [m for m in imports if (Path(m).stem if m.endswith(".py") else m) not in sys.modules]
    if todo:
        from agents import import_agent_modules

        import_agent_modules(todo)


def finish_ranks(progress) -> list[int]:
    """Finishing positions (1 = winner) by total progress [m], exact ties to the lower car
    index (the winner rule of ``alpha-racer bench``)."""
    p = np.asarray(progress, dtype=float)
    return [int(r) + 1 for r in np.argsort(np.argsort(-p, kind="stable"), kind="stable")]


def _race_failed(race: ScheduledRace, exc: Exception) -> RuntimeError:
    """The error of a failed league race, naming it (a worker's traceback does not)."""
    return RuntimeError(
        f"league race {race.index} ({', '.join(race.agents)} on "
        f"{race.track!r}, seed {race.seed}) failed: "
        f"{type(exc).__name__}: {exc}"
    )


def _league_record(
    race: ScheduledRace,
    states,
    progress,
    contacts,
    off_tracks,
    decision_ms,
    stats,
    dt,
    contact_dn,
    seconds: float,
) -> dict:
    """A finished league race's record."""
    if not np.isfinite(states).all():
        raise FloatingPointError(
            f"league race {race.index} ({', '.join(race.agents)} on "
            f"{race.track!r}) produced non-finite states"
        )
    ranks = finish_ranks(progress)
    return {
        "race": race.index,
        "round": race.round,
        "rotation": race.rotation,
        "track": race.track,
        "seed": race.seed,
        "agents": list(race.agents),
        "start_regions": [f"R{r + 1}" for r in race.order],
        "ranks": ranks,
        "winner": race.agents[ranks.index(1)],
        "progress_m": [round(float(v), 4) for v in progress],
        "contacts": contacts.tolist(),
        "off_tracks": off_tracks.tolist(),
        "decision_ms": [round(float(v), 4) for v in decision_ms],
        "fallbacks": [int(st.get("fallbacks", 0)) for st in stats],
        **race_metrics.record_metrics(states, dt, contact_dn),
        "seconds": round(seconds, 3),
    }


#: league races raced together in one lockstep batch (a pool task; :func:`league_races`)
BATCH_RACES = 8


def league_race(race: ScheduledRace, steps: int, imports=()) -> dict:
    """Run one scheduled race alone (pure: no file access) and return its record."""
    from experiments.evaluation.race import run_race

    warnings.simplefilter("ignore")
    _import_once(imports)
    t0 = time.perf_counter()
    try:
        result, _ = run_race(
            list(race.agents),
            track=race.track,
            seed=race.seed,
            max_cycles=steps,
            start="regions",
            order=list(race.order),
            progress_bar=False,
        )
    except Exception as exc:
        raise _race_failed(race, exc) from exc
    return _league_record(
        race,
        result.states,
        result.progress,
        result.contacts,
        result.off_tracks,
        result.decision_ms,
        result.agent_stats,
        result.dt,
        result.contact_dn,
        time.perf_counter() - t0,
    )


def league_races(races: list[ScheduledRace], steps: int, imports=()) -> list[dict]:
    """Run scheduled races in lockstep batches (one per track,
    :func:`~experiments.evaluation.races.run_races`; pure: no file access) and return their
    records, each the record :func:`league_race` gives alone. A batch that fails is raced
    again one race at a time, so that the error names the race that failed."""
    from experiments.evaluation.races import RaceSpec, run_races

    warnings.simplefilter("ignore")
    _import_once(imports)
    t0 = time.perf_counter()
    specs = [
        RaceSpec(tuple(r.agents), r.seed, tuple(r.order), track=r.track, max_cycles=steps)
        for r in races
    ]
    try:
        outcomes = run_races(specs)
    except Exception:
        return [league_race(r, steps, imports) for r in races]
    seconds = (time.perf_counter() - t0) / len(races)
    return [
        _league_record(
            race,
            o.result.states,
            o.result.progress,
            o.result.contacts,
            o.result.off_tracks,
            o.result.decision_ms,
            [dict(getattr(a, "stats", {}) or {}) for a in o.agents],
            o.config.dt,
            o.config.rules.contact_dn,
            seconds,
        )
        for race, o in zip(races, outcomes)
    ]


# ---------------------------------------------------------------------------- storage
class LeagueRun(ResumableRun):
    """The output directory of one league (see the module docstring)."""

    what = "a league"
    records_name = "races.jsonl"

    def __init__(self, out_dir, config: LeagueConfig, agents=None):
        """``agents``: the agents of ``config.agents`` already built (same order; as
        :func:`~experiments.evaluation.bench_config.check_agent_specs` returns them), so that
        the provenance does not build them again."""
        super().__init__(out_dir, config)
        stored = json.loads(self.manifest_path.read_text()) if self.manifest_path.exists() else None
        self.stages, joining = self._stages(stored, config)
        self.races = schedule(config, self.stages)
        meta = {"schema_version": SCHEMA_VERSION, "config": asdict(config), "env": env_version()}
        if len(self.stages) > 1:
            meta["stages"] = self.stages
        # agents join: the stored manifest is of the league before them (its config checked
        # by _stages), and only its provenance is checked before the manifest is rewritten
        self.claim(
            meta, config.agents, config.tracks, stored=stored if joining else None, built=agents
        )

    @staticmethod
    def _stages(stored: dict | None, config: LeagueConfig) -> tuple[list[int], bool]:
        """The league's stages (see :func:`schedule`) and whether agents join now, from the
        stored manifest (None: a new league): the stored stages, plus one when ``config``
        adds agents to the stored league (its agents first, in their order, every other
        setting equal); a league of another configuration is left for :func:`claim` to
        refuse."""
        if stored is None:
            return [len(config.agents)], False
        old = stored.get("config", {})
        stages = list(stored.get("stages") or [len(old.get("agents", []))])
        now = as_stored(asdict(config))
        old_agents, new_agents = old.get("agents", []), now["agents"]
        same_rest = {k: v for k, v in old.items() if k != "agents"} == {
            k: v for k, v in now.items() if k != "agents"
        }
        if (
            same_rest
            and len(new_agents) > len(old_agents)
            and new_agents[: len(old_agents)] == old_agents
        ):
            return stages + [len(new_agents)], True
        return (stages if old_agents == new_agents else [len(config.agents)]), False

    def tasks(self) -> list[ScheduledRace]:
        return self.races

    def task_key(self, task: ScheduledRace) -> int:
        return task.index

    def record_key(self, record: dict) -> int:
        return record["race"]

    def check_record(self, record: dict) -> bool:
        """A record that is not the scheduled race of its index (agents, track, seed) is an
        error: the schedule has changed since it was written."""
        k = record.get("race")
        race = self.races[k] if isinstance(k, int) and 0 <= k < len(self.races) else None
        if race is None or (record["agents"], record["track"], record["seed"]) != (
            list(race.agents),
            race.track,
            race.seed,
        ):
            raise ValueError(
                f"{self.records_path}: race {k} is not the race this league "
                f"schedules there (written by another version?); use "
                f"another --out"
            )
        return True

    def write_outputs(self) -> dict:
        board = leaderboard(list(self.records().values()), self.config)
        write_json(self.out / "leaderboard.json", board)
        write_text(self.out / "leaderboard.md", leaderboard_markdown(board))
        plot_ratings(board, self.out / "ratings.png")
        plot_pairwise(board, self.out / "pairwise.png")
        return board


def check_tracks(tracks, cars: int) -> None:
    """Build each track and its ``cars`` start regions once, so a bad track spec or a track
    too short for the regions fails before any race starts."""
    from racing_env.config import StartConfig, VehicleParams
    from racing_env.core import start_states
    from racing_env.tracks import make_track

    for spec in tracks:
        try:
            start_states(
                make_track(spec),
                cars,
                StartConfig(mode="regions"),
                VehicleParams().width,
                np.random.default_rng(0),
            )
        except (ValueError, FileNotFoundError, KeyError) as exc:
            msg = str(exc)
            raise ValueError(msg if repr(spec) in msg else f"track {spec!r}: {msg}") from None


def check_field(agents, cars: int, track: str) -> None:
    """Let each agent take one decision in a field of ``cars`` cars on ``track`` (the others
    raceline followers), so an agent that cannot race that many cars (an alpha-potential model
    trained for another number) fails before any race of the league starts."""
    from experiments.evaluation.race import run_race

    for spec in agents:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                run_race(
                    [spec] + ["raceline"] * (cars - 1),
                    track=track,
                    max_cycles=1,
                    start="regions",
                    order=list(range(cars)),
                    progress_bar=False,
                )
        except Exception as exc:
            exc = getattr(exc, "agent_error", exc)  # this message names the agent already
            raise ValueError(
                f"agent {spec!r} cannot race in a field of {cars} cars on "
                f"{track!r}: {type(exc).__name__}: {exc}"
            ) from None


def league(
    config: LeagueConfig,
    out_dir,
    pool: Pool = Pool(),
    imports=(),
) -> dict:
    """Run (or resume) the league ``config`` into ``out_dir``; returns its leaderboard with
    ``new_races``, the number of races run by this call. ``imports`` (module names or ``.py``
    paths, as ``--import``) are imported in every worker before its first race."""
    imports = tuple(str(Path(m).resolve()) if m.endswith(".py") else m for m in imports)
    _import_once(imports)
    agents = check_agent_specs(config.agents, config.tracks)
    check_tracks(config.tracks, config.cars)
    check_field(config.agents, config.cars, config.tracks[0])
    run = LeagueRun(out_dir, config, agents)
    new = run.run_missing(
        league_races,
        lambda races: (races, config.steps, imports),
        pool,
        desc="league",
        unit="race",
        postfix=lambda k, rec: f"{rec['race']}:{rec['winner']}",
        batch=BATCH_RACES,
    )
    board = run.write_outputs()
    board["new_races"] = new
    return board
