"""The honest control: the best fixed theta per track, chosen by a rule from measurements
(``alpha-racer control``).

A learned potential that chooses theta online is only worth something against the best
*fixed* theta in the same seat. This module finds that theta on each track, never by hand:

1. **Map** (:mod:`experiments.evaluation.policy_map`): ``thetas`` scrambled-Sobol thetas (seed ``seed``)
   of the theta box of policy space ``space`` (the paper's five parameters by default; the
   extended space's six with ``b``, ``--space extended``), each alone from the grid (``solo``) and as car_0 against two
   ``opponents`` from the start regions (``race``, theta k from R(k mod 3 + 1)), ``steps``
   control periods each.
2. **Candidates** (:func:`choose_candidates`): among the thetas on track in both modes (at
   most :data:`experiments.evaluation.policy_map_summary.OFF_TRACK_LIMIT` of the steps off track, no error),
   the top ``candidates`` by their rank among the thetas that started their race from the
   same region (by race progress), then by *region-adjusted race progress* (race progress
   minus the median of that region), then by the lower Sobol index: the best of R1, of R2
   and of R3 first, then the second of each, and so on, so that the rotating start region
   does not decide (from R1, with a free road, pace spreads progress far more than from R3
   behind two cars that never yield). The best solo theta (most progress alone) joins if it
   is not among them.
3. **Playoff** (:func:`rank_playoff`): each candidate as the ego of the same ``races`` seeded
   races (:class:`experiments.evaluation.bench_config.BenchConfig`: race k from R(k mod 3 + 1), so every
   region equally often, the same start positions for every candidate) against two
   ``opponents``, ``steps`` each. Scored by wins, then mean progress margin over the best
   opponent [m], then the lower Sobol index (a deterministic order for exact ties).
4. **Winner**: the first of the playoff. ``selection.json`` records the rule, the config,
   every candidate with its map and playoff scores, the winner, the env version
   (``RacingParallelEnv.metadata["name"]``), the track's geometry fingerprint and the package
   version; with ``install`` the winner goes into the table that ``mpc:theta=best`` races
   (:mod:`agents.best_theta`; an extended selection into the table's extended entries, raced
   by ``mpc:space=extended,theta=best``).

Opponents (default ``raceline``, for both the map's race mode and the playoff): the
raceline follower is the strongest simple baseline. It drives the racing line at the car's
own g-g-v limit and never yields, it needs no trained model (so the control is not tuned
against the agents it is compared with: alpha, IBR, PPO) and it is cheap and deterministic.
Seeds: ``seed`` (default 100) seeds the Sobol sample, the map's start positions and the
playoff's races; the benchmarks (``bench``, ``league``, ``general-report``) use seed 0 by
default, and seed 0 is refused here, so the playoff never races a benchmark's races.

Output folder (resumable; run the same command again, also with more tracks; default
``results/control``, ``results/control_extended`` for the extended space):

* ``manifest.json``: schema version, the :class:`ControlConfig` (without tracks) and the
  env version; a folder of another config or env is refused.
* ``<track>/map/``: the track's policy map (:class:`experiments.evaluation.policy_map.PolicyMapRun`).
* ``<track>/playoff/theta_<index>/``: the playoff races of one candidate
  (:class:`experiments.evaluation.bench.BenchRun`).
* ``<track>/selection.json`` and ``summary.md``, ``summary.json`` (every track);
  ``runs.jsonl``: the wall time of every invocation that ran something.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.evaluation.bench import BenchRun, run_many
from experiments.evaluation.bench_config import (
    REGIONS,
    BenchConfig,
    check_agent_specs,
    check_class_wake,
)
from experiments.evaluation.control_rule import (
    RULE,
    choose_candidates,
    eligible_indices,
    playoff_score,
    rank_playoff,
)
from experiments.evaluation.control_summary import track_dir, write_summary
from experiments.evaluation.policy_map import MODES, PolicyMapConfig, PolicyMapRun, run_maps
from experiments.evaluation.refine import compass_search
from experiments.evaluation.thetas import theta_spec
from experiments.infra.artifacts import (
    append_jsonl,
    claim,
    manifest_config,
    read_jsonl,
    write_json,
)
from experiments.infra.checks import check_counts
from experiments.infra.parallel import Pool

SCHEMA_VERSION = 1
BEST_FIXED_SPEC = "mpc:theta=best"
"""The control's agent spec: the ``mpc`` agent with the track's best fixed theta."""
ADDED_FIELDS = {"space": "paper", "refine": 0, "vehicle_class": "orca", "wake": 0.0}
"""Config fields added after selections were first made, with their defaults: a manifest and a
``selection.json`` record them only when they differ
(:func:`experiments.infra.artifacts.manifest_config`), so paper folders resume unchanged."""


def best_fixed_spec(space: str = "paper") -> str:
    """The control's agent spec in policy space ``space``: :data:`BEST_FIXED_SPEC` for the
    paper's, ``mpc:space=<space>,theta=best`` for another."""
    from agents.theta import policy_space

    name = policy_space(space).name
    return BEST_FIXED_SPEC if name == "paper" else f"mpc:space={name},theta=best"


def default_out(space: str = "paper", vehicle_class: str = "orca") -> str:
    """The control folder of policy space ``space`` and ``vehicle_class`` (a folder holds the
    selections of one space and class): ``results/control``, ``results/control_<space>`` for
    another space than the paper's, with ``_<class>`` for another class than the paper's."""
    from agents.theta import policy_space

    name = policy_space(space).name
    out = "results/control" if name == "paper" else f"results/control_{name}"
    return out if vehicle_class == "orca" else f"{out}_{vehicle_class}"


@dataclass(frozen=True)
class ControlConfig:
    """One best-fixed-theta selection (per track; see the module docstring).

    ``thetas`` Sobol points of the map, ``candidates`` (K) thetas taken to the playoff by the
    race map (plus the best solo theta), ``races`` playoff races per candidate (a multiple of
    3: every start region equally often), ``steps`` control periods of 0.1 s per run (map and
    playoff), ``opponents`` the agent spec of the two other cars (map and playoff), ``seed``
    the seed of the Sobol sample, the map's starts and the playoff races (not 0, the
    benchmarks' seed), ``space`` the policy space whose box is mapped (``"paper"`` or
    ``"extended"``, :data:`agents.theta.SPACES`), ``refine`` the rounds of the compass search
    from the playoff's winner (:mod:`experiments.evaluation.refine`; 0: none, the rule before it
    existed), ``vehicle_class`` and ``wake`` the world of every run (the paper's 1:43 class
    by default; ``wake`` None: the class's). Defaults: about 6 CPU-minutes per track for the
    map and playoff (256 map runs, up to 180 playoff races) in the paper's world, and up to 2
    (2 dim + 1) x 30 races more for the search."""

    thetas: int = 128
    candidates: int = 5
    races: int = 30
    steps: int = 500
    opponents: str = "raceline"
    seed: int = 100
    space: str = "paper"
    refine: int = 2
    vehicle_class: str = "orca"
    wake: float | None = None

    def __post_init__(self):
        from agents.theta import policy_space

        check_class_wake(self)
        policy_space(self.space)  # names the choices if unknown
        check_counts(self, ("thetas", "candidates", "races", "steps"))
        if isinstance(self.refine, bool) or not (isinstance(self.refine, int) and self.refine >= 0):
            raise ValueError(
                f"ControlConfig.refine must be a non-negative integer (rounds of the local "
                f"search; 0 = none), got {self.refine!r}"
            )
        if self.races % len(REGIONS):
            raise ValueError(
                f"ControlConfig.races must be a multiple of {len(REGIONS)} (every "
                f"start region equally often), got {self.races}"
            )
        check_counts(self, ("seed",), minimum=0)
        if self.seed == BenchConfig.seed:
            raise ValueError(
                f"ControlConfig.seed {self.seed} is the benchmarks' seed; the "
                f"selection must not race the races it is compared on"
            )
        if not isinstance(self.opponents, str) or not self.opponents:
            raise ValueError(
                f"ControlConfig.opponents must be an agent spec, got {self.opponents!r}"
            )

    def map_config(self, track: str) -> PolicyMapConfig:
        """The policy map of ``track``: both modes, this config's thetas, steps, seed and
        opponents."""
        return PolicyMapConfig(
            thetas=self.thetas,
            tracks=(track,),
            modes=MODES,
            steps=self.steps,
            seed=self.seed,
            opponents=self.opponents,
            space=self.space,
            vehicle_class=self.vehicle_class,
            wake=self.wake,
        )

    def playoff_config(self, track: str, theta) -> BenchConfig:
        """The playoff races of the candidate ``theta`` (dim,) of the config's space on
        ``track``."""
        return BenchConfig(
            ego=theta_spec(theta),
            opponents=self.opponents,
            races=self.races,
            steps=self.steps,
            track=track,
            seed=self.seed,
            vehicle_class=self.vehicle_class,
            wake=self.wake,
        )


# ---------------------------------------------------------------------------- the rule


# ---------------------------------------------------------------------------- storage


def _theta_array(theta: dict, space: str = "paper") -> np.ndarray:
    """A stored theta (name -> value) as an array (dim,) in policy space ``space``'s order."""
    from agents.theta import policy_space

    return np.array([theta[n] for n in policy_space(space).names], dtype=float)


def stored_config(cfg: ControlConfig) -> dict:
    """The config as a manifest and ``selection.json`` record it (:data:`ADDED_FIELDS`)."""
    return manifest_config(cfg, ADDED_FIELDS)


def _run_key(track: str, index: int) -> str:
    """Name of a candidate's playoff run in the shared pool (shown in the progress bar)."""
    return f"{track}/theta_{index:04d}"


def _playoff_runs(cfg: ControlConfig, out: Path, track: str, cands) -> dict:
    folder = track_dir(out, track) / "playoff"
    return {
        _run_key(track, c["index"]): BenchRun(
            folder / f"theta_{c['index']:04d}",
            cfg.playoff_config(track, _theta_array(c["theta"], cfg.space)),
        )
        for c in cands
    }


def _ranked_playoff(cfg: ControlConfig, track: str, cands, runs) -> list[dict]:
    """The playoff's candidates of ``track`` with their scores, ranked (:func:`rank_playoff`)."""
    scores = []
    for c in cands:
        s = runs[_run_key(track, c["index"])].write_summary()
        scores.append({**c, **playoff_score(s)})
    return rank_playoff(scores)


def _seconds(runs) -> float:
    return sum(rec["seconds"] for run in runs for rec in run.records().values())


def _selection(
    cfg: ControlConfig, track: str, map_run: PolicyMapRun, ranked, refined: dict, seconds
) -> dict:
    """The content of ``selection.json`` (a function of the stored rows only, so a resume
    that runs nothing writes the same bytes). ``ranked``: the playoff (:func:`_ranked_playoff`),
    ``refined``: the search's rounds and winner (:func:`_refine`), ``seconds``: the worker
    seconds of the playoff's and the search's races."""
    from agents.best_theta import env_name
    from experiments import __version__
    from racing_env.tracks import make_track

    t = make_track(track, vehicle_class=cfg.vehicle_class)
    rows = list(map_run.records().values())
    seconds += sum(r.get("seconds", 0.0) for r in rows)
    out = {
        "schema_version": SCHEMA_VERSION,
        "track": track,
        "name": t.name,
        "fingerprint": t.fingerprint(),
        "env": env_name(),
        "package_version": __version__,
        "rule": RULE,
        "config": stored_config(cfg),
        "map": {
            "rows": len(rows),
            "errors": sum("error" in r for r in rows),
            "eligible_thetas": len(eligible_indices(rows)),
        },
        "candidates": ranked,
        "winner": refined["winner"],
        "worker_seconds": round(float(seconds), 3),
    }
    if cfg.refine:
        out["refine"] = refined["rounds"]
    return out


def selection_sha256(path) -> str:
    """SHA-256 of a ``selection.json`` file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def selection_space(selection: dict) -> str:
    """The policy space of a ``selection.json``'s content (``"paper"`` when its config does
    not name one: every selection made before policy spaces)."""
    return selection["config"].get("space", "paper")


def install(selection_path, table=None) -> dict:
    """Put the winner of ``selection_path`` (a ``selection.json``) into the best-theta table
    ``table`` (default :func:`agents.best_theta.table_path`) among the entries of the
    selection's policy space, replacing the track's entry there (and any entry of the same
    geometry under another spec); the other spaces' entries are kept. A selection of another
    vehicle class than the paper's is keyed ``"TRACK (CLASS)"`` (its geometry is the
    circuit at the class's scale, so ``mpc:theta=best`` finds it by fingerprint). Returns the
    new entry (with ``space`` unless it is the paper's, ``vehicle_class`` unless the ORCA
    car's)."""
    from agents.best_theta import read_table, set_space_entries, space_entries, table_path

    selection_path = Path(selection_path)
    sel = json.loads(selection_path.read_text())
    space = selection_space(sel)
    path = Path(table) if table is not None else table_path()
    current = read_table(path)
    w = sel["winner"]
    entry = {
        "track": sel["track"],
        "name": sel["name"],
        "fingerprint": sel["fingerprint"],
        "env": sel["env"],
        "theta": w["theta"],
        "package_version": sel["package_version"],
        "selection": {
            "file": str(selection_path),
            "sha256": selection_sha256(selection_path),
            "rule": sel["rule"],
            "config": sel["config"],
            "index": w["index"],
            "wins": w["wins"],
            "races": w["races"],
            "margin_m_mean": w["margin_m_mean"],
            "candidates": len(sel["candidates"]),
        },
    }
    if space != "paper":
        entry["space"] = space
    vehicle_class = sel["config"].get("vehicle_class", "orca")
    key = sel["track"]
    if vehicle_class != "orca":
        entry["vehicle_class"] = vehicle_class
        key = f"{key} ({vehicle_class})"
    tracks = {
        k: e
        for k, e in space_entries(current, space).items()
        if k != key and e["fingerprint"] != sel["fingerprint"]
    }
    tracks[key] = entry
    set_space_entries(current, space, tracks)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, current)
    return entry


# ---------------------------------------------------------------------------- the search
def _refine_races(out: Path, tracks) -> int:
    """Races stored by the search of ``tracks`` in ``out`` (to count the new ones)."""
    return sum(
        len(read_jsonl(f))
        for t in tracks
        for f in (track_dir(out, t) / "refine").glob("theta_*/races.jsonl")
    )


def _refine_folder(out: Path, track: str, index: int) -> Path:
    return track_dir(out, track) / "refine" / f"theta_{index:04d}"


def _refine(cfg: ControlConfig, out: Path, ranked: dict, pool: Pool) -> dict:
    """``cfg.refine`` rounds of the compass search (:func:`experiments.evaluation.refine.compass_search`)
    from the playoff's first on every track of ``ranked`` (track -> its ranked playoff), the
    proposals of all tracks raced in one pool. A new theta gets the next index after the
    map's (``cfg.thetas``, ...), in the order the moves are made, so a resume names the same
    folders (``<track>/refine/theta_<index>``); a theta raced before (in the playoff or an
    earlier round) is not raced again. Returns, per track, ``rounds`` and ``winner`` (the
    search's result) and ``runs`` (the search's benchmark runs)."""
    from agents.theta import policy_space

    space = policy_space(cfg.space)

    def key(theta):
        return tuple(float(v) for v in theta)

    def theta_of(score):
        return _theta_array(score["theta"], cfg.space)

    raced = {t: {key(theta_of(c)): c for c in r} for t, r in ranked.items()}
    runs = {t: [] for t in ranked}
    index = dict.fromkeys(ranked, cfg.thetas)
    searches = {
        t: compass_search(r[0], theta_of, space.low, space.high, space.names, cfg.refine, cfg.steps)
        for t, r in ranked.items()
    }
    results, pending = {}, {}

    def advance(t, scored=None):
        try:
            pending[t] = searches[t].send(scored)
        except StopIteration as done:
            results[t] = done.value
            pending.pop(t, None)

    for t in searches:
        advance(t)
    while pending:
        batch, new = {}, []
        for t, (props, round_no) in pending.items():
            for label, theta in props:
                if key(theta) in raced[t]:
                    continue
                i, index[t] = index[t], index[t] + 1
                run = BenchRun(_refine_folder(out, t, i), cfg.playoff_config(t, theta))
                batch[_run_key(t, i)] = run
                new.append((t, i, f"refine {round_no}: {label}", run, theta))
        run_many(batch, pool)
        for t, i, reason, run, theta in new:
            runs[t].append(run)
            raced[t][key(theta)] = {
                "index": i,
                "theta": {n: float(v) for n, v in zip(space.names, theta)},
                "reasons": [reason],
                **playoff_score(run.write_summary()),
            }
        for t, (props, _) in list(pending.items()):
            advance(t, [(label, raced[t][key(theta)]) for label, theta in props])
    return {t: {**results[t], "runs": runs[t]} for t in ranked}


# ---------------------------------------------------------------------------- drivers
def select_best_thetas(
    cfg: ControlConfig,
    tracks,
    out_dir=None,
    pool: Pool = Pool(),
    install_table: bool = True,
    table=None,
) -> dict:
    """Run (or resume) the selection ``cfg`` on every track of ``tracks`` into ``out_dir``
    (maps of all tracks in one pool, then all playoffs in one pool), write every track's
    ``selection.json`` and, with ``install_table``, put the winners into the best-theta table
    ``table`` (default: the one ``mpc:theta=best`` reads). ``out_dir`` defaults to
    :func:`default_out` of the config's space and class. Returns ``summary.json``'s content with
    ``new_map_runs``, ``new_races`` and ``wall_seconds_this_run``."""
    from agents.best_theta import env_name

    tracks = list(dict.fromkeys(tracks))
    if not tracks or not all(isinstance(t, str) and t for t in tracks):
        raise ValueError(f"tracks must be non-empty track specs, got {tracks!r}")
    check_agent_specs([cfg.opponents], tracks, cfg.vehicle_class)  # typos fail now
    out = Path(out_dir if out_dir is not None else default_out(cfg.space, cfg.vehicle_class))
    out.mkdir(parents=True, exist_ok=True)
    claim(
        out / "manifest.json",
        {"schema_version": SCHEMA_VERSION, "config": stored_config(cfg), "env": env_name()},
        "a best-fixed-theta selection",
    )
    t0 = time.perf_counter()
    maps = {t: PolicyMapRun(track_dir(out, t) / "map", cfg.map_config(t)) for t in tracks}
    new_map_runs = run_maps(maps, pool, "control: map")
    for run in maps.values():
        run.write_outputs()
    cands = {t: choose_candidates(maps[t].records().values(), cfg.candidates) for t in tracks}
    runs = {}
    for t in tracks:
        runs.update(_playoff_runs(cfg, out, t, cands[t]))
    todo = sum(len(run.missing()) for run in runs.values())
    run_many(runs, pool)
    ranked = {t: _ranked_playoff(cfg, t, cands[t], runs) for t in tracks}
    raced_before = _refine_races(out, tracks)
    refined = _refine(cfg, out, ranked, pool)
    todo += _refine_races(out, tracks) - raced_before
    for t in tracks:
        path = track_dir(out, t) / "selection.json"
        playoff_runs = [runs[_run_key(t, c["index"])] for c in cands[t]]
        seconds = _seconds(playoff_runs + refined[t]["runs"])
        write_json(path, _selection(cfg, t, maps[t], ranked[t], refined[t], seconds))
        if install_table:
            install(path, table)
    wall = time.perf_counter() - t0
    if new_map_runs or todo:
        append_jsonl(
            out / "runs.jsonl",
            {
                "tracks": tracks,
                "map_runs": new_map_runs,
                "playoff_races": todo,
                "wall_seconds": wall,
                "workers": pool.workers,
                "backend": pool.backend,
                "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
            },
        )
    summary = write_summary(out)
    return {
        **summary,
        "new_map_runs": new_map_runs,
        "new_races": todo,
        "wall_seconds_this_run": wall,
    }


def ensure_best_thetas(
    tracks,
    cfg: ControlConfig,
    out_dir=None,
    pool: Pool = Pool(),
    table=None,
) -> dict:
    """The best-theta table entry of every track of ``tracks`` in the policy space of ``cfg``;
    tracks the table lacks there (or holds for another env version or geometry) are selected
    first with ``cfg`` into ``out_dir`` (resumable; default :func:`default_out`) and
    installed. Returns ``{track: entry}``."""
    from agents.best_theta import lookup
    from racing_env.tracks import make_track

    def entry(t):
        return lookup(make_track(t, vehicle_class=cfg.vehicle_class), table, cfg.space)

    missing = []
    for t in dict.fromkeys(tracks):
        try:
            entry(t)
        except ValueError:
            missing.append(t)
    if missing:
        select_best_thetas(cfg, missing, out_dir, pool, True, table)
    return {t: entry(t) for t in dict.fromkeys(tracks)}
