"""The pass ladder (``alpha-racer ladder``): how close to its own pace the cars ahead may be
for the ego still to pass them.

In the style of the Indy Autonomous Challenge's passing competition: the ego starts from R2,
behind one of two followers that never yield (``followers``, default ``raceline``, the
racing-line follower; the other starts in R3, behind the ego), and the followers' pace is a
fraction of the ego's own solo pace, one *rung* per fraction (default 100%, 98%, 96%, 94%).
The ego's result is the **highest rung at which it wins at least half of its races from R2**
(``wins >= races / 2``, :func:`won_at_least_half`), or none.

Per track and ego:

1. **Calibration.** The ego's solo pace is its progress alone from the grid in ``steps``
   control periods (:func:`~experiments.evaluation.strategy.solo_pace`, ``seed``); with
   ``pace_of`` set, that spec's solo pace is the unit of every ego. For each rung r, the
   followers' pace knob (``knob``: a ``raceline`` follower's ``speed_scale``, its speed
   target over its race line's speed profile, or an ``mpc`` follower's ``zeta``) is searched
   so that a follower's solo progress over the same steps is r times the unit's, to within
   :data:`TOLERANCE` (0.2%) of that target: from the knob at 1, a proportional first guess,
   then secant steps (regula falsi with a bisection guard once the target is bracketed), at
   most :data:`MAX_SOLO_RACES` solo races per rung (:func:`propose`), within the knob's
   range (:data:`KNOB_RANGES`). Values are rounded to 4 decimals. A rung the followers
   cannot reach (no value in the range made them that fast: beyond some ``speed_scale`` the
   car, not the speed target, limits them) or that does not converge is reported as such
   (:func:`calibration_result`) and not raced, with the closest ratio.
2. **Races.** Each calibrated rung is one ``alpha-racer bench`` folder: the ego against two
   followers at the rung's knob value from ``regions`` (default R2 only; R2 R3 in turn
   with ``regions=("R2", "R3")``), ``races`` races per region. Race k has the seed of
   ``(seed, k)`` on every rung and for every ego, so the rungs differ only in the followers'
   pace.

Output folder (``out``, default ``results/ladder``; run again to resume):

* ``manifest.json``: the settings every record of the folder shares (races, regions, steps,
  seed, followers, knob, pace unit, class, wake); a run with others is refused. Egos, tracks and rungs may be
  added to a folder.
* ``solo.jsonl``: every solo race (the pace units and the followers at each value tried), one line
  each, appended as it finishes. The calibration is a deterministic function of these
  races, so a resumed run replays it from the file and races only the solo races it lacks.
* ``races/TRACK/EGO/rung_R/``: one bench folder per rung (manifest, ``races.jsonl``,
  ``states/``, summary); a killed run loses no finished race.
* ``calibration.json``: per track, ego and rung the solo races tried, the knob value
  chosen and the achieved follower / ego pace ratio.
* ``ladder.json`` and ``ladder.md``: per track and ego, wins from R2 per rung with the
  achieved ratio, passes and contacts, and the highest rung won at least half.
* ``runs.jsonl``: one line per invocation that raced (races simulated, wall time).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from agents.theta import THETA_HIGH, THETA_LOW
from experiments.evaluation.bench import BenchRun, run_many
from experiments.evaluation.bench_config import (
    BenchConfig,
    check_agent_specs,
    check_class_wake,
    check_spec_fields,
    drop_default_class,
)
from experiments.evaluation.strategy import PaceRun, solo_pace, with_option
from experiments.infra.artifacts import (
    check_track_specs,
    claim,
    env_version,
    record_run,
    slug,
    write_json,
    write_text,
)
from experiments.infra.checks import check_counts
from experiments.infra.parallel import Pool

SCHEMA_VERSION = 1
#: The followers' pace as fractions of the ego's solo pace, highest first.
RUNGS = (1.0, 0.98, 0.96, 0.94)
#: Largest rung (followers 50% faster than the ego alone).
MAX_RUNG = 1.5
#: The followers' pace knobs (``LadderConfig.knob``) and the range searched for each: the
#: ``raceline`` follower's ``speed_scale`` (it takes (0, 1.5]; above 1 it asks more of its
#: tyres than its own line does), or an ``mpc`` follower's ``zeta`` (the policy box's range).
KNOB_RANGES = {"speed_scale": (0.05, 1.5), "zeta": (float(THETA_LOW[1]), float(THETA_HIGH[1]))}
MIN_SCALE, MAX_SCALE = KNOB_RANGES["speed_scale"]
#: A calibration is done when the follower's solo progress is within this fraction of
#: its target (rung x the ego's solo progress).
TOLERANCE = 0.002
#: Solo races per rung's calibration at most, beyond the follower at speed_scale 1.
MAX_SOLO_RACES = 12
#: The start regions the ladder may race from (behind both followers or one).
LADDER_REGIONS = ("R2", "R3")
DEFINITION = (
    "the ego starts from R2, behind one follower (R1) and ahead of the other (R3), and "
    "neither yields; at rung r the followers' pace knob makes their solo progress from the "
    "grid over the race's steps r times the ego's (within {tol:g}%); an ego's rung is the "
    "highest rung at which it wins (the most progress at the end) at least half of its "
    "races from R2 (wins >= races / 2), or none"
)


@dataclass(frozen=True)
class LadderConfig:
    """The ladder: ``egos`` (agent specs) on ``tracks``, each among two ``followers`` (an
    agent spec taking ``knob``: the default ``raceline`` with ``speed_scale``, or an ``mpc``
    spec with ``knob="zeta"``; it must not set the knob, the ladder sets it) at each of
    ``rungs`` (the followers' solo pace as a fraction of the ego's, in (0, 1.5], distinct;
    stored highest first), ``races`` races per rung and start region of ``regions`` (R2,
    optionally R3; R2 must be one: the ladder is defined from R2) of ``steps`` control
    periods (0.1 s); ``seed`` fixes every race's start positions and agents' seeds (race k
    of every rung and ego has the seed of ``(seed, k)``) and the solo races'.
    ``vehicle_class`` and ``wake`` are the world of every race (the paper's 1:43 class by
    default; ``wake`` None: the class's, stored resolved), left out of :meth:`to_dict` for
    the paper's."""

    egos: tuple[str, ...] = ("mpc:theta=best",)
    tracks: tuple[str, ...] = ("default",)
    rungs: tuple[float, ...] = RUNGS
    races: int = 16
    regions: tuple[str, ...] = ("R2",)
    steps: int = 200
    seed: int = 0
    followers: str = "raceline"
    knob: str = "speed_scale"
    pace_of: str | None = None
    vehicle_class: str = "orca"
    wake: float | None = None

    def __post_init__(self):
        check_class_wake(self)
        if self.knob not in KNOB_RANGES:
            raise ValueError(
                f"LadderConfig.knob must be one of {', '.join(KNOB_RANGES)}, got {self.knob!r}"
            )
        for name in ("egos", "tracks", "rungs", "regions"):
            value = getattr(self, name)
            if isinstance(value, str) or not hasattr(value, "__iter__"):
                raise ValueError(f"LadderConfig.{name} must be a sequence, got {value!r}")
            object.__setattr__(self, name, tuple(value))
        check_counts(self, ("races", "steps"))
        check_counts(self, ("seed",), minimum=0)
        check_spec_fields(self, ("followers",))
        if self.pace_of is not None:
            check_spec_fields(self, ("pace_of",))
        bad = [e for e in self.egos if not isinstance(e, str) or not e.strip()]
        if not self.egos or bad:
            raise ValueError(
                f"LadderConfig.egos must be one or more agent spec strings, got bad "
                f"{bad or list(self.egos)!r}"
            )
        if len(set(self.egos)) != len(self.egos):
            twice = sorted({e for e in self.egos if self.egos.count(e) > 1})
            raise ValueError(f"LadderConfig.egos must be distinct; given twice: {twice}")
        params = self.followers.partition(":")[2].split(",")
        if self.knob in [item.partition("=")[0].strip() for item in params]:
            raise ValueError(
                f"LadderConfig.followers must not set {self.knob} (the ladder sets it per "
                f"rung), got {self.followers!r}"
            )
        check_track_specs(self.tracks)
        bad = [
            r
            for r in self.rungs
            if isinstance(r, bool)
            or not isinstance(r, (int, float))
            or not math.isfinite(r)
            or not 0 < r <= MAX_RUNG
        ]
        if not self.rungs or bad:
            raise ValueError(
                f"LadderConfig.rungs must be the followers' solo pace as fractions of the "
                f"ego's, each a number in (0, {MAX_RUNG:g}], got bad {bad or list(self.rungs)!r}"
            )
        if len(set(self.rungs)) != len(self.rungs):
            twice = sorted({r for r in self.rungs if self.rungs.count(r) > 1}, reverse=True)
            raise ValueError(f"LadderConfig.rungs must be distinct; given twice: {twice}")
        object.__setattr__(self, "rungs", tuple(sorted(map(float, self.rungs), reverse=True)))
        if (
            not self.regions
            or any(r not in LADDER_REGIONS for r in self.regions)
            or len(set(self.regions)) != len(self.regions)
            or "R2" not in self.regions
        ):
            raise ValueError(
                f"LadderConfig.regions must be distinct start regions of "
                f"{', '.join(LADDER_REGIONS)} including R2 (the ladder is defined from R2), "
                f"got {list(self.regions)}"
            )

    def to_dict(self) -> dict:
        d = asdict(self)
        for name in ("egos", "tracks", "rungs", "regions"):
            d[name] = list(d[name])
        return drop_default_class(d)

    def pace_unit(self, ego: str) -> str:
        """The spec whose solo pace the rungs of ``ego`` are fractions of: ``pace_of`` when
        set (one unit for every ego: their ladders are raced against the same followers, and
        an ego that cannot race alone, such as a 3-car alpha model, gets a ladder), else the
        ego itself."""
        return self.pace_of if self.pace_of is not None else ego

    def follower_spec(self, scale: float) -> str:
        """The followers' spec with the knob at ``scale`` (rounded to 4 decimals, the
        canonical form every record uses: ``raceline:speed_scale=0.9612``)."""
        return with_option(self.followers, self.knob, scale_text(scale))

    def bench_config(self, track: str, ego: str, scale: float) -> BenchConfig:
        """The races of one rung: ``ego`` behind two followers at ``scale``."""
        return BenchConfig(
            ego=ego,
            opponents=self.follower_spec(scale),
            races=self.races * len(self.regions),
            steps=self.steps,
            track=track,
            seed=self.seed,
            ego_regions=self.regions,
            vehicle_class=self.vehicle_class,
            wake=self.wake,
        )

    def shared(self) -> dict:
        """What every record of an output folder shares (its manifest)."""
        d = self.to_dict()
        for name in ("egos", "tracks", "rungs"):
            del d[name]
        return d


def scale_text(scale: float) -> str:
    """``scale`` rounded to 4 decimals as the spec writes it (``1``, ``0.95``, ``0.9612``)."""
    return f"{round(float(scale), 4):.4f}".rstrip("0").rstrip(".")


def rung_folder(out, track: str, ego: str, rung: float) -> Path:
    return Path(out) / "races" / slug(track) / slug(ego) / f"rung_{rung:g}"


# ---------------------------------------------------------------------------- calibration
def _err(progress: float, target: float) -> float:
    return progress / target - 1.0


def propose(
    points,
    target: float,
    tol: float = TOLERANCE,
    bounds: tuple[float, float] = (MIN_SCALE, MAX_SCALE),
) -> float | None:
    """The next knob value to race alone for a follower whose solo progress should be
    ``target`` [m], given the ``points`` (``(scale, progress)``) raced so far; None when one
    is within ``tol`` of the target or no new scale can come closer (a bracket narrower than
    the rounding, or the scale range's end reached on the wrong side).

    Bracketed (points on both sides of the target): regula falsi in the narrowest bracket of
    neighbouring scales whose progress rises with the scale (a falling one only without),
    bisection when its step lands in the bracket's outer tenths. Not
    bracketed: the secant through the two points closest to the target, or a proportional
    step (progress taken as proportional to the scale) from the closest one when the secant
    is flat or falls; clipped to ``bounds`` (the knob's range, :data:`KNOB_RANGES`). Rounded to 4
    decimals (:func:`scale_text`)."""
    pts = sorted({round(s, 4): p for s, p in points}.items())
    if not pts or any(abs(_err(p, target)) <= tol for _, p in pts):
        return None
    brackets = [(a, b) for a, b in zip(pts, pts[1:]) if a[1] < target <= b[1]]
    # a falling bracket (a faster scale that went slower: off the line) only without a rising one
    brackets = brackets or [(a, b) for a, b in zip(pts, pts[1:]) if b[1] < target <= a[1]]
    if brackets:
        (sa, pa), (sb, pb) = min(brackets, key=lambda ab: ab[1][0] - ab[0][0])
        s = sa + (target - pa) * (sb - sa) / (pb - pa)
        if not sa + 0.1 * (sb - sa) <= s <= sb - 0.1 * (sb - sa):
            s = 0.5 * (sa + sb)
    else:
        near = sorted(pts, key=lambda sp: abs(sp[1] - target))
        s0, p0 = near[0]
        s = s0 * target / p0
        if len(near) > 1:
            s1, p1 = near[1]
            slope = (p1 - p0) / (s1 - s0)
            if slope > 0:
                s = s0 + (target - p0) / slope
        s = min(max(s, bounds[0]), bounds[1])
    s = round(s, 4)
    return None if any(s == sp[0] for sp in pts) else s


def calibration_result(points, target: float, tol: float = TOLERANCE) -> dict:
    """The outcome of a calibration from its ``points``: the scale closest to the target,
    its progress, and ``status``: ``ok`` (within ``tol``), ``unreachable`` (no scale tried
    reached the target's side: the followers were never that fast, or never that slow; the
    closest is then their limit as far as the search went) or ``not converged`` (the target
    was bracketed, but no scale came within ``tol``: progress jumps across it)."""
    s, p = min(points, key=lambda sp: (abs(_err(sp[1], target)), sp[0]))
    if abs(_err(p, target)) <= tol:
        status = "ok"
    elif all(q < target for _, q in points) or all(q > target for _, q in points):
        status = "unreachable"
    else:
        status = "not converged"
    return {"value": s, "progress_m": p, "status": status}


class SoloRun(PaceRun):
    """The ladder's solo races (``solo.jsonl``): one record per (spec, track) of the ladder's
    ``steps``, ``seed``, class and wake; :attr:`wanted` holds the tasks of the round being
    raced."""

    what = "the ladder's solo races"
    records_name = "solo.jsonl"

    def __init__(self, out_dir, config: LadderConfig):
        super().__init__(out_dir, config)
        self.wanted: list[tuple[str, str]] = []

    def tasks(self) -> list[tuple]:
        return list(dict.fromkeys(self.wanted))

    def race(self, wanted, pool: Pool, desc: str) -> dict:
        """Race the solo races of ``wanted`` ((spec, track) pairs) that the file lacks;
        returns every record by (spec, track)."""
        self.wanted = list(wanted)
        c = self.config
        args = (c.steps, c.seed, c.vehicle_class, c.wake)
        self.run_missing(solo_pace, lambda task: (*task, *args), pool, desc=desc, unit="race")
        return self.records()


def _progress(records: dict, spec: str, track: str, role: str) -> float:
    rec = records[(spec, track)]
    if rec["progress_m"] is None:
        raise ValueError(
            f"{role} {spec!r} cannot race alone on {track} ({rec['reason']}); the ladder's "
            f"rungs are fractions of the ego's solo pace"
        )
    return rec["progress_m"]


def calibrate(config: LadderConfig, out, pool: Pool) -> dict:
    """Every calibration of ``config`` (module docstring), the solo races it lacks raced
    round by round (one pool per round, every calibration's next scale at once) and stored
    in ``solo.jsonl``; returns ``{(track, ego, rung): calibration}``, each with the ego's
    (the pace unit's) and the followers' (at the knob's 1) solo progress, the target, the solo
    races tried (``points``: value, progress, ratio), the value chosen, its ``ratio`` and
    ``status``."""
    solo = SoloRun(out, config)
    base = config.follower_spec(1.0)
    units = list(dict.fromkeys(config.pace_unit(e) for e in config.egos))
    recs = solo.race(
        [(spec, t) for t in config.tracks for spec in (*units, base)],
        pool,
        "solo pace",
    )
    keys = [(t, e, r) for t in config.tracks for e in config.egos for r in config.rungs]
    role = "ego" if config.pace_of is None else "pace_of"
    ego_m = {
        (t, e): _progress(recs, config.pace_unit(e), t, role)
        for t in config.tracks
        for e in config.egos
    }
    base_m = {t: _progress(recs, base, t, "the followers") for t in config.tracks}
    points = {k: [(1.0, base_m[k[0]])] for k in keys}
    target = {k: k[2] * ego_m[k[:2]] for k in keys}
    for round_ in range(1, MAX_SOLO_RACES + 1):
        todo = {}
        for k in keys:
            s = propose(points[k], target[k], bounds=KNOB_RANGES[config.knob])
            if s is not None:
                todo[k] = s
        if not todo:
            break
        recs = solo.race(
            [(config.follower_spec(s), k[0]) for k, s in todo.items()],
            pool,
            f"calibration {round_}",
        )
        for k, s in todo.items():
            spec = config.follower_spec(s)
            points[k].append((s, _progress(recs, spec, k[0], "the followers")))
    out_cal = {}
    for k in keys:
        ego = ego_m[k[:2]]
        res = calibration_result(points[k], target[k])
        out_cal[k] = {
            "track": k[0],
            "ego": k[1],
            "rung": k[2],
            "ego_solo_m": ego,
            "followers_solo_m_at_1": base_m[k[0]],
            "target_m": round(target[k], 4),
            "points": [
                {"value": s, "progress_m": p, "ratio": round(p / ego, 5)} for s, p in points[k]
            ],
            "value": res["value"],
            "followers_spec": config.follower_spec(res["value"]),
            "ratio": round(res["progress_m"] / ego, 5),
            "status": res["status"],
        }
    return out_cal


# ---------------------------------------------------------------------------- report
def rung_row(cal: dict, run: BenchRun | None, out) -> dict:
    """One rung of one ego's ladder: its calibration and, raced, the ego's wins per start
    region, passes (clean and through contact, totals) and contacts (total)."""
    row = {
        "rung": cal["rung"],
        "value": cal["value"],
        "ratio": cal["ratio"],
        "status": cal["status"],
        "races": 0,
        "races_by_region": {},
        "wins_by_region": {},
        "passes": None,
        "passes_contact": None,
        "contacts": None,
        "won_half_from_R2": False,
        "folder": None,
    }
    if run is None:
        return row
    recs = [r for _, r in sorted(run.records_with_metrics().items())]
    regions = run.config.ego_regions
    row.update(
        races=len(recs),
        races_by_region={g: sum(r["ego_region"] == g for r in recs) for g in regions},
        wins_by_region={
            g: sum(r["ego_region"] == g and r["winner"] == "ego" for r in recs) for g in regions
        },
        passes=sum(r["passes"][0] for r in recs),
        passes_contact=sum(r["passes_contact"][0] for r in recs),
        contacts=sum(r["contacts"][0] for r in recs),
        folder=str(run.out.relative_to(out)),
    )
    row["won_half_from_R2"] = won_at_least_half(
        row["wins_by_region"]["R2"], row["races_by_region"]["R2"]
    )
    return row


def won_at_least_half(wins: int, races: int) -> bool:
    """The ladder's criterion: ``wins >= races / 2`` of at least one race (8 of 16 is won,
    7 of 16 not)."""
    return races > 0 and 2 * wins >= races


def ladder_markdown(table: dict) -> str:
    """``ladder.md`` from the ladder's table (``ladder.json``'s content)."""
    c = table["config"]
    regions = c["regions"]
    world = (
        f", class `{c['vehicle_class']}` with the wake at {c['wake']:g}"
        if "vehicle_class" in c
        else ""
    )
    pct = lambda r: f"{100 * r:g}%"
    lines = [
        "# Pass ladder",
        "",
        f"Definition: {table['definition']}.",
        "",
        f"Followers `{c['followers']}` ({c['knob']} set per rung); {c['races']} races per "
        f"rung from {' and '.join(regions)}"
        + (" in turn" if len(regions) > 1 else "")
        + f", {c['steps']} steps ({c['steps'] / 10:g} s), seed {c['seed']}{world}; the same "
        f"seeds on every rung and for every ego. "
        + (
            f"The rungs are fractions of `{c['pace_of']}`'s solo pace for every ego. "
            if c.get("pace_of")
            else ""
        )
        + "Cells: wins from R2 / races from R2 (achieved follower / unit solo pace).",
        "",
        "| track | ego | unit's solo m | "
        + " | ".join(pct(r) for r in c["rungs"])
        + " | highest rung won at least half |",
        "|---|---|---|" + "---|" * len(c["rungs"]) + "---|",
    ]
    for row in table["rows"]:
        cells = []
        for rg in row["rungs"]:
            if rg["status"] != "ok":
                cells.append(f"{rg['status']} ({rg['ratio']:.3f})")
            else:
                w, n = rg["wins_by_region"]["R2"], rg["races_by_region"]["R2"]
                cells.append(f"{w}/{n} ({rg['ratio']:.3f})")
        best = row["highest_rung_won"]
        lines.append(
            f"| `{row['track']}` | `{row['ego']}` | {row['ego_solo_m']:.2f} | "
            + " | ".join(cells)
            + f" | {'none' if best is None else pct(best)} |"
        )
    lines += [
        "",
        f"Per rung: the followers' {c['knob']}, wins per start region, the ego's passes "
        "(held 1 s; through contact apart) and contacts, totals over the rung's races.",
        "",
        f"| track | ego | rung | {c['knob']} | pace ratio | "
        + " | ".join(f"wins from {g}" for g in regions)
        + " | passes | through contact | contacts |",
        "|---|---|---|---|---|" + "---|" * len(regions) + "---|---|---|",
    ]
    for row in table["rows"]:
        for rg in row["rungs"]:
            dash = lambda v: "-" if v is None else str(v)
            wins = [
                f"{rg['wins_by_region'][g]}/{rg['races_by_region'][g]}"
                if rg["status"] == "ok"
                else "-"
                for g in regions
            ]
            lines.append(
                f"| `{row['track']}` | `{row['ego']}` | {pct(rg['rung'])} | "
                f"{rg['value']:g} | {rg['ratio']:.4f}"
                + ("" if rg["status"] == "ok" else f" ({rg['status']})")
                + " | "
                + " | ".join(wins)
                + f" | {dash(rg['passes'])} | {dash(rg['passes_contact'])} "
                f"| {dash(rg['contacts'])} |"
            )
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- driver
def ladder(config: LadderConfig, out_dir="results/ladder", pool: Pool = Pool()) -> dict:
    """Run (or resume) the ladder ``config`` into ``out_dir`` (module docstring): the
    calibrations' solo races, then every calibrated rung's missing races in one pool; writes
    ``calibration.json``, ``ladder.json`` and ``ladder.md`` and returns the latter's table
    with ``new_races``, the pass races this call ran."""
    check_agent_specs(
        [*config.egos, *([config.pace_of] if config.pace_of else []), config.follower_spec(1.0)],
        config.tracks,
        config.vehicle_class,
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    claim(
        out / "manifest.json",
        {"schema_version": SCHEMA_VERSION, "env": env_version(), **config.shared()},
        "a pass ladder",
    )
    cals = calibrate(config, out, pool)
    write_json(
        out / "calibration.json",
        {"tolerance": TOLERANCE, "calibrations": list(cals.values())},
    )
    runs = {
        k: BenchRun(rung_folder(out, *k), config.bench_config(k[0], k[1], cal["value"]))
        for k, cal in cals.items()
        if cal["status"] == "ok"
    }
    new = sum(len(run.missing()) for run in runs.values())
    t0 = time.perf_counter()
    run_many(runs, pool)
    wall = time.perf_counter() - t0
    if new:
        record_run(out / "runs.jsonl", {"config": config.to_dict()}, new, wall, pool)
    for run in runs.values():
        run.write_summary()
    rows = []
    for t in config.tracks:
        for e in config.egos:
            rungs = [rung_row(cals[(t, e, r)], runs.get((t, e, r)), out) for r in config.rungs]
            won = [rg["rung"] for rg in rungs if rg["won_half_from_R2"]]
            rows.append(
                {
                    "track": t,
                    "ego": e,
                    "ego_solo_m": cals[(t, e, config.rungs[0])]["ego_solo_m"],
                    "followers_solo_m_at_1": cals[(t, e, config.rungs[0])]["followers_solo_m_at_1"],
                    "rungs": rungs,
                    "highest_rung_won": max(won) if won else None,
                }
            )
    table = {
        "schema_version": SCHEMA_VERSION,
        "config": config.to_dict(),
        "definition": DEFINITION.format(tol=100 * TOLERANCE),
        "tolerance": TOLERANCE,
        "rows": rows,
    }
    write_json(out / "ladder.json", table)
    write_text(out / "ladder.md", ladder_markdown(table))
    return {**table, "new_races": new, "wall_seconds_this_run": wall}


def config_defaults() -> dict:
    """The :class:`LadderConfig` defaults by field name (the command line's defaults)."""
    return {f.name: f.default for f in fields(LadderConfig)}
