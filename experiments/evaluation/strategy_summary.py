"""The strategy suite's table: one row per bench and track from the ego's and the control's
bench summaries (:func:`table_row`), and ``strategy.md`` (:func:`strategy_markdown`); the
suite itself is :mod:`experiments.evaluation.strategy`."""

from __future__ import annotations

from pathlib import Path


def _side(s: dict) -> dict:
    st = s["strategy"]
    return {
        "races": s["races"],
        "wins": s["wins"]["ego"]["wins"],
        "wins_by_region": {reg: w["ego"]["wins"] for reg, w in s["by_region"].items()},
        "races_by_region": {reg: w["ego"]["races"] for reg, w in s["by_region"].items()},
        "passes": st["passes"] and st["passes"]["ego"],
        "passes_contact": st["passes_contact"] and st["passes_contact"]["ego"],
        "opponent_passes": st["passes"] and sum(v for r, v in st["passes"].items() if r != "ego"),
        "wins_from_behind": st["wins_from_behind"] and st["wins_from_behind"]["ego"],
        "margin_m_mean": s["margin_m"]["mean"],
        "behind_1m_s": st["behind_1m_s"] and st["behind_1m_s"]["ego"],
        "complete": s["complete"],
    }


def table_row(bench: str, track: str, ego: dict, control: dict, ego_dir, control_dir, out) -> dict:
    """One row of the suite's table from the ego's and the control's bench summaries."""
    return {
        "bench": bench,
        "track": track,
        "ego_spec": ego["config"]["ego"],
        "control_spec": control["config"]["ego"],
        "opponents": ego["config"]["opponents"],
        "ego": _side(ego),
        "control": _side(control),
        "ego_dir": str(Path(ego_dir).relative_to(out)),
        "control_dir": str(Path(control_dir).relative_to(out)),
    }


def _wins(side: dict) -> str:
    split = " / ".join(f"{reg} {w}" for reg, w in side["wins_by_region"].items())
    return f"{side['wins']}/{side['races']}" + (
        f" ({split})" if len(side["wins_by_region"]) > 1 else ""
    )


def _pair(a, b, fmt: str = "{}") -> str:
    f = lambda v: "-" if v is None else fmt.format(v)
    return f"{f(a)} / {f(b)}"


def strategy_markdown(table: dict, pass_opponents: str) -> str:
    """``strategy.md`` from the suite's table (``strategy.json``'s content);
    ``pass_opponents``: the pass scenario's opponents where the stored config predates the
    field."""
    c = table["config"]
    lines = [
        "# Strategy benchmark",
        "",
        f"Ego `{c['ego']}` and control `{c['control']}` in the same seats and races: "
        f"{c['races']} races per bench of {c['steps']} steps ({c['steps'] / 10:g} s), three "
        f"cars, seed {c['seed']}"
        + (
            f", class `{c['vehicle_class']}` with the wake at {c['wake']:g}"
            if "vehicle_class" in c
            else ""
        )
        + f". `pass`: behind two "
        f"`{c.get('pass_opponents', pass_opponents)}` cars from R2 and R3 "
        f"in turn; `equal`: against two control cars from R1, R2, R3 in turn; `defend`: "
        f"from R1 with a zeta ceiling of {c['zeta_max']:g} against two control cars "
        f"without it; `table1_*`: against two cars of the paper's opponents from R1, R2, "
        f"R3 in turn. Passes: held 1 s, clear sideways at the crossing (totals over the "
        f"races); wins from behind: the winner did not start at the front; margin: the "
        f"ego's progress minus the best opponent's; time within 1 m behind another car: "
        f"mean seconds per race. Cells: ego / control.",
        "",
        "| scenario | track | opponents | ego wins | control wins | passes | passes "
        "through contact | opponents' passes | wins from behind | mean margin m "
        "| within 1 m behind s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in table["rows"]:
        e, k = r["ego"], r["control"]
        partial = "" if e["complete"] and k["complete"] else " (partial)"
        lines.append(
            f"| {r['bench']}{partial} | `{r['track']}` | `{r['opponents']}` | {_wins(e)} "
            f"| {_wins(k)} | {_pair(e['passes'], k['passes'])} "
            f"| {_pair(e['passes_contact'], k['passes_contact'])} "
            f"| {_pair(e['opponent_passes'], k['opponent_passes'])} "
            f"| {_pair(e['wins_from_behind'], k['wins_from_behind'])} "
            f"| {_pair(e['margin_m_mean'], k['margin_m_mean'], '{:+.2f}')} "
            f"| {_pair(e['behind_1m_s'], k['behind_1m_s'], '{:.1f}')} |"
        )
    if table["pace"]:
        lines += [
            "",
            f"## Defend: measured pace (alone from the grid, {c['steps']} steps)",
            "",
            f"The opponents must be at least {100 * table['pace_gap_required']:g}% faster "
            f"alone than the capped ego.",
            "",
            "| track | agent | progress m | opponents faster by |",
            "|---|---|---|---|",
        ]
        for track, p in table["pace"].items():
            for spec, m in p["progress_m"].items():
                gap = p["gaps"].get(spec)
                what = (
                    "(the opponent)"
                    if spec == c["control"]
                    else "-"
                    if gap is None
                    else f"{100 * gap:+.1f}%"
                )
                shown = "-" if m is None else f"{m:.2f}"
                if spec in p["reasons"]:
                    what = "not measured: " + p["reasons"][spec].split(";")[0]
                lines.append(f"| `{track}` | `{spec}` | {shown} | {what} |")
    if table.get("pass_report"):
        from experiments.evaluation.pass_report import report_markdown

        reports = [table["pass_report"]] + [b["pass_report"] for b in table.get("beside", [])]
        rows = [(r["track"], r) for rep in reports for r in rep]
        rows.sort(key=lambda tr: (c["tracks"].index(tr[0]), tr[1]["role"] != "ego", -tr[1]["wake"]))
        lines += report_markdown(
            rows,
            f"Pass report: class {c['vehicle_class']}"
            + (
                ", wake "
                + " and ".join(f"{w:g}" for w in dict.fromkeys(r["wake"] for _, r in rows))
            ),
        )
        if table.get("beside"):
            lines += [
                "",
                "Rows of another wake come from "
                + ", ".join(f"`{b['folder']}`" for b in table["beside"])
                + " (the same suite, seeds and seats).",
            ]
    if table["flags"]:
        lines += ["", "**Flags:**", ""] + [f"- {f}" for f in table["flags"]]
    runs = table.get("runs", [])
    lines += [
        "",
        f"Wall time: {sum(r['wall_seconds'] for r in runs) / 60:.1f} min for the "
        f"{sum(r['races_simulated'] for r in runs)} races simulated over {len(runs)} "
        f"invocation(s) (`runs.jsonl`). Each bench's folder: "
        f"`SCENARIO/TRACK/EGO/summary.md`.",
    ]
    return "\n".join(lines) + "\n"
