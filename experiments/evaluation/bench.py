"""Head-to-head benchmark (the paper's Table 1): ``alpha-racer bench``.

The paper's protocol: three cars, the ego against two opponents of one kind, ``races`` races
(99) of ``steps`` control periods (500 x 0.1 s = 50 s). Race k puts the ego in start region
R1, R2, R3 for k = 0, 1, 2 (mod 3), so 99 races give 33 per region; of the two other regions
opponent O1 always takes the front one, O2 the back one. Cars: car_0 ego, car_1 O1, car_2 O2.
A race is won by the largest total progress along the track (unwrapped s).

Scaled to N cars (``--cars N``, 2..8): N start regions R1..RN, race k puts the ego in
R(k mod N + 1) (so ``races`` must be a multiple of N: every region equally often), and the
opponents O1..O(N-1) take the other regions front to back. N = 3 is the paper's protocol,
race for race (same seeds, same start orders, same outputs).

Output directory:

* ``manifest.json``: schema version and the :class:`BenchConfig`; a directory of another
  config is refused.
* ``races.jsonl``: one JSON line per finished race (written by the driver as the race
  arrives, flushed and fsynced; a killed run resumes with the missing races, and a torn last
  line is dropped).
* ``states/race_00000.npz``: every car's Frenet state per step (float32, (T + 1, 3, 6)),
  for animations of the benchmark's own races.
* ``summary.json`` and ``summary.md``: :func:`summarise`.

Every record carries the race's strategy metrics (:mod:`experiments.evaluation.metrics`: passes per car,
passes through contact, whether the winner came from behind, time within 1 m behind),
computed from the stored float32 states; a folder written before they existed gets them
recomputed from its ``states/`` when summarised.

``ego_regions`` (``alpha-racer strategy``) fixes the ego's start region per race instead of
the rotation: race k puts the ego in ``ego_regions[k mod len]``.

``alpha-racer bench --paper-table`` runs the paper's five cases (:data:`PAPER_CASES`) with one
pool over all their races and writes ``paper_table.md`` beside the paper's numbers.
"""

from __future__ import annotations

import json
import time
import warnings
from pathlib import Path

import numpy as np

from experiments.evaluation import metrics as race_metrics
from experiments.evaluation.bench_config import BenchConfig, check_agent_specs
from experiments.evaluation.bench_summary import race_dt_dn, summarise, summary_markdown
from experiments.infra.artifacts import (
    ResumableRun,
    env_version,
    run_missing,
    write_json,
    write_npz,
    write_text,
)
from experiments.infra.parallel import Pool

SCHEMA_VERSION = 1


#: races of one benchmark raced together in one lockstep batch (a pool task): every period's
#: MPC steps of all its cars in one compiled call; a killed run loses at most a batch
BATCH_RACES = 8


def bench_race(config: BenchConfig, k: int) -> dict:
    """Race k of the benchmark (pure: no file access); returns its record and states
    (:func:`bench_races` of one race)."""
    return bench_races(config, [k])[0]


def bench_races(config: BenchConfig, ks) -> list[dict]:
    """Races ``ks`` of the benchmark (pure: no file access) in one lockstep batch
    (:func:`experiments.evaluation.races.run_races`): each race bit for bit the race
    :func:`~experiments.evaluation.race.run_race` runs alone; returns each race's record and
    states, in order. ``seconds`` is the batch's wall time shared equally, and
    ``decision_ms`` a batched decision's time shared equally by its cars."""
    from experiments.evaluation.races import RaceSpec, run_races

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    specs = [
        RaceSpec(
            tuple(config.agents),
            config.race_seed(k),
            tuple(config.order(k)),
            track=config.track,
            max_cycles=config.steps,
            vehicle_class=config.vehicle_class,
            wake=config.wake,
        )
        for k in ks
    ]
    outcomes = run_races(specs)
    seconds = (time.perf_counter() - t0) / len(specs)
    return [
        _record(config, k, spec, outcome, seconds) for k, spec, outcome in zip(ks, specs, outcomes)
    ]


def _record(config: BenchConfig, k: int, spec, outcome, seconds: float) -> dict:
    """Race k's record and float32 states from its outcome (:func:`run_races`)."""
    result, race_config = outcome.result, outcome.config
    if not np.isfinite(result.states).all():
        raise FloatingPointError(f"benchmark race {k} produced non-finite states")
    p = result.progress
    winner = int(np.argmax(p))
    states = result.states.astype(np.float32)
    reg = config.regions
    order = spec.order
    stats = [dict(getattr(a, "stats", {}) or {}) for a in outcome.agents]
    record = {
        "race": k,
        "seed": spec.seed,
        "ego_region": reg[order[0]],
        "start_regions": [reg[r] for r in order],
        "agents": config.agents,
        "winner": config.roles[winner],
        "progress_m": [round(float(v), 4) for v in p],
        "margin_m": round(float(p[0] - max(p[1:])), 4),
        "ranks": [int(r) for r in np.argsort(np.argsort(-p, kind="stable"), kind="stable") + 1],
        "contacts": result.contacts.tolist(),
        "off_tracks": result.off_tracks.tolist(),
        "decision_ms": [round(float(v), 4) for v in result.decision_ms],
        "fallbacks": [int(st.get("fallbacks", 0)) for st in stats],
        # from the states as stored, so a summary recomputing them finds the same numbers
        **race_metrics.record_metrics(states, race_config.dt, race_config.rules.contact_dn),
        "seconds": round(seconds, 3),
    }
    return {"record": record, "states": states}


# ---------------------------------------------------------------------------- storage
class BenchRun(ResumableRun):
    """The output directory of one benchmark (see the module docstring)."""

    what = "a benchmark"
    records_name = "races.jsonl"

    def __init__(self, out_dir, config: BenchConfig):
        super().__init__(out_dir, config)
        (self.out / "states").mkdir(exist_ok=True)
        self.claim(
            {"schema_version": SCHEMA_VERSION, "config": config.to_dict(), "env": env_version()},
            config.agents,
            [config.track],
            vehicle_class=config.vehicle_class,
        )

    @classmethod
    def open(cls, out_dir) -> BenchRun:
        """The benchmark stored in ``out_dir``, to read (its races and states): the config
        comes from its manifest and nothing is written, where constructing a run claims the
        folder and records this commit's provenance in it."""
        out = Path(out_dir)
        config = BenchConfig(**json.loads((out / cls.manifest_name).read_text())["config"])
        run = cls.__new__(cls)
        ResumableRun.__init__(run, out, config)
        return run

    def tasks(self) -> list[int]:
        return list(range(self.config.races))

    def record_key(self, record: dict) -> int:
        return record["race"]

    def check_record(self, record: dict) -> bool:
        return self._states_path(record["race"]).exists()

    def add(self, result: dict) -> None:
        """Store one race: states first, then its JSON line (a line means a complete race)."""
        rec = result["record"]
        write_npz(self._states_path(rec["race"]), compressed=True, states=result["states"])
        super().add(rec)

    def _states_path(self, k: int) -> Path:
        return self.out / "states" / f"race_{k:05d}.npz"

    def states(self, k: int) -> np.ndarray:
        with np.load(self._states_path(k)) as z:
            return z["states"]

    def records_with_metrics(self) -> dict[int, dict]:
        """:meth:`records`, each with its strategy metrics: those of a record written before
        they existed are computed from its stored states (with the default race config's
        ``dt`` and contact box, the only ones a benchmark races with)."""
        out = self.records()
        for k, rec in out.items():
            if any(key not in rec for key in race_metrics.RECORD_KEYS):
                out[k] = {**rec, **race_metrics.record_metrics(self.states(k), *race_dt_dn())}
        return out

    def write_summary(self) -> dict:
        summary = summarise(list(self.records_with_metrics().values()), self.config)
        write_json(self.out / "summary.json", summary)
        write_text(self.out / "summary.md", summary_markdown(summary))
        return summary


# ---------------------------------------------------------------------------- statistics


# ---------------------------------------------------------------------------- drivers
def run_many(runs: dict, pool: Pool) -> None:
    """Run the missing races of every :class:`BenchRun` in ``runs`` (name -> run) in one pool,
    in lockstep batches of up to :data:`BATCH_RACES` races of one run (:func:`bench_races`)."""
    run_missing(
        runs,
        bench_races,
        lambda run, ks: (run.config, ks),
        pool,
        desc="bench",
        unit="race",
        postfix=lambda key, result: f"{key[0]}:{result['record']['winner']}",
        batch=BATCH_RACES,
    )


def bench(config: BenchConfig, out_dir, pool: Pool = Pool()) -> dict:
    """Run (or resume) one benchmark into ``out_dir`` on ``pool``; returns its summary."""
    check_agent_specs(config.agents, [config.track], config.vehicle_class)
    run = BenchRun(out_dir, config)
    run_many({"bench": run}, pool)
    return run.write_summary()
