"""The control folder's summary: each track's selection (``<track>/selection.json``) gathered
into ``summary.json`` and ``summary.md``."""

from __future__ import annotations

import json
from pathlib import Path

from experiments.evaluation.bench_config import REGIONS
from experiments.evaluation.control_rule import RULE
from experiments.evaluation.policy_map_summary import OFF_TRACK_LIMIT
from experiments.infra.artifacts import (
    read_jsonl,
    slug,
    write_json,
    write_text,
)


def track_dir(out_dir, track: str) -> Path:
    """The folder of ``track``'s selection inside a control folder."""
    return Path(out_dir) / slug(track)


def write_summary(out_dir) -> dict:
    """``summary.json`` and ``summary.md`` over every track of the control folder that has a
    ``selection.json``; returns the former's content."""
    out = Path(out_dir)
    sels = [json.loads(p.read_text()) for p in sorted(out.glob("*/selection.json"))]
    manifest = json.loads((out / "manifest.json").read_text())
    summary = {
        "config": manifest["config"],
        "env": manifest["env"],
        "rule": RULE,
        "runs": read_jsonl(out / "runs.jsonl"),
        "tracks": {
            s["track"]: {
                "theta": s["winner"]["theta"],
                "index": s["winner"]["index"],
                "wins": s["winner"]["wins"],
                "races": s["winner"]["races"],
                "margin_m_mean": s["winner"]["margin_m_mean"],
                "candidates": len(s["candidates"]),
                "eligible_thetas": s["map"]["eligible_thetas"],
                "worker_seconds": s["worker_seconds"],
                "selection": str(track_dir(out, s["track"]) / "selection.json"),
            }
            for s in sels
        },
    }
    write_json(out / "summary.json", summary)
    write_text(out / "summary.md", summary_markdown(summary, sels))
    return summary


def summary_markdown(summary: dict, selections) -> str:
    from agents.theta import policy_space

    c = summary["config"]
    space = c.get("space", "paper")
    names = policy_space(space).names
    head = "" if space == "paper" else f" of the {space} policy space"
    lines = [
        f"# The best fixed theta{head} per track (the control)",
        "",
        f"Env `{summary['env']}`. Rule: {summary['rule']}. Map: {c['thetas']} thetas "
        f"(seed {c['seed']}), {c['steps']} steps per run; K = {c['candidates']}; playoff: "
        f"{c['races']} races per candidate against two `{c['opponents']}`.",
        "",
        f"| track | winner ({', '.join(names)}) | wins | margin m | candidates | eligible "
        "thetas | worker min |",
        "|---|---|---|---|---|---|---|",
    ]
    for t, r in summary["tracks"].items():
        th = ", ".join(f"{r['theta'][n]:.3g}" for n in names)
        lines.append(
            f"| `{t}` | {th} | {r['wins']}/{r['races']} | {r['margin_m_mean']:+.2f} "
            f"| {r['candidates']} | {r['eligible_thetas']} "
            f"| {r['worker_seconds'] / 60:.1f} |"
        )
    for s in selections:
        lines += [
            "",
            f"## Playoff on `{s['track']}`",
            "",
            "| rank | index | " + " | ".join(names) + " | why | map: race adj. m "
            "| wins (R1/R2/R3) | margin m | progress m |",
            "|" + "---|" * (len(names) + 7),
        ]
        for cand in s["candidates"]:
            reg = "/".join(str(cand["wins_by_region"].get(r, "-")) for r in REGIONS)
            lines.append(
                f"| {cand['rank']} | {cand['index']} | "
                + " | ".join(f"{cand['theta'][n]:.3g}" for n in names)
                + f" | {'+'.join(cand['reasons'])} | {cand['race_adjusted_m']:+.2f} "
                f"| {cand['wins']} ({reg}) | {cand['margin_m_mean']:+.2f} "
                f"| {cand['progress_m_mean']:.2f} |"
            )
        rounds = s.get("refine", [])
        if rounds:
            lines += [
                "",
                f"Compass search from the playoff's first on `{s['track']}` (wins of "
                f"{s['winner']['races']}, mean margin m; * off track on more than "
                f"{100 * OFF_TRACK_LIMIT:g}% of the steps, not eligible):",
                "",
                "| round | step | from | moves: index move wins/margin | to |",
                "|---|---|---|---|---|",
            ]
            for r in rounds:
                moves = ", ".join(
                    f"{m['index']} {m['move']} {m['wins']}/{m['margin_m_mean']:+.2f}"
                    + ("" if m["eligible"] else "*")
                    for m in r["moves"]
                )
                lines.append(
                    f"| {r['round']} | {r['step']:g} | {r['from']} | {moves} | {r['to']} |"
                )
            w = s["winner"]
            lines += [
                "",
                f"Winner: index {w['index']} ("
                + ", ".join(f"{n} {w['theta'][n]:.3g}" for n in names)
                + f"), {w['wins']} wins (R1/R2/R3 "
                + "/".join(str(w["wins_by_region"].get(r, "-")) for r in REGIONS)
                + f"), mean margin {w['margin_m_mean']:+.2f} m.",
            ]
    runs = summary["runs"]
    if runs:
        lines += [
            "",
            f"Wall time: {sum(r['wall_seconds'] for r in runs) / 60:.1f} min over "
            f"{len(runs)} invocation(s) (`runs.jsonl`).",
        ]
    return "\n".join(lines) + "\n"
