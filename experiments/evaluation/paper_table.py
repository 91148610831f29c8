"""The paper's Table 1 (``alpha-racer bench --paper-table``): its five cases, each a benchmark
of the ego against two opponents of one kind, the table of their results beside the paper's,
and the comparison of several egos over the same races (``comparison.md``)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from experiments.evaluation.bench import BenchRun, run_many
from experiments.evaluation.bench_config import REGIONS, BenchConfig, check_agent_specs
from experiments.evaluation.bench_summary import wins_text
from experiments.infra.artifacts import (
    read_jsonl,
    record_run,
    write_json,
    write_text,
)
from experiments.infra.parallel import Pool


@dataclass(frozen=True)
class PaperCase:
    opponents: str
    title: str
    paper_wins: tuple[int, int, int]  # the paper's Table 1: ego, O1, O2 wins of 99


#: The paper's Table 1, ego = ``alpha`` (gamma 0.99, 4000 races) in every case.
PAPER_CASES = {
    "I": PaperCase(
        "alpha:model=gamma0.98", "Opponents with low gamma (alpha, gamma 0.98)", (61, 28, 10)
    ),
    "II": PaperCase(
        "alpha:model=gamma0.995", "Opponents with high gamma (alpha, gamma 0.995)", (52, 40, 7)
    ),
    "III": PaperCase(
        "alpha:model=races400", "Opponents trained with less data (alpha, 400 races)", (76, 16, 7)
    ),
    "IV": PaperCase("ibr", "Opponents using IBR (6 rounds, 2 s horizon)", (73, 22, 4)),
    "V": PaperCase("ppo", "Opponents trained by self-play RL (PPO)", (91, 7, 1)),
}


def paper_cases(space: str = "paper", vehicle_class: str = "orca") -> dict[str, PaperCase]:
    """The paper's five cases in policy space ``space``: :data:`PAPER_CASES` in the paper's
    space; in another, the learned opponents of cases I-III are that space's variants of the
    same kind (``alpha:model=gamma0.98`` becomes ``alpha:space=extended,model=
    extended_gamma0.98``: same discount or data, trained on the space's races), while IBR
    and PPO stay as they are. For ``vehicle_class="fullsize"`` cases I-III are the variants
    of the class's shipped model (``alpha:model=fullsize_monza_gamma0.98``, trained on its
    races; its space is the model's own) and IBR and PPO race in the class (``ppo``: the
    class's shipped checkpoint)."""
    from agents.alpha_agent import CLASS_MODELS
    from agents.reference import policy_space

    space = policy_space(space).name  # names the choices if unknown
    if vehicle_class not in ("orca", *CLASS_MODELS):
        raise ValueError(
            f"paper cases for vehicle class {vehicle_class!r}: expected one of "
            f"{', '.join(('orca', *CLASS_MODELS))}"
        )
    if space == "paper" and vehicle_class == "orca":
        return dict(PAPER_CASES)
    prefix = "alpha:model="
    out = {}
    for name, case in PAPER_CASES.items():
        if case.opponents.startswith(prefix):
            model = case.opponents[len(prefix) :]
            if vehicle_class == "orca":
                spec, kind = f"alpha:space={space},model={space}_{model}", f"{space} space"
            else:
                spec, kind = f"alpha:model={CLASS_MODELS[vehicle_class]}_{model}", vehicle_class
            case = PaperCase(
                spec, case.title.replace("(alpha,", f"(alpha, {kind},"), case.paper_wins
            )
        out[name] = case
    return out


def paper_table(
    out_dir,
    ego: str = "alpha",
    races: int = 99,
    steps: int = 500,
    track: str = "default",
    seed: int = 0,
    cases=None,
    pool: Pool = Pool(),
    space: str = "paper",
    vehicle_class: str = "orca",
    wake: float | None = None,
) -> dict:
    """The paper's five cases (or ``cases``, names of :data:`PAPER_CASES`) with the
    opponents of policy space ``space`` and ``vehicle_class`` (:func:`paper_cases`) in
    ``out_dir/case_<name>``, all races in one pool, in that class's world (``wake``: its
    strength, None the class's); writes ``out_dir/paper_table.md`` and ``paper_table.json``
    and returns the latter's content."""
    from agents.reference import policy_space

    space = policy_space(space).name  # the name, as paper_table.json records it
    table_cases = paper_cases(space, vehicle_class)
    cases = list(table_cases) if cases is None else list(cases)
    unknown = [c for c in cases if c not in table_cases]
    if unknown:
        raise ValueError(f"unknown paper cases {unknown}; choose from {list(table_cases)}")
    out = Path(out_dir)
    configs = {
        c: BenchConfig(
            ego=ego,
            opponents=table_cases[c].opponents,
            races=races,
            steps=steps,
            track=track,
            seed=seed,
            vehicle_class=vehicle_class,
            wake=wake,
        )
        for c in cases
    }
    check_agent_specs([ego] + [cfg.opponents for cfg in configs.values()], [track], vehicle_class)
    runs = {c: BenchRun(out / f"case_{c}", cfg) for c, cfg in configs.items()}
    todo = sum(len(run.missing()) for run in runs.values())
    t0 = time.perf_counter()
    run_many(runs, pool)
    wall = time.perf_counter() - t0
    history = out / "runs.jsonl"
    if todo:  # every invocation that raced: the table's total wall time
        record_run(history, {"cases": cases}, todo, wall, pool)
    past = read_jsonl(history)
    table = {
        "ego": ego,
        "space": space,
        **({} if vehicle_class == "orca" else {"vehicle_class": vehicle_class}),
        "races": races,
        "steps": steps,
        "track": track,
        "seed": seed,
        "workers": pool.workers,
        "backend": pool.backend,
        "wall_seconds_this_run": wall,
        "runs": past,
        "cases": {
            c: {
                "opponents": table_cases[c].opponents,
                "title": table_cases[c].title,
                "paper_wins": list(table_cases[c].paper_wins),
                "summary": runs[c].write_summary(),
            }
            for c in cases
        },
    }
    write_json(out / "paper_table.json", table)
    write_text(out / "paper_table.md", paper_table_markdown(table))
    return table


def paper_table_markdown(table: dict) -> str:
    lines = [
        "# Head-to-head benchmark: the paper's Table 1",
        "",
        f"Ego `{table['ego']}` against two opponents of one kind; {table['races']} races per "
        f"case of {table['steps']} steps ({table['steps'] / 10:.0f} s), the ego starting "
        f"from R1, R2, R3 in turn (race k from R(k mod 3 + 1)), O1 always ahead of O2; "
        f"won by the largest "
        f"total progress. Wins with Wilson 95% intervals; `paper` is the paper's Table 1."
        + (
            f" Class `{table['vehicle_class']}` on `{table['track']}`."
            if "vehicle_class" in table
            else ""
        ),
        "",
        "| case | opponents | ego wins | O1 wins | O2 wins | paper (ego/O1/O2) "
        "| ego wins from R1 / R2 / R3 | ego margin m | contacts ego/opp | off-track ego/opp "
        "| ms/decision ego/opp |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c, case in table["cases"].items():
        s = case["summary"]
        w = s["wins"]
        reg = " / ".join(
            str(s["by_region"][r]["ego"]["wins"]) if r in s["by_region"] else "-" for r in REGIONS
        )
        opp = lambda key: 0.5 * (s[key]["O1"] + s[key]["O2"])  # noqa: B023
        lines.append(
            f"| {c} | `{case['opponents']}` | {wins_text(w['ego'])} | {w['O1']['wins']} | "
            f"{w['O2']['wins']} | {'/'.join(map(str, case['paper_wins']))} | {reg} | "
            f"{s['margin_m']['mean']:+.2f} | {s['contacts']['ego']:.1f}/{opp('contacts'):.1f} | "
            f"{s['off_tracks']['ego']:.1f}/{opp('off_tracks'):.1f} | "
            f"{s['decision_ms']['ego']:.1f}/{opp('decision_ms'):.1f} |"
        )
        if not s["complete"]:
            lines[-1] += f" (partial: {s['races']} of {s['config']['races']} races)"
    runs = table.get("runs", [])
    total = sum(r["wall_seconds"] for r in runs)
    simulated = sum(r["races_simulated"] for r in runs)
    race_cpu = sum(c["summary"]["race_seconds_total"] for c in table["cases"].values())
    lines += [
        "",
        f"Wall time: {total / 60:.1f} min for the {simulated} races simulated over "
        f"{len(runs)} invocation(s) (`runs.jsonl`); the races themselves took "
        f"{race_cpu / 60:.1f} worker-minutes.",
    ]
    return "\n".join(lines) + "\n"


def comparison_markdown(tables: dict, note: str = "") -> str:
    """One table over paper tables run on the same races with different egos (``tables``:
    label -> ``paper_table.json`` content, the first label's cases in order): per case, each
    ego's wins, its wins by start region R1/R2/R3 and its mean margin over the best opponent
    [m]. ``note`` (a sentence) follows the description."""
    labels = list(tables)
    if not labels:
        raise ValueError("no paper tables to compare")
    first = tables[labels[0]]
    lines = [
        "# The same races with other egos: what maximising the potential adds",
        "",
        f"Every ego races the same {first['races']} races per case ({first['steps']} "
        f"steps, seed {first['seed']}, same start orders and opponents): "
        + ", ".join(f"{label} = `{t['ego']}`" for label, t in tables.items())
        + ". Wins of the races, then by the ego's start region R1 / R2 / R3 (R1 the "
        "front); margin: ego minus the best opponent, mean over the races [m]."
        + (f" {note}" if note else ""),
        "",
        "| case | opponents | "
        + " | ".join(f"{label} wins (R1/R2/R3)" for label in labels)
        + " | margin m ("
        + " / ".join(labels)
        + ") |",
        "|---|---|" + "---|" * (len(labels) + 1),
    ]
    for c, case in first["cases"].items():
        cells, margins = [], []
        for label in labels:
            s = tables[label]["cases"].get(c, {}).get("summary")
            if s is None:
                cells.append("-")
                margins.append("-")
                continue
            reg = "/".join(
                str(s["by_region"][r]["ego"]["wins"]) if r in s["by_region"] else "-"
                for r in REGIONS
            )
            cells.append(f"{s['wins']['ego']['wins']}/{s['races']} ({reg})")
            margins.append(f"{s['margin_m']['mean']:+.2f}")
        lines.append(
            f"| {c} | `{case['opponents']}` | " + " | ".join(cells) + f" | {' / '.join(margins)} |"
        )
    return "\n".join(lines) + "\n"
