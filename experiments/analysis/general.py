"""The general alpha-potential on held-out tracks: ``alpha-racer general-report``.

Everything is measured on tracks the model never saw (its metadata lists its training tracks;
a held-out track among them is refused), except the last part, which is about ``default``:

1. **Approximation gap** per field size N (default 2, 3, 5): fresh races on the held-out
   tracks (a family collection, ``heldout/``), unilateral deviations at their states, the gap
   ``|dPhi - dV_i|`` relative to the model's value range (from its training validation, as
   ``alpha-racer analyze`` does; the range measured on these races is reported beside it):
   median and 95th percentile, against a constant potential. ``gap.json``.
2. **alpha (general) against the fixed-theta control** in the paper's protocol scaled to N
   cars (:class:`experiments.evaluation.bench_config.BenchConfig` with ``n_cars = N``): on every held-out track
   and N, ``rounds`` rounds of N races (the ego from each start region once per round)
   against N - 1 ``mpc`` cars (the MPC at its fixed default theta, zeta 0.9). The control
   runs the same races with the best fixed theta on that track as ego, in the model's policy
   space (``mpc:theta=best`` or ``mpc:space=extended,theta=best``, chosen per held-out track
   by ``alpha-racer control`` with ``control_thetas`` and ``control_races``, into
   ``control/`` unless the best-theta table has the track; about 6 CPU-minutes per track
   with the defaults in the paper's space), or with ``control``, one agent spec on every
   track; an extra row runs them with an ``mpc`` ego at its default theta.
   ``bench/<track>_<N>cars/{alpha,control,mpc_default}/``;
   ``bench/best_fixed_theta.json`` ties the races to the thetas they used.
3. **alpha (general) against the single-track model on default**: the general model against
   two cars of the shipped single-track model of its space (``alpha:model=default``, or
   ``alpha:model=extended``) in the paper's 3-car protocol; the control runs the same races
   with that model as ego. ``default/{general,control}/``.

Part 1's held-out races are drawn as the model's training races were: in its policy space,
with its collection's start regions and paces (``start``, ``pace``).

``summary.md`` and ``summary.json`` collect the three. The folder is claimed by its config
(``manifest.json``); every part resumes (the collection by shards, the races by race), so a
killed run loses no finished race.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from experiments.evaluation.bench import BenchRun, run_many
from experiments.evaluation.bench_config import BenchConfig, check_agent_specs
from experiments.evaluation.bench_summary import win_share
from experiments.evaluation.control import ControlConfig, best_fixed_spec, ensure_best_thetas
from experiments.infra.artifacts import claim, manifest_config, slug, write_json, write_text
from experiments.infra.checks import check_counts
from experiments.infra.parallel import Pool
from experiments.potential.family import (
    FamilyConfig,
    collect_family,
    expand_tracks,
    load_family,
    parse_cars,
)

HELDOUT_RANDOM = "random:10000-10019"
"""Procedural tracks of the default held-out set: seeds outside any training range we use."""


def default_heldout_tracks(training_tracks) -> list[str]:
    """:data:`HELDOUT_RANDOM` and every TUMFTM circuit of the local folder (if any) that is not
    among ``training_tracks``."""
    from racing_env.tracks import tumftm_dir

    tracks = expand_tracks([HELDOUT_RANDOM])
    d = tumftm_dir()
    if d is not None:
        trained = set(training_tracks)
        tracks += [
            f"tumftm:{p.stem}" for p in sorted(d.glob("*.csv")) if f"tumftm:{p.stem}" not in trained
        ]
    return [t for t in tracks if t not in set(training_tracks)]


@dataclass(frozen=True)
class GeneralReportConfig:
    """Sizes of the report (defaults: the full report; the tests use tiny ones).

    ``tracks``: held-out track specs (``random:A-B`` ranges allowed; empty: the defaults of
    :func:`default_heldout_tracks`). ``gap_races`` fresh races per field size of
    ``gap_cars``, ``gap_pairs`` deviations per field size. ``bench_cars`` field sizes of the
    N-car protocol, ``bench_rounds`` rounds of N races per track and N. ``default_races``
    races of the comparison on ``default`` (0 skips it). ``control_thetas`` and
    ``control_races``: the :class:`experiments.evaluation.control.ControlConfig` of the selection of
    the best fixed theta on held-out tracks the best-theta table lacks. ``control``: an agent
    spec that replaces that per-track selection as the control ego on every held-out track
    (empty: the per-track best fixed theta of the model's policy space)."""

    model: str = "general"
    tracks: tuple = ()
    gap_cars: tuple = (2, 3, 5)
    gap_races: int = 40
    gap_pairs: int = 20000
    heldout_seed: int = 1
    bench_cars: tuple = (2, 3, 5)
    bench_rounds: int = 1
    default_races: int = 99
    steps: int = 500
    seed: int = 0
    control_thetas: int = ControlConfig.thetas
    control_races: int = ControlConfig.races
    control: str = ""

    def __post_init__(self):
        self.control_config()  # names a bad control_thetas / control_races
        if not isinstance(self.control, str):
            raise ValueError(
                f"GeneralReportConfig.control must be an agent spec, got {self.control!r}"
            )
        check_counts(self, ("gap_races", "gap_pairs", "bench_rounds", "steps"))
        if isinstance(self.default_races, bool) or not (
            isinstance(self.default_races, int) and self.default_races >= 0
        ):
            raise ValueError(
                f"GeneralReportConfig.default_races must be an integer >= 0, got "
                f"{self.default_races!r}"
            )
        for name in ("gap_cars", "bench_cars"):
            object.__setattr__(self, name, parse_cars(getattr(self, name)))
        object.__setattr__(self, "tracks", tuple(expand_tracks(self.tracks)) if self.tracks else ())
        if any(ch in str(self.model) for ch in ",="):
            raise ValueError(
                f"model {self.model!r}: a name or path without ',' or '=' "
                f"(it goes into an agent spec)"
            )

    def control_config(self, space: str = "paper") -> ControlConfig:
        """The selection of the best fixed theta on a held-out track in policy space ``space``
        (this report's steps)."""
        return ControlConfig(
            thetas=self.control_thetas, races=self.control_races, steps=self.steps, space=space
        )


ADDED_FIELDS = {"control": ""}
"""Config fields added after reports were first made, with their defaults: the manifest records
them only when they differ, so earlier report folders resume."""


ROLES = ("alpha", "control", "mpc_default")
"""Egos of the N-car races: the general model, the best fixed theta (the control) and the
``mpc`` agent at its default theta (an extra row)."""


def _model(name):
    from agents.potential import cached_model

    try:
        model = cached_model(name)
    except FileNotFoundError as exc:
        raise ValueError(str(exc)) from None
    if not model.general:
        raise ValueError(
            f"model {name!r} is a single-track model (trained on "
            f"{model.meta.get('track')!r} with {model.n_cars} cars); the report "
            f"needs a general one (trained on a family collection)"
        )
    return model


def heldout_tracks(cfg: GeneralReportConfig, model) -> list[str]:
    """The held-out tracks of the report; a training track among them is a ValueError."""
    training = model.meta.get("tracks", [])
    tracks = list(cfg.tracks) or default_heldout_tracks(training)
    seen = sorted(set(tracks) & set(training))
    if seen:
        raise ValueError(
            f"held-out tracks {seen} were used to train the model; the report "
            f"measures on tracks the model never saw"
        )
    if not tracks:
        raise ValueError("no held-out tracks: give --tracks")
    return tracks


# ---------------------------------------------------------------------------- 1. the gap
def gap_by_cars(model, heldout_dir, cfg: GeneralReportConfig) -> dict:
    """Per field size of the held-out collection: gap statistics relative to the model's
    value range (:func:`experiments.potential.train_general.family_gaps`)."""
    from experiments.potential.train_general import FamilyData, family_gaps

    groups, _ = load_family(heldout_dir)
    data = FamilyData(groups)
    vr = model.meta.get("metrics", {}).get("value_range")
    if not vr or not np.isfinite(vr) or vr <= 0:
        raise ValueError(f"model has no positive value_range in its metrics ({vr!r}); retrain it")
    out = {"value_range_model": float(vr), "by_cars": {}}
    for N in data.cars:
        races = np.flatnonzero(data.race_n == N)
        g = family_gaps(model, data, races, cfg.gap_pairs, cfg.seed + N, value_range=vr)
        out["by_cars"][str(N)] = {
            "races": int(len(races)),
            "pairs": g["val_pairs"],
            "tracks": sorted({data.track_spec(int(r)) for r in races}),
            "value_range_heldout": g["value_range_measured"],
            **{
                k: g[k]
                for k in (
                    "gap_rel_median",
                    "gap_rel_p95",
                    "gap_rel_max",
                    "gap_rel_within_10pct",
                    "const_rel_median",
                    "const_rel_p95",
                    "sign_agreement",
                )
            },
        }
    return out


# ---------------------------------------------------------------------------- 2, 3. races
def control_spec(cfg: GeneralReportConfig, space: str = "paper") -> str:
    """The control ego of part 2: ``cfg.control``, else the best fixed theta of the track in
    policy space ``space`` (:func:`experiments.evaluation.control.best_fixed_spec`)."""
    return cfg.control or best_fixed_spec(space)


def single_track_model(space: str = "paper") -> str:
    """The shipped single-track model of policy space ``space`` (part 3's opponents)."""
    from agents.alpha_agent import AUTO_MODELS

    return AUTO_MODELS[space][0]


def _bench_runs(cfg: GeneralReportConfig, tracks, out: Path, space: str = "paper") -> dict:
    """name -> BenchRun of every race set of parts 2 and 3 (the control and part 3's
    single-track model of policy space ``space``, the general model's)."""
    ego = f"alpha:model={cfg.model}"
    runs = {}
    for track in tracks:
        for N in cfg.bench_cars:
            for role, who in zip(ROLES, (ego, control_spec(cfg, space), "mpc")):
                bc = BenchConfig(
                    ego=who,
                    opponents="mpc",
                    races=N * cfg.bench_rounds,
                    steps=cfg.steps,
                    track=track,
                    seed=cfg.seed,
                    n_cars=N,
                )
                runs[("field", track, N, role)] = BenchRun(
                    out / "bench" / f"{slug(track)}_{N}cars" / role, bc
                )
    if cfg.default_races:
        single = f"alpha:model={single_track_model(space)}"
        for role, who in (("general", ego), ("control", single)):
            bc = BenchConfig(
                ego=who,
                opponents=single,
                races=cfg.default_races,
                steps=cfg.steps,
                track="default",
                seed=cfg.seed,
            )
            runs[("default", role)] = BenchRun(out / "default" / role, bc)
    return runs


def _ego_wins(summaries) -> dict:
    """Ego wins summed over benchmark summaries, with a Wilson 95% interval, and the mean
    margin over the best opponent [m]."""
    wins = sum(s["wins"]["ego"]["wins"] for s in summaries)
    races = sum(s["races"] for s in summaries)
    margin = sum(s["margin_m"]["mean"] * s["races"] for s in summaries) / races
    return {**win_share(wins, races), "margin_m_mean": float(margin)}


def _wins_by_start(summaries) -> dict:
    """Ego wins split by start order, summed over benchmark summaries: ``front`` from R1,
    ``behind`` from every later region (pace wins from the front; from behind a car must
    pass), each ``{"wins", "races"}``."""
    out = {"front": {"wins": 0, "races": 0}, "behind": {"wins": 0, "races": 0}}
    for s in summaries:
        for region, w in s["by_region"].items():
            key = "front" if region == "R1" else "behind"
            out[key]["wins"] += int(w["ego"]["wins"])
            out[key]["races"] += int(w["ego"]["races"])
    return out


def field_results(runs: dict, cfg: GeneralReportConfig, tracks) -> dict:
    """Part 2: per N, the ego's wins of alpha and of the control over all held-out tracks,
    and per track."""
    out = {}
    for N in cfg.bench_cars:
        per = {
            role: {t: runs[("field", t, N, role)].write_summary() for t in tracks} for role in ROLES
        }
        out[str(N)] = {
            "chance": 1.0 / N,
            **{role: _ego_wins(per[role].values()) for role in per},
            "by_start": {role: _wins_by_start(per[role].values()) for role in per},
            "by_track": {
                t: {role: per[role][t]["wins"]["ego"]["wins"] for role in per}
                | {"races": per["alpha"][t]["races"]}
                for t in tracks
            },
        }
    return out


def default_results(runs: dict) -> dict:
    """Part 3: wins of every car in the general-vs-default races and in the control."""
    out = {}
    for role in ("general", "control"):
        s = runs[("default", role)].write_summary()
        out[role] = {
            "wins": s["wins"],
            "races": s["races"],
            "margin_m": s["margin_m"],
            "ego": s["config"]["ego"],
            "opponents": s["config"]["opponents"],
        }
    return out


# ---------------------------------------------------------------------------- driver
def general_report(
    cfg: GeneralReportConfig,
    out_dir="results/general",
    pool: Pool = Pool(),
    command: str | None = None,
    control_dir=None,
) -> dict:
    """Run (or resume) the three parts into ``out_dir``; returns ``summary.json``'s content.
    ``command`` (the command line that made it) goes into the summary. The best fixed theta
    of a held-out track the best-theta table lacks is selected into ``control_dir`` (default
    ``out_dir/control``) and installed first."""
    model = _model(cfg.model)
    space = model.space.name
    tracks = heldout_tracks(cfg, model)
    specs = [f"alpha:model={cfg.model}", "mpc"] + ([cfg.control] if cfg.control else [])
    check_agent_specs(
        specs + [f"alpha:model={single_track_model(space)}"] if cfg.default_races else specs
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    claim(
        out / "manifest.json",
        {"config": manifest_config(cfg, ADDED_FIELDS), "heldout_tracks": tracks},
        "a general-model report",
    )
    t0 = time.perf_counter()
    # the control on every held-out track: selected first where the table lacks it
    control_dir = Path(control_dir) if control_dir is not None else out / "control"
    best = (
        {}
        if cfg.control
        else ensure_best_thetas(tracks, cfg.control_config(space), control_dir, pool)
    )
    # the held-out races are drawn as the model's own were (space, start regions, paces)
    collected = model.meta.get("data", {}).get("collect", {})
    fam = FamilyConfig(
        races=cfg.gap_races * len(cfg.gap_cars),
        tracks=tuple(tracks),
        cars=cfg.gap_cars,
        steps=cfg.steps,
        seed=cfg.heldout_seed,
        races_per_shard=1,
        space=space,
        start=collected.get("start", "paper"),
        pace=collected.get("pace", "box"),
    )
    collect_family(fam, out / "heldout", pool)
    gap = gap_by_cars(model, out / "heldout", cfg)
    write_json(out / "gap.json", gap)
    runs = _bench_runs(cfg, tracks, out, space)
    run_many(runs, pool)
    summary = {
        "config": json.loads(json.dumps(asdict(cfg))),
        "space": space,
        "control": control_spec(cfg, space),
        "single_track_model": single_track_model(space),
        "model": _model_info(model),
        "heldout_tracks": tracks,
        "gap": gap,
        "best_fixed_theta": {
            t: {
                "theta": e["theta"],
                "env": e["env"],
                "selection": e["selection"]["file"],
                "sha256": e["selection"]["sha256"],
            }
            for t, e in best.items()
        },
        "field": field_results(runs, cfg, tracks),
        "default": default_results(runs) if cfg.default_races else None,
        "command": command or f"alpha-racer general-report --model {cfg.model} --out {out_dir}",
        "seconds_this_run": time.perf_counter() - t0,
    }
    write_json(out / "summary.json", summary)
    write_text(out / "summary.md", summary_markdown(summary))
    return summary


def _model_info(model) -> dict:
    m = model.meta
    return {
        "feature_set": m["feature_set"],
        "feature_version": m["feature_version"],
        "tracks": len(m["tracks"]),
        "track_specs": m.get("track_specs"),
        "n_cars_range": m["n_cars_range"],
        "races": m["data"]["races"],
        "command": m.get("command"),
    }


def wins_text(w: dict) -> str:
    return (
        f"{w['wins']}/{w['races']} ({100 * w['fraction']:.0f}%, "
        f"{100 * w['ci95'][0]:.0f}-{100 * w['ci95'][1]:.0f}%)"
    )


def summary_markdown(s: dict) -> str:
    c, m, g = s["config"], s["model"], s["gap"]
    tracks = s["heldout_tracks"]
    space = s.get("space", "paper")
    ctrl = s.get("control", best_fixed_spec(space))
    ctrl_name = f"`{ctrl}`" if c.get("control") else "best fixed theta"
    single = s.get("single_track_model", "default")
    lines = [
        f"# General alpha-potential on held-out tracks (`{c['model']}`)",
        "",
        f"Model ({space} policy space): trained on {m['races']} races on {m['tracks']} tracks "
        f"({' '.join(m['track_specs'] or [])}) with {m['n_cars_range'][0]}.."
        f"{m['n_cars_range'][1]} cars. Held out (never used in training or tuning): "
        f"{len(tracks)} tracks: {', '.join(tracks)}.",
        "",
        "## Approximation gap",
        "",
        f"|dPhi - dV_i| relative to the model's value range ({g['value_range_model']:.3f} m), "
        f"{c['gap_pairs']} unilateral deviations per field size at states of fresh races "
        f"({c['steps']} steps, seed {c['heldout_seed']}) on the held-out tracks.",
        "",
        "| cars | races | gap median | gap p95 | constant median | constant p95 "
        "| range of V on these races [m] |",
        "|---|---|---|---|---|---|---|",
    ]
    for N, r in g["by_cars"].items():
        lines.append(
            f"| {N} | {r['races']} | {100 * r['gap_rel_median']:.2f}% | "
            f"{100 * r['gap_rel_p95']:.2f}% | {100 * r['const_rel_median']:.2f}% | "
            f"{100 * r['const_rel_p95']:.2f}% | {r['value_range_heldout']:.3f} |"
        )
    lines += [
        "",
        "## alpha (general) against the best fixed theta, N cars",
        "",
        f"On every held-out track, {c['bench_rounds']} round(s) of N races of "
        f"{c['steps']} steps: the ego from each of the N start regions once per round, "
        f"N - 1 `mpc` opponents (fixed default theta, zeta 0.9) in the other regions "
        f"front to back. The control races the same races with "
        + (
            f"`{ctrl}` as ego on every track"
            if c.get("control")
            else f"the best fixed theta on that track as ego (`{ctrl}`, chosen by "
            f"`alpha-racer control`)"
        )
        + "; the extra row with an `mpc` ego at its default theta (zeta 0.9). Ego wins with "
        "Wilson 95% intervals; margin = ego minus the best opponent.",
        "",
        f"| cars | alpha (general) ego wins | margin m | {ctrl_name} ego wins (control) "
        "| margin m | `mpc` (zeta 0.9) ego wins | margin m | chance |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for N, r in s["field"].items():
        lines.append(
            f"| {N} | "
            + " | ".join(
                f"{wins_text(r[role])} | {r[role]['margin_m_mean']:+.2f}" for role in ROLES
            )
            + f" | {100 * r['chance']:.0f}% |"
        )
    if all("by_start" in r for r in s["field"].values()):
        lines += [
            "",
            "The same wins by start order: from R1 (pace alone can win there) and from behind "
            "(R2 and later: the ego must pass).",
            "",
            f"| cars | alpha (general): from R1 | from behind | {ctrl_name}: from R1 "
            "| from behind | `mpc` (zeta 0.9): from R1 | from behind |",
            "|---|---|---|---|---|---|---|",
        ]
        for N, r in s["field"].items():
            lines.append(
                f"| {N} | "
                + " | ".join(
                    f"{b['wins']}/{b['races']}"
                    for role in ROLES
                    for b in (r["by_start"][role]["front"], r["by_start"][role]["behind"])
                )
                + " |"
            )
    lines += [
        "",
        f"Ego wins per track (alpha / {ctrl_name} / `mpc` at zeta 0.9, of the races "
        "per track), and the best fixed theta (its parameters in the order of the space):",
        "",
        "| track | " + " | ".join(f"{N} cars" for N in s["field"]) + " | best fixed theta |",
        "|---" * (len(s["field"]) + 2) + "|",
    ]
    for t in tracks:
        th = s.get("best_fixed_theta", {}).get(t)
        th = ", ".join(f"{v:.3g}" for v in th["theta"].values()) if th else "-"
        lines.append(
            f"| `{t}` | "
            + " | ".join(
                " / ".join(str(r["by_track"][t][role]) for role in ROLES)
                + f" of {r['by_track'][t]['races']}"
                for r in s["field"].values()
            )
            + f" | {th} |"
        )
    d = s["default"]
    if d:
        lines += [
            "",
            f"## alpha (general) against the single-track `{single}` model on `default`",
            "",
            f"The paper's 3-car protocol ({c['default_races']} races of {c['steps']} "
            f"steps): the ego against two `alpha:model={single}` cars; the control "
            f"races the same races with the `{single}` model as ego.",
            "",
            "| ego | ego wins | O1 wins | O2 wins | ego margin m |",
            "|---|---|---|---|---|",
        ]
        for role in ("general", "control"):
            r = d[role]
            lines.append(
                f"| `{r['ego']}` | {wins_text(r['wins']['ego'])} | {r['wins']['O1']['wins']} "
                f"| {r['wins']['O2']['wins']} | {r['margin_m']['mean']:+.2f} |"
            )
    lines += ["", f"Command: `{s['command']}` (this run: {s['seconds_this_run'] / 60:.1f} min)."]
    return "\n".join(lines) + "\n"
