"""A benchmark's figures: win shares with Wilson 95% intervals, per start region, progress
margins, contacts, decision times and the strategy metrics (:mod:`experiments.evaluation.metrics`),
summarised from its race records (``summary.json``) and written as ``summary.md``."""

from __future__ import annotations

import numpy as np

from experiments.evaluation import metrics as race_metrics
from experiments.evaluation.bench_config import BenchConfig, roles


def wilson_interval(wins: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval (95% by default) of a binomial proportion ``wins / n``."""
    if n <= 0:
        raise ValueError(f"wilson_interval needs n >= 1 trials, got {n}")
    if not 0 <= wins <= n:
        raise ValueError(f"wins must be in [0, n={n}], got {wins}")
    p = wins / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    lo = 0.0 if wins == 0 else max(0.0, min(p, centre - half))  # exact ends (no 1 - 1e-16)
    hi = 1.0 if wins == n else min(1.0, max(p, centre + half))
    return float(lo), float(hi)


def win_share(wins: int, races: int) -> dict:
    """``{"wins", "races", "fraction", "ci95"}``: a win count with its Wilson 95% interval."""
    lo, hi = wilson_interval(wins, races)
    return {"wins": int(wins), "races": int(races), "fraction": wins / races, "ci95": [lo, hi]}


def race_dt_dn() -> tuple[float, float]:
    """(dt [s], contact_dn [m]) of the default race config."""
    from racing_env.config import RaceConfig

    c = RaceConfig()
    return c.dt, c.rules.contact_dn


def _wins(records, role) -> dict:
    return win_share(sum(r["winner"] == role for r in records), len(records))


def summarise(records: list[dict], config: BenchConfig) -> dict:
    """Win counts per car and per ego start region (Wilson 95% intervals), progress margins
    (ego minus the best opponent, m), contacts, off-track steps, decision times and fallbacks
    per car (means per race)."""
    if not records:
        raise ValueError("no finished races to summarise")
    records = sorted(records, key=lambda r: r["race"])
    n = len(records)
    arr = lambda key: np.array([r[key] for r in records], dtype=float)  # (n, N)
    margin = arr("margin_m")
    names = config.roles
    out = {
        "config": config.to_dict(),
        "races": n,
        "complete": n == config.races,
        "wins": {role: _wins(records, role) for role in names},
        "by_region": {},
    }
    for reg in config.regions:
        sub = [r for r in records if r["ego_region"] == reg]
        if sub:
            out["by_region"][reg] = {role: _wins(sub, role) for role in names}
            out["by_region"][reg]["margin_m_mean"] = float(np.mean([r["margin_m"] for r in sub]))
    out["margin_m"] = {
        "mean": float(margin.mean()),
        "median": float(np.median(margin)),
        "std": float(margin.std()),
    }
    for key in ("progress_m", "contacts", "off_tracks", "decision_ms", "fallbacks"):
        a = arr(key)
        out[key] = dict(zip(names, map(float, a.mean(axis=0))))
    out["decision_ms_max_race_mean"] = dict(zip(names, map(float, arr("decision_ms").max(axis=0))))
    out["race_seconds_total"] = float(sum(r["seconds"] for r in records))
    out["strategy"] = strategy_summary(records, names, config.regions)
    return out


def strategy_summary(records: list[dict], names, region_names) -> dict:
    """The strategy metrics of benchmark ``records`` (:mod:`experiments.evaluation.metrics`), per car
    (``names``: ego, O1, ...): ``passes``, ``passes_contact`` and ``fell_back`` (totals
    and means per race), ``wins_from_behind`` (count), ``behind_1m_s`` (mean seconds per race);
    ``wins_by_start_region`` (races won by the car that started in each region, R2.. being
    wins from behind); and per ego start region (``by_region``) the ego's and opponents'
    passes and wins from behind. Over the records that carry the metrics; ``races`` counts
    them and ``missing`` the others (recorded before the metrics existed, without states):
    with none, every figure is ``None``, never a zero."""
    have = [r for r in records if all(k in r for k in race_metrics.RECORD_KEYS)]
    out = {
        "definition": race_metrics.definition(*race_dt_dn()),
        "races": len(have),
        "missing": len(records) - len(have),
    }
    keys = (
        "passes",
        "passes_per_race",
        "passes_contact",
        "passes_contact_per_race",
        "fell_back",
        "wins_from_behind",
        "behind_1m_s",
        "wins_by_start_region",
        "by_region",
    )
    if not have:
        return {**out, **dict.fromkeys(keys)}
    n = len(have)
    names = list(names)

    def per_car(key, sub):
        return np.array([r[key] for r in sub], dtype=float).sum(axis=0)

    def wfb(sub):
        return {
            role: int(sum(r["won_from_behind"] and r["winner"] == role for r in sub))
            for role in names
        }

    for key in ("passes", "passes_contact", "fell_back"):
        tot = per_car(key, have)
        out[key] = dict(zip(names, map(int, tot)))
        if key != "fell_back":
            out[key + "_per_race"] = dict(zip(names, map(float, tot / n)))
    out["wins_from_behind"] = wfb(have)
    out["behind_1m_s"] = dict(zip(names, map(float, per_car("behind_1m_s", have) / n)))
    out["wins_by_start_region"] = {
        reg: int(sum(r["start_regions"][names.index(r["winner"])] == reg for r in have))
        for reg in region_names
    }
    out["by_region"] = {}
    for reg in region_names:
        sub = [r for r in have if r["ego_region"] == reg]
        if sub:
            out["by_region"][reg] = {
                "races": len(sub),
                "passes": dict(zip(names, map(int, per_car("passes", sub)))),
                "wins_from_behind": wfb(sub),
            }
    return out


def wins_text(w: dict) -> str:
    return f"{w['wins']}/{w['races']} ({100 * w['ci95'][0]:.0f}-{100 * w['ci95'][1]:.0f}%)"


def summary_markdown(s: dict) -> str:
    c = s["config"]
    N = c.get("n_cars", 3)
    names = roles(N)
    many = "two" if N == 3 else str(N - 1)
    lines = [
        f"# Benchmark: `{c['ego']}` vs {many} `{c['opponents']}`",
        "",
        f"{s['races']} of {c['races']} races, {c['steps']} steps each on `{c['track']}`, "
        f"seed {c['seed']}. Wins with Wilson 95% intervals.",
        "",
        "| | " + " | ".join(names) + " |",
        "|---" * (N + 1) + "|",
        "| wins (all) | " + " | ".join(wins_text(s["wins"][r]) for r in names) + " |",
    ]
    for reg, w in s["by_region"].items():
        lines.append(
            f"| wins, ego from {reg} | " + " | ".join(wins_text(w[r]) for r in names) + " |"
        )
    for key, label, fmt in (
        ("progress_m", "progress per race [m]", "{:.2f}"),
        ("contacts", "contact steps per race", "{:.2f}"),
        ("off_tracks", "off-track steps per race", "{:.2f}"),
        ("fallbacks", "fallbacks per race", "{:.2f}"),
        ("decision_ms", "mean decision time [ms]", "{:.2f}"),
    ):
        lines.append(f"| {label} | " + " | ".join(fmt.format(s[key][r]) for r in names) + " |")
    lines += strategy_rows(s.get("strategy"), names)
    m = s["margin_m"]
    lines += [
        "",
        f"Ego margin over the best opponent: mean {m['mean']:.2f} m, median "
        f"{m['median']:.2f} m, std {m['std']:.2f} m.",
    ]
    lines += strategy_note(s.get("strategy"), s["races"])
    return "\n".join(lines) + "\n"


def strategy_rows(st: dict | None, names) -> list[str]:
    """Rows of the summary table for :func:`strategy_summary` (``-`` where missing)."""
    have = st is not None and st.get("passes") is not None
    rows = []
    for key, label, fmt in (
        ("passes_per_race", "passes per race (held 1 s, clear sideways)", "{:.2f}"),
        ("passes_contact_per_race", "passes through contact per race", "{:.2f}"),
        ("wins_from_behind", "wins from behind", "{}"),
        ("behind_1m_s", "time within 1 m behind [s per race]", "{:.1f}"),
    ):
        cells = [fmt.format(st[key][r]) if have else "-" for r in names]
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    return rows


def strategy_note(st: dict | None, races: int) -> list[str]:
    """A line saying over which races the strategy metrics were taken, or that they are
    missing (old records without states)."""
    if st is None or not st.get("races"):
        return [
            "",
            f"Strategy metrics missing for all {races} races (recorded before they "
            f"existed, and no stored states to compute them from).",
        ]
    lines = [
        "",
        "Wins by the winner's start region: "
        + ", ".join(f"{reg} {w}" for reg, w in st["wins_by_start_region"].items())
        + " (from R2 and behind: wins from behind).",
    ]
    if st["missing"]:
        lines.append(
            f"Strategy metrics over {st['races']} of {races} races; "
            f"{st['missing']} lack them (recorded before they existed, no states)."
        )
    return lines
