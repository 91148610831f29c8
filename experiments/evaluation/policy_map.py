"""Map the MPC policy space: ``alpha-racer policy-map``.

Thetas ``(q, zeta, s1, s2, s3)`` from a scrambled Sobol sequence (seeded) over the box
``[THETA_LOW, THETA_HIGH]`` of :mod:`agents.reference`, read when the map starts (the box is
stored in the manifest, so a map of another box is never mixed in). Each theta drives an
``mpc`` car on every track in two modes:

* ``solo``: the car alone, standing start from the grid (``start="grid"``), ``steps`` control
  periods. The best lap is taken over the flying laps only (laps 2, 3, ...: the first lap
  includes the standing start), ``None`` with fewer than two completed laps.
* ``race``: the car (car_0) against two fixed opponents (``opponents``, default ``mpc`` at its
  default theta) from the paper's start regions; theta k starts from region R(k mod 3 + 1) and
  the opponents take the other two, O1 the front one (as in ``alpha-racer bench``). Adds the
  car's rank (1 = most progress) and its progress margin over the best opponent.

Output directory:

* ``manifest.json``: schema version, the :class:`PolicyMapConfig` and the theta box
  (``config.theta_box``); a folder of another configuration or box is refused.
* ``rows.jsonl``: one JSON line per (mode, track, theta index), written by the driver as the
  row arrives (flushed, fsynced); a rerun computes only the missing rows. A row whose race
  raised holds ``error`` (the exception) instead of the measurements and is not retried.
* ``summary.json``, ``summary.md``: :func:`summarise`.
* ``heatmap_<mode>_<track>.png``: binned means of progress and off-track fraction over
  (zeta, q) and (zeta, s1), :func:`plot_heatmaps`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from experiments.evaluation.bench_config import (
    REGIONS,
    BenchConfig,
    check_agent_specs,
    check_class_wake,
    drop_default_class,
)
from experiments.evaluation.policy_map_summary import (
    heatmap_name,
    plot_heatmaps,
    summarise,
    summary_markdown,
)
from experiments.evaluation.thetas import (
    sample_thetas,
    theta_box,
    theta_dict,
    theta_names,
    theta_spec,
)
from experiments.infra.artifacts import (
    ResumableRun,
    check_track_specs,
    env_version,
    manifest_config,
    run_missing,
    write_json,
    write_text,
)
from experiments.infra.checks import check_counts
from experiments.infra.parallel import Pool

SCHEMA_VERSION = 1
MODES = ("solo", "race")
DEFAULT_TRACKS = ("default", "oval", "random:101", "random:202")
TIMING_KEYS = ("decision_ms", "seconds")
"""Row fields that are wall-clock measurements (they differ between identical reruns)."""


@dataclass(frozen=True)
class PolicyMapConfig:
    """One policy map: ``thetas`` Sobol points of the theta box (scrambled with ``seed``) on
    each of ``tracks`` in each of ``modes``, ``steps`` control periods of 0.1 s per run.
    ``opponents`` is the agent spec of the two fixed cars of the ``race`` mode; ``space`` the
    policy space whose box is mapped (``"paper"`` or ``"extended"``, :mod:`agents.reference`);
    ``vehicle_class`` and ``wake`` the world of every run (the paper's 1:43 class by default;
    ``wake`` None: the class's, stored resolved), left out of the manifest for the paper's."""

    thetas: int = 256
    tracks: tuple[str, ...] = DEFAULT_TRACKS
    modes: tuple[str, ...] = MODES
    steps: int = 500
    seed: int = 0
    opponents: str = "mpc"
    space: str = "paper"
    vehicle_class: str = "orca"
    wake: float | None = None

    def __post_init__(self):
        from agents.reference import policy_space

        check_class_wake(self)
        policy_space(self.space)  # names the choices if unknown
        object.__setattr__(self, "tracks", tuple(self.tracks))
        object.__setattr__(self, "modes", tuple(self.modes))
        check_counts(self, ("thetas", "steps"))
        check_counts(self, ("seed",), minimum=0)
        bad = [m for m in self.modes if m not in MODES]
        if bad or not self.modes or len(set(self.modes)) != len(self.modes):
            raise ValueError(f"modes must be distinct values of {MODES}, got {list(self.modes)}")
        check_track_specs(self.tracks)

    def row_seed(self, k: int) -> int:
        """Seed of theta k's runs (start positions in the race mode, the agents' seeds)."""
        return int(np.random.SeedSequence([self.seed, k]).generate_state(1)[0])


def best_flying_lap(lap_times) -> float | None:
    """Fastest lap [s] after the first from cumulative lap completion times [s] (the env's
    ``core.lap_times``, as ``experiments.evaluation.race`` reads them); ``None`` with fewer than 2 laps."""
    if len(lap_times) < 2:
        return None
    return float(np.diff(np.asarray(lap_times, dtype=float)).min())


# ---------------------------------------------------------------------------- one row
def _row_start(config: PolicyMapConfig, mode: str, track: str, k: int, theta) -> tuple:
    """Row k's first fields and its race (:class:`~experiments.evaluation.races.RaceSpec`)."""
    from experiments.evaluation.races import RaceSpec

    spec, seed = theta_spec(theta), config.row_seed(k)
    row = {"mode": mode, "track": track, "index": k, "theta": theta_dict(theta), "seed": seed}
    order: tuple[int, ...] | None = None
    if mode == "race":
        order = tuple(BenchConfig.start_order(k))
        row["start_region"] = REGIONS[order[0]]
        agents, start = (spec, config.opponents, config.opponents), "regions"
    else:
        agents, start = (spec,), "grid"
    race = RaceSpec(
        agents,
        seed,
        order,
        track=track,
        max_cycles=config.steps,
        start=start,
        vehicle_class=config.vehicle_class,
        wake=config.wake,
    )
    return row, race


def _row_end(row: dict, states, progress, lap_times, off_tracks, contacts, stats, decision_ms):
    """``row`` completed in place from its finished race (the theta's car first)."""
    if not np.isfinite(states).all():
        row["error"] = "FloatingPointError: non-finite states"
        return
    steps = len(states) - 1
    p = progress
    row.update(
        {
            "steps": steps,
            "progress_m": round(float(p[0]), 4),
            "laps": len(lap_times[0]),
            "lap_times_s": [round(float(t), 4) for t in lap_times[0]],
            "best_lap_s": best_flying_lap(lap_times[0]),
            "off_track_steps": int(off_tracks[0]),
            "off_track_frac": float(off_tracks[0]) / max(steps, 1),
            "contacts": int(contacts[0]),
            "fallbacks": int(stats.get("fallbacks", 0)),
            "restarts": int(stats.get("restarts", 0)),
            "decision_ms": round(float(decision_ms[0]), 4),
        }
    )
    if row["mode"] == "race":
        row["opponents_progress_m"] = [round(float(v), 4) for v in p[1:]]
        row["rank"] = int(1 + np.sum(p[1:] > p[0]))
        row["margin_m"] = round(float(p[0] - p[1:].max()), 4)


def map_row(config: PolicyMapConfig, mode: str, track: str, k: int, theta) -> dict:
    """Run theta k on ``track`` in ``mode`` alone (pure: no file access) and return its row."""
    from experiments.evaluation.race import run_race

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    row, race = _row_start(config, mode, track, k, theta)
    try:
        res, _ = run_race(
            list(race.agents),
            track=track,
            seed=race.seed,
            max_cycles=config.steps,
            start=race.start,
            order=None if race.order is None else list(race.order),
            progress_bar=False,
            vehicle_class=config.vehicle_class,
            wake=config.wake,
        )
    except Exception as exc:  # one failing theta must not end a map of thousands
        row["error"] = f"{type(exc).__name__}: {exc}"
    else:
        _row_end(
            row,
            res.states,
            res.progress,
            res.lap_times,
            res.off_tracks,
            res.contacts,
            res.agent_stats[0],
            res.decision_ms,
        )
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return row


def map_rows(config: PolicyMapConfig, items) -> list[dict]:
    """The rows of ``items`` (``(mode, track, k, theta)`` each) raced in lockstep batches
    (:func:`~experiments.evaluation.races.run_races`; pure: no file access), each the row
    :func:`map_row` gives alone. A batch in which a race fails is raced again one row at a
    time, so that the failing theta gets its error row and the others theirs."""
    from experiments.evaluation.races import run_races

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    try:
        starts = [_row_start(config, *item) for item in items]
        outcomes = run_races([race for _, race in starts])
    except Exception:  # one failing theta must not end a map of thousands
        return [map_row(config, *item) for item in items]
    seconds = round((time.perf_counter() - t0) / len(items), 3)
    for (row, _), o in zip(starts, outcomes):
        r = o.result
        stats = dict(getattr(o.agents[0], "stats", {}) or {})
        _row_end(
            row, r.states, r.progress, r.lap_times, r.off_tracks, r.contacts, stats, r.decision_ms
        )
        row["seconds"] = seconds
    return [row for row, _ in starts]


# ---------------------------------------------------------------------------- storage
class PolicyMapRun(ResumableRun):
    """The output directory of one policy map (see the module docstring)."""

    what = "a policy map"
    records_name = "rows.jsonl"

    def __init__(self, out_dir, config: PolicyMapConfig):
        low, high = theta_box(config.space)
        self.thetas = sample_thetas(config.thetas, config.seed, low, high)
        super().__init__(out_dir, config)
        # the box goes into "config", so a refusal after a change of the box names it
        self.claim(
            {
                "schema_version": SCHEMA_VERSION,
                "config": {
                    **drop_default_class(manifest_config(config, {"space": "paper"})),
                    "theta_box": {
                        "names": list(theta_names(config.space)),
                        "low": low.tolist(),
                        "high": high.tolist(),
                    },
                },
                "env": env_version(),
            }
        )

    def tasks(self) -> list[tuple]:
        """Every row of the map as (mode, track, index), the key of its finished record."""
        c = self.config
        return [(m, t, k) for m in c.modes for t in c.tracks for k in range(c.thetas)]

    def record_key(self, record: dict) -> tuple:
        return (record["mode"], record["track"], record["index"])

    def write_outputs(self) -> dict:
        rows = list(self.records().values())
        summary = summarise(rows, self.config)
        write_json(self.out / "summary.json", summary)
        write_text(self.out / "summary.md", summary_markdown(summary))
        for mode in self.config.modes:
            for track in self.config.tracks:
                sub = [r for r in rows if r["mode"] == mode and r["track"] == track]
                if any("error" not in r for r in sub):
                    plot_heatmaps(
                        sub,
                        self.out / heatmap_name(mode, track),
                        title=f"{mode} on {track}",
                        low=summary["theta_low"],
                        high=summary["theta_high"],
                    )
        return summary


# ---------------------------------------------------------------------------- driver
def policy_map(config: PolicyMapConfig, out_dir, pool: Pool = Pool()) -> dict:
    """Run (or resume) the policy map ``config`` into ``out_dir``; returns its summary with
    ``new_rows``, the number of rows computed by this call."""

    # a typo (in a track or the opponents' spec) fails before any run starts
    check_agent_specs(
        [config.opponents] if "race" in config.modes else [], config.tracks, config.vehicle_class
    )
    run = PolicyMapRun(out_dir, config)
    new = run_maps({None: run}, pool)
    summary = run.write_outputs()
    summary["new_rows"] = new
    return summary


#: rows raced together in one lockstep batch (a pool task; :func:`map_rows`)
BATCH_ROWS = 8


def run_maps(maps: dict, pool: Pool, desc: str = "policy map") -> int:
    """Compute the missing rows of every :class:`PolicyMapRun` of ``maps`` (name -> run) in
    one pool, behind one progress bar ``desc``; returns the number of rows computed."""
    return run_missing(
        maps,
        map_rows,
        lambda run, keys: (run.config, [(*key, run.thetas[key[2]]) for key in keys]),
        pool,
        desc=desc,
        unit="run",
        postfix=lambda key, row: f"{row['mode']}:{row['track']}:{row['index']}",
        batch=BATCH_ROWS,
    )
