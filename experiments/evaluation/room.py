"""The room of a strategy suite (``alpha-racer room``): the rollout oracle
(:mod:`experiments.evaluation.oracle`) in the seats of a finished suite's races.

Issue 48 measures "alpha adds strategy" against the *room*: how much any state-dependent
choice of theta can gain over the best fixed theta in the same seats. This module races the
oracle in every race of the chosen benches of a finished ``alpha-racer strategy`` folder: the
same seed, start regions and opponents as the suite's ego, the oracle choosing among the
``base`` agent's theta and ``moves`` one-parameter moves of it
(:func:`~experiments.evaluation.oracle.candidate_moves`), every ``every`` periods with a
look-ahead of ``lookahead`` seconds. The base is the suite's control (the best fixed theta,
by default) or its ego, an ``mpc`` spec either way (the oracle chooses thetas).

Output, in ``SUITE/room/BASE_T{lookahead}_M{candidates}_k{every}/`` (run again to resume; a
killed run keeps every finished race): ``manifest.json``, ``races.jsonl`` (one record per
race: the oracle's progress, winner and choices) and ``room.md`` / ``room.json``: per bench
and track, the wins from each start region and mean margin of the oracle, the suite's ego and
its control in the same races, the room (the oracle's margin minus the base's, race by race)
and the share of it the other agent takes (its margin minus the base's over the room).

The oracle's races from the control (``base="control"``) depend on the control and the seats
alone, not on the suite's ego: a suite of another ego with the same control and settings
shares them (copy ``SUITE/room`` into its folder; its manifest does not name the ego), so a
new ego's share of the room costs no oracle race.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from agents.base import spec_params, spec_with
from agents.theta import MOVES, check_moves
from experiments.evaluation.oracle import candidate_moves, oracle_race
from experiments.evaluation.race import start_order
from experiments.evaluation.strategy import StrategyConfig, cells
from experiments.infra.artifacts import (
    ResumableRun,
    read_jsonl,
    write_json,
    write_npz,
    write_text,
)
from experiments.infra.parallel import Pool

#: Benches the room is measured in: the ego against fixed opponents. ``table1_*`` (IBR, PPO,
#: alpha opponents) are left out: their opponents' copies are costly and the issue's room
#: is the fixed theta's.
ROOM_BENCHES = ("pass", "equal", "defend")

#: How the oracle's rollouts drive the other cars (:class:`RoomConfig`): their own agents'
#: copies (None), the base's spec (``"self"``) or the suite's control (``"control"``).
MODELS = (None, "self", "control")


@dataclass(frozen=True)
class RoomConfig:
    """The oracle's settings: ``base`` (``"control"`` or ``"ego"``, the suite's agent whose
    theta the candidates start from), ``moves`` (0..len(MOVES) one-parameter moves of it),
    ``lookahead`` [s], ``every`` (control periods between choices), the ``benches`` of the
    suite to measure, ``races`` (the first N races of each bench; None: all), and ``model``:
    how the oracle's rollouts drive the other cars, by copies of their own agents (None, full
    information: the room), or by a model of them, ``"self"`` (the base's own spec: the
    oracle assumes nothing of them) or ``"control"`` (the suite's control spec)."""

    base: str = "control"
    moves: int = 4
    lookahead: float = 3.0
    every: int = 10
    benches: tuple[str, ...] = ROOM_BENCHES
    races: int | None = None
    model: str | None = None

    def __post_init__(self):
        object.__setattr__(self, "benches", tuple(self.benches))
        if self.base not in ("control", "ego"):
            raise ValueError(f"base must be 'control' or 'ego', got {self.base!r}")
        check_moves(self.moves)
        if isinstance(self.lookahead, bool) or not (
            isinstance(self.lookahead, (int, float)) and 0 < self.lookahead <= 60
        ):
            raise ValueError(f"lookahead must be a time in (0, 60] s, got {self.lookahead!r}")
        if isinstance(self.every, bool) or not (isinstance(self.every, int) and self.every >= 1):
            raise ValueError(f"every must be a number of control periods >= 1, got {self.every!r}")
        bad = [b for b in self.benches if b not in ROOM_BENCHES]
        if not self.benches or bad:
            raise ValueError(f"benches must be names of {', '.join(ROOM_BENCHES)}, got {bad}")
        if self.races is not None and (
            isinstance(self.races, bool) or not isinstance(self.races, int) or self.races < 1
        ):
            raise ValueError(f"races must be a positive number or None, got {self.races!r}")
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {MODELS}, got {self.model!r}")

    def folder_name(self) -> str:
        name = f"{self.base}_T{self.lookahead:g}_M{self.moves + 1}_k{self.every}"
        return name if self.model is None else f"{name}_model-{self.model}"


def suite_config(suite) -> StrategyConfig:
    """The :class:`StrategyConfig` of a finished suite folder (its ``strategy.json``); a
    ValueError naming the folder when there is none."""
    path = Path(suite) / "strategy.json"
    if not path.exists():
        raise ValueError(f"{suite} holds no finished strategy suite (no strategy.json)")
    return StrategyConfig(**json.loads(path.read_text())["config"])


def suite_races(suite, config: StrategyConfig, room: RoomConfig) -> dict:
    """The suite's races the room is measured in: ``{(bench, track): {"ego": [records],
    "control": [records]}}`` (the first ``room.races`` of each bench, by race number, the
    ego's and the control's in the same seats); a ValueError for a bench the suite did not
    run or a race it has not finished."""
    out: dict = {}
    for cell in cells(config):
        if cell.bench not in room.benches:
            continue
        path = cell.folder(suite) / "races.jsonl"
        # by race number, the last line of a race kept (a bench resumed where its states
        # were not stored races again and appends, as its own reader keeps the last)
        by_race = {r["race"]: r for r in read_jsonl(path)}
        recs = [by_race[k] for k in sorted(by_race)][: room.races]
        if not recs:
            raise ValueError(f"{path}: no finished races of {cell.bench!r} on {cell.track!r}")
        out.setdefault((cell.bench, cell.track), {})[cell.role] = recs
    missing = [b for b in room.benches if not any(k[0] == b for k in out)]
    if missing:
        raise ValueError(
            f"the suite in {suite} ran no {', '.join(missing)} (its scenarios: "
            f"{', '.join(config.scenarios)})"
        )
    for key, roles in out.items():
        if [r["race"] for r in roles["ego"]] != [r["race"] for r in roles["control"]]:
            raise ValueError(f"{key}: the ego's and the control's races differ; finish the suite")
    return out


def explicit_theta(spec: str, track: str, vehicle_class: str = "orca") -> str:
    """``spec`` with ``theta=best`` replaced by the best fixed theta of ``track`` (the
    circuit at ``vehicle_class``'s scale) written out (``mpc:theta=best`` ->
    ``mpc:q=..,zeta=..,s1=..,s2=..,s3=..``, the same car), so that its parameters can be
    moved; other specs unchanged."""
    if spec_params(spec)[1].get("theta") != "best":
        return spec
    from agents import make_agent_spec
    from agents.best_theta import PAPER, best_theta
    from agents.mpc_agent import MPCAgent
    from agents.theta import policy_space
    from racing_env.tracks import make_track

    agent = make_agent_spec(spec)
    space = agent.space if isinstance(agent, MPCAgent) else PAPER
    theta = best_theta(make_track(track, vehicle_class=vehicle_class), space=space)
    values = {k: repr(float(getattr(theta, k))) for k in policy_space(space).names}
    return spec_with(spec, drop=("theta",), **values)


def room_race(
    key: tuple,
    candidates: list[str],
    opponents: list[str],
    track: str,
    seed: int,
    regions: list[str],
    steps: int,
    room: RoomConfig,
    vehicle_class: str,
    wake: float,
    model: list[str] | None = None,
) -> dict:
    """One oracle race in the seats of a suite's race (pure: no file access): ``{"record":
    its JSON record, "observations": (C, D) float32, "scores": (C, M)}``, the oracle's
    observation and every candidate's look-ahead score at each of its C choices. ``model``:
    the agent specs the rollouts drive the opponents by (None: their own)."""
    t0 = time.perf_counter()
    res = oracle_race(
        candidates,
        opponents,
        track=track,
        seed=seed,
        order=start_order(regions, len(regions)),
        steps=steps,
        lookahead=room.lookahead,
        every=room.every,
        vehicle_class=vehicle_class,
        wake=wake,
        model=model,
    )
    record = {
        "bench": key[0],
        "track": key[1],
        "race": key[2],
        "seed": seed,
        "ego_region": regions[0],
        "candidates": list(candidates),
        **({} if model is None else {"model": list(model)}),
        "progress_m": [round(float(p), 4) for p in res.progress],
        "winner": int(res.winner),
        "choices": {str(k): v for k, v in sorted(Counter(res.choices).items())},
        "seconds": round(time.perf_counter() - t0, 2),
    }
    return {"record": record, "observations": res.observations, "scores": res.scores}


def choices_file(folder, record: dict) -> Path:
    """The file of a room folder ``folder`` that keeps the oracle's choices in the race of
    ``record`` (one of its ``races.jsonl``)."""
    track = record["track"].replace(":", "_")
    return Path(folder) / "choices" / f"{record['bench']}_{track}_{record['race']:05d}.npz"


SELECTION = ("benches", "races")
"""The :class:`RoomConfig` fields that select a room run's races but do not change them."""


class RoomRun(ResumableRun):
    """The oracle's races of one :class:`RoomConfig` in a suite's folder."""

    what = "oracle races of a strategy suite"
    records_name = "races.jsonl"

    def __init__(self, suite, room: RoomConfig, config: StrategyConfig):
        super().__init__(Path(suite) / "room" / room.folder_name(), room)
        self.suite_config = config
        self.races = suite_races(suite, config, room)
        stored = config.to_dict()
        if room.base == "control":  # the control's seats and opponents: any ego's suite
            stored.pop("ego")  # of the same control shares these races
        self._forget(ego=room.base == "control")
        # the benches and the number of races choose which races run, not how: a folder
        # grows by more races or another bench of the same oracle
        setting = {k: v for k, v in asdict(room).items() if k not in SELECTION}
        if room.model is None:  # folders written before there was a model hold none
            setting.pop("model")
        self.claim({"room": setting, "suite": stored})

    def _forget(self, ego: bool) -> None:
        """Drop from a folder's manifest what older versions stored and the races never
        depended on: the benches and the number of races, and (``ego``: the oracle's races
        from the control, shared by every suite of that control) the suite's ego."""
        path = self.manifest_path
        if path.exists():
            meta = json.loads(path.read_text())
            dropped = [meta.get("room", {}).pop(k, None) for k in SELECTION]
            if ego:
                dropped.append(meta.get("suite", {}).pop("ego", None))
            if any(d is not None for d in dropped):
                write_json(path, meta)

    def tasks(self) -> list[tuple]:
        return [
            (bench, track, rec["race"])
            for (bench, track), roles in self.races.items()
            for rec in roles["ego"]
        ]

    def record_key(self, record: dict) -> tuple:
        return (record["bench"], record["track"], record["race"])

    def add(self, result: dict) -> None:
        """Store one oracle race: its choices first (``choices/``: the oracle's observations
        and the candidates' scores, the data :mod:`experiments.learning.ranker` learns
        from), then its JSON line (a line means a finished race). Folders written before the
        choices were kept hold the lines alone."""
        rec = result["record"]
        write_npz(
            self.choices_path(rec),
            compressed=True,
            observations=result["observations"],
            scores=result["scores"],
        )
        super().add(rec)

    def choices_path(self, record: dict) -> Path:
        """Where the choices of the race of ``record`` are kept."""
        return choices_file(self.out, record)

    def task_args(self, task: tuple) -> tuple:
        bench, track, race = task
        roles = self.races[(bench, track)]
        ego = next(r for r in roles["ego"] if r["race"] == race)
        base = next(r for r in roles[self.config.base] if r["race"] == race)
        c = self.suite_config
        candidates = candidate_moves(
            explicit_theta(base["agents"][0], track, c.vehicle_class), self.config.moves
        )
        opponents = ego["agents"][1:]
        model = {None: None, "self": candidates[0], "control": c.control}[self.config.model]
        return (
            task,
            candidates,
            opponents,
            track,
            ego["seed"],
            ego["start_regions"],
            c.steps,
            self.config,
            c.vehicle_class,
            float(c.wake or 0.0),
            None if model is None else [model] * len(opponents),
        )


def _margin(progress) -> float:
    p = np.asarray(progress, dtype=float)
    return float(p[0] - p[1:].max())


def room_table(run: RoomRun) -> list[dict]:
    """One row per bench and track of the finished races: races, and for the oracle, the
    suite's ego and control, wins per ego start region and the mean margin [m]; the room
    (oracle minus base margin: mean, min, max) and the other agent's share of it."""
    done = run.records()
    rows = []
    for (bench, track), roles in run.races.items():
        recs = [
            done[(bench, track, r["race"])]
            for r in roles["ego"]
            if (bench, track, r["race"]) in done
        ]
        if not recs:
            continue
        races = {r["race"] for r in recs}
        by_role = {
            role: [r for r in roles[role] if r["race"] in races] for role in ("ego", "control")
        }
        row = {"bench": bench, "track": track, "races": len(recs), "base": run.config.base}
        agents = {"oracle": recs, **by_role}
        margins = {}
        for name, rs in agents.items():
            regions = sorted({r["ego_region"] for r in rs})
            won = [r for r in rs if (r["winner"] == 0 or r["winner"] == "ego")]
            row[f"{name}_wins"] = len(won)
            row[f"{name}_wins_by_region"] = {
                g: sum(r["ego_region"] == g for r in won) for g in regions
            }
            margins[name] = np.array(
                [_margin(r["progress_m"]) for r in sorted(rs, key=lambda r: r["race"])]
            )
            row[f"{name}_margin_m"] = round(float(margins[name].mean()), 2)
        base = run.config.base
        other = "ego" if base == "control" else "control"
        room = margins["oracle"] - margins[base]
        row["room_m"] = {
            "mean": round(float(room.mean()), 2),
            "min": round(float(room.min()), 2),
            "max": round(float(room.max()), 2),
        }
        gain = margins[other] - margins[base]
        row[f"{other}_gain_m"] = round(float(gain.mean()), 2)
        # the share only where the room is measurable: its mean over two standard errors
        se = float(room.std(ddof=1) / np.sqrt(len(room))) if len(room) > 1 else np.inf
        row["room_m"]["se"] = round(se, 2) if np.isfinite(se) else None
        row[f"{other}_share_of_room"] = (
            round(float(gain.mean() / room.mean()), 3) if room.mean() > 2.0 * se else None
        )
        # by the candidate's move, not its index: races of one folder may hold other
        # candidate lists (a duplicate left out by a later version)
        choices: Counter = Counter()
        order: dict[str, int] = {}  # each move in the order of the candidates
        for r in recs:
            names = r["candidates"]
            for i, name in enumerate(names):
                order.setdefault(_short(name, names[0]), i)
            for k, v in r["choices"].items():
                choices[_short(names[int(k)], names[0])] += v
        total = sum(choices.values()) or 1
        row["choice_share"] = {
            k: round(choices[k] / total, 3) for k in sorted(choices, key=order.__getitem__)
        }
        row["oracle_seconds_per_race"] = round(float(np.mean([r["seconds"] for r in recs])), 1)
        rows.append(row)
    return rows


def room_markdown(run: RoomRun, rows: list[dict]) -> str:
    """``room.md``: the table of :func:`room_table` with the settings it was measured at."""
    room, c = run.config, run.suite_config
    other = "ego" if room.base == "control" else "control"
    base_spec = c.control if room.base == "control" else c.ego
    kept = next(iter(run.records().values()), None)  # a move that changes nothing is left out
    moves = (
        [_short(spec, kept["candidates"][0]) for spec in kept["candidates"][1:]]
        if kept is not None
        else list(MOVES[: room.moves])
    )
    lines = [
        "# The room",
        "",
        f"The rollout oracle in the seats of the suite's races (ego `{c.ego}`, control "
        f"`{c.control}`, class `{c.vehicle_class}`, {c.steps} steps, seed {c.seed}): "
        f"{len(moves) + 1} candidates (`{base_spec}`, the {room.base}, and {len(moves)} "
        f"one-parameter moves of it: {', '.join(moves) or 'none'}), "
        f"a choice every {room.every} periods with a look-ahead of {room.lookahead:g} s. "
        f"Margin: the car's progress minus the best opponent's; room: the oracle's margin "
        f"minus the {room.base}'s, race by race (mean, min, max); share: the {other}'s gain over "
        f"the {room.base} over the room (means; shown where the room's mean exceeds two "
        f"standard errors); choices: the candidates the oracle kept (`base` the {room.base}'s "
        f"theta, the others by their move).",
        "",
        "| bench | track | races | oracle wins | ego wins | control wins | "
        "margin m: oracle / ego / control | room m: mean (min, max) | "
        f"{other}'s share of the room | oracle's choices | oracle s per race |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]

    def wins(row, name):
        by = row[f"{name}_wins_by_region"]
        return f"{row[f'{name}_wins']} ({' / '.join(f'{g} {n}' for g, n in by.items())})"

    for r in rows:
        share = r[f"{other}_share_of_room"]
        lines.append(
            f"| {r['bench']} | `{r['track']}` | {r['races']} | {wins(r, 'oracle')} | "
            f"{wins(r, 'ego')} | {wins(r, 'control')} | {r['oracle_margin_m']:+.1f} / "
            f"{r['ego_margin_m']:+.1f} / {r['control_margin_m']:+.1f} | "
            f"{r['room_m']['mean']:+.1f} ({r['room_m']['min']:+.1f}, {r['room_m']['max']:+.1f}) | "
            f"{'-' if share is None else f'{share:.0%}'} | "
            + ", ".join(f"`{k}` {v:.0%}" for k, v in r["choice_share"].items())
            + f" | {r['oracle_seconds_per_race']} |"
        )
    return "\n".join(lines) + "\n"


def _short(spec: str, base: str) -> str:
    """A candidate named by its move from the base candidate (``"base"`` for itself)."""
    if spec == base:
        return "base"
    mine, theirs = spec_params(spec)[1], spec_params(base)[1]
    moved = [f"{k}={v}" for k, v in mine.items() if theirs.get(k) != v]
    return ",".join(moved) or spec


def room(suite, config: RoomConfig, pool: Pool = Pool()) -> dict:
    """Run (or resume) the oracle in the suite ``suite`` (module docstring); writes
    ``room.md`` and ``room.json`` into its folder and returns the latter's content with
    ``new_races``."""
    suite_cfg = suite_config(suite)
    run = RoomRun(suite, config, suite_cfg)
    new = run.run_missing(room_race, run.task_args, pool, desc="oracle", unit="race")
    # the tables show every race the folder holds, of every bench, not only this call's (as
    # many of each bench's first races as cover them, so that a suite still racing its later
    # races does not stop the table)
    done = run.records()
    held = tuple(b for b in ROOM_BENCHES if any(key[0] == b for key in done))
    view = replace(config, benches=held, races=1 + max(k[2] for k in done)) if held else config
    rows = room_table(RoomRun(suite, view, suite_cfg))
    table = {"room": asdict(view), "suite": suite_cfg.to_dict(), "rows": rows}
    write_json(run.out / "room.json", table)
    write_text(run.out / "room.md", room_markdown(run, rows))
    return {**table, "new_races": new, "folder": str(run.out)}
