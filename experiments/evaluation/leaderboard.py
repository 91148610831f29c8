"""The league's leaderboard: openskill Plackett-Luce ratings replayed over the races in race
order (:data:`RATING_MODEL`), the pairwise results, ``leaderboard.md`` and the figures
(``ratings.png``, ``pairwise.png``)."""

from __future__ import annotations

import itertools
from dataclasses import asdict
from pathlib import Path

import numpy as np

from experiments.evaluation import metrics as race_metrics
from experiments.evaluation.bench_summary import wilson_interval
from experiments.evaluation.league_schedule import LeagueConfig, schedule

#: openskill Plackett-Luce parameters: the package's defaults (mu 25, sigma 25/3, beta 25/6)
#: with no dynamics (tau 0; see the module docstring).
RATING_MODEL = {
    "model": "PlackettLuce",
    "mu": 25.0,
    "sigma": 25.0 / 3.0,
    "beta": 25.0 / 6.0,
    "tau": 0.0,
}


ORDINAL_Z = 3.0
"""The leaderboard's ordinal is ``mu - ORDINAL_Z * sigma``."""


def rate(records: list[dict], agents) -> dict[str, tuple[float, float]]:
    """``{agent: (mu, sigma)}`` after replaying ``records`` in race-index order through
    openskill's Plackett-Luce model (:data:`RATING_MODEL`), each car a team of one ranked by
    its record's ``ranks``. Agents without races keep the prior."""
    from openskill.models import PlackettLuce

    p = RATING_MODEL
    model = PlackettLuce(mu=p["mu"], sigma=p["sigma"], beta=p["beta"], tau=p["tau"])
    ratings = {a: model.rating(name=a) for a in agents}
    for rec in sorted(records, key=lambda r: r["race"]):
        unknown = [a for a in rec["agents"] if a not in ratings]
        if unknown:
            raise ValueError(
                f"race {rec['race']} has agents {unknown} outside the league {list(ratings)}"
            )
        new = model.rate([[ratings[a]] for a in rec["agents"]], ranks=list(rec["ranks"]))
        for a, (r,) in zip(rec["agents"], new):
            ratings[a] = r
    return {a: (float(r.mu), float(r.sigma)) for a, r in ratings.items()}


def pairwise(records: list[dict], agents) -> dict:
    """For every ordered pair (a, b) of distinct agents: ``races[a][b]``, the races with both,
    and ``ahead[a][b]``, the share of them in which a finished ahead of b (``None`` if they
    never met)."""
    agents = list(agents)
    met = {a: {b: 0 for b in agents if b != a} for a in agents}
    won = {a: {b: 0 for b in agents if b != a} for a in agents}
    for rec in records:
        for (a, ra), (b, rb) in itertools.permutations(zip(rec["agents"], rec["ranks"]), 2):
            met[a][b] += 1
            won[a][b] += ra < rb
    share = {a: {b: (won[a][b] / met[a][b] if met[a][b] else None) for b in met[a]} for a in agents}
    return {"races": met, "ahead": share}


def leaderboard(records: list[dict], config: LeagueConfig) -> dict:
    """The league's standings: per agent (sorted by ordinal ``mu - 3 sigma``, best first)
    rank, mu, sigma, ordinal, races, wins, win rate with its Wilson 95% interval, mean
    finishing position, mean progress [m], mean off-track steps per race and decision time
    per act() [ms] (the median over races of a race's mean); the strategy metrics over the
    races that carry them (``strategy_races`` of them): ``passes`` and ``passes_contact``
    (totals and ``*_per_race``), ``wins_from_behind`` (count) and ``behind_1m_s`` (mean
    seconds per race), ``None`` when none of the agent's races carries them; plus
    :func:`pairwise`."""
    if not records:
        raise ValueError("no finished races to rank")
    records = sorted({r["race"]: r for r in records}.values(), key=lambda r: r["race"])
    ratings = rate(records, config.agents)
    rows = []
    for a in config.agents:
        cars = [(r, r["agents"].index(a)) for r in records if a in r["agents"]]
        mu, sigma = ratings[a]
        row = {
            "agent": a,
            "mu": mu,
            "sigma": sigma,
            "ordinal": mu - ORDINAL_Z * sigma,
            "races": len(cars),
        }
        if cars:
            wins = sum(r["ranks"][i] == 1 for r, i in cars)
            lo, hi = wilson_interval(wins, len(cars))
            mean = lambda key: float(np.mean([r[key][i] for r, i in cars]))  # noqa: B023
            row.update(
                {
                    "wins": int(wins),
                    "win_rate": wins / len(cars),
                    "win_ci95": [lo, hi],
                    "mean_finish": mean("ranks"),
                    "progress_m": mean("progress_m"),
                    "off_tracks": mean("off_tracks"),
                    # the median: a worker's first race carries the JIT and solver builds
                    "decision_ms": float(np.median([r["decision_ms"][i] for r, i in cars])),
                }
            )
        row.update(_strategy_row(cars))
        rows.append(row)
    rows.sort(key=lambda r: (-r["ordinal"], r["agent"]))
    for i, row in enumerate(rows, 1):
        row["rank"] = i
    expected = len(schedule(config))
    return {
        "config": asdict(config),
        "rating_model": dict(RATING_MODEL),
        "ordinal_z": ORDINAL_Z,
        "races": len(records),
        "races_scheduled": expected,
        "complete": len(records) == expected,
        "standings": rows,
        "pairwise": pairwise(records, [r["agent"] for r in rows]),
    }


def _strategy_row(cars) -> dict:
    """An agent's strategy metrics over its races ``cars`` ((record, car index) pairs) that
    carry them; ``None`` figures when none does (no silent zeros)."""
    have = [(r, i) for r, i in cars if all(k in r for k in race_metrics.RECORD_KEYS)]
    row = {"strategy_races": len(have)}
    if not have:
        return {
            **row,
            **dict.fromkeys(
                (
                    "passes",
                    "passes_per_race",
                    "passes_contact",
                    "passes_contact_per_race",
                    "wins_from_behind",
                    "behind_1m_s",
                )
            ),
        }
    for key in ("passes", "passes_contact"):
        tot = int(sum(r[key][i] for r, i in have))
        row[key], row[key + "_per_race"] = tot, tot / len(have)
    row["wins_from_behind"] = int(sum(r["won_from_behind"] and r["ranks"][i] == 1 for r, i in have))
    row["behind_1m_s"] = float(np.mean([r["behind_1m_s"][i] for r, i in have]))
    return row


def _f(v, fmt: str) -> str:
    return "-" if v is None else fmt.format(v)


def leaderboard_markdown(board: dict) -> str:
    c = board["config"]
    n = c["cars"]
    lines = [
        "# League",
        "",
        f"{len(c['agents'])} agents, {n} cars per race from the start regions R1-R{n} "
        f"(rotated so each agent starts from each region equally often), "
        f"{c['steps']} steps ({c['steps'] / 10:g} s) per race on "
        f"{', '.join('`' + t + '`' for t in c['tracks'])}; {c['rounds']} round(s), "
        f"seed {c['seed']}. {board['races']} of {board['races_scheduled']} races"
        + ("" if board["complete"] else " (partial)")
        + ".",
        "",
        f"Rating: openskill Plackett-Luce (mu0 {board['rating_model']['mu']:g}, sigma0 "
        f"{board['rating_model']['sigma']:.3g}, beta {board['rating_model']['beta']:.3g}, "
        f"tau {board['rating_model']['tau']:g}) over the finishing orders by total "
        f"progress, replayed in schedule order; ranked by the ordinal mu - "
        f"{board['ordinal_z']:g} sigma. Wins with Wilson 95% intervals (chance: 1/{n}).",
        "",
        "| rank | agent | ordinal | mu | sigma | races | wins | win rate | mean finish "
        "| progress m | off-track steps | ms/decision (median) | passes/race "
        "| via contact/race | wins from behind | <= 1 m behind s/race |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in board["standings"]:
        if not r["races"]:
            lines.append(
                f"| {r['rank']} | `{r['agent']}` | {r['ordinal']:.2f} | {r['mu']:.2f} "
                f"| {r['sigma']:.2f} | 0 | - | - | - | - | - | - | - | - | - | - |"
            )
            continue
        lo, hi = r["win_ci95"]
        lines.append(
            f"| {r['rank']} | `{r['agent']}` | {r['ordinal']:.2f} | {r['mu']:.2f} "
            f"| {r['sigma']:.2f} | {r['races']} | {r['wins']} "
            f"| {100 * r['win_rate']:.0f}% ({100 * lo:.0f}-{100 * hi:.0f}%) "
            f"| {r['mean_finish']:.2f} | {r['progress_m']:.2f} | {r['off_tracks']:.1f} "
            f"| {r['decision_ms']:.2f} | {_f(r.get('passes_per_race'), '{:.2f}')} "
            f"| {_f(r.get('passes_contact_per_race'), '{:.2f}')} "
            f"| {_f(r.get('wins_from_behind'), '{}')} "
            f"| {_f(r.get('behind_1m_s'), '{:.1f}')} |"
        )
    partial = [
        r for r in board["standings"] if r["races"] and r.get("strategy_races", 0) < r["races"]
    ]
    if partial:
        lines += [
            "",
            "Strategy metrics (passes held 1 s and clear sideways; wins from behind; "
            "time within 1 m behind) missing for some races, recorded before they "
            "existed (a league stores no states to recompute them): "
            + ", ".join(
                f"`{r['agent']}` over {r.get('strategy_races', 0)} of {r['races']} races"
                for r in partial
            )
            + ".",
        ]
    pw = board["pairwise"]
    names = [r["agent"] for r in board["standings"]]
    lines += [
        "",
        "## Pairwise",
        "",
        "Row a, column b: the share of the races with both in which a finished ahead of "
        "b (races together in brackets).",
        "",
        "| a \\ b | " + " | ".join(f"`{b}`" for b in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for a in names:
        cells = [
            "" if a == b else f"{_f(pw['ahead'][a][b], '{:.2f}')} ({pw['races'][a][b]})"
            for b in names
        ]
        lines.append(f"| `{a}` | " + " | ".join(cells) + " |")
    lines += ["", "![ratings](ratings.png)", "", "![pairwise](pairwise.png)"]
    return "\n".join(lines) + "\n"


def _figure(size):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)  # the Agg canvas directly: the global backend is left alone
    return fig


def plot_ratings(board: dict, path, dpi: int = 120) -> Path:
    """PNG of every agent's mu with a +-2 sigma bar and its ordinal (mu - 3 sigma), in
    leaderboard order (best at the top)."""
    rows = board["standings"]
    y = np.arange(len(rows))[::-1]
    mu = np.array([r["mu"] for r in rows])
    sigma = np.array([r["sigma"] for r in rows])
    fig = _figure((7, 1.2 + 0.45 * len(rows)))
    ax = fig.subplots()
    ax.errorbar(mu, y, xerr=2 * sigma, fmt="o", capsize=4, label="mu +- 2 sigma")
    ax.plot(
        mu - board["ordinal_z"] * sigma,
        y,
        "x",
        color="0.4",
        label=f"ordinal mu - {board['ordinal_z']:g} sigma",
    )
    ax.set_yticks(y, [r["agent"] for r in rows])
    ax.set_xlabel("openskill Plackett-Luce rating")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower right", fontsize="small")
    ax.set_title(f"League ratings, {board['races']} races")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return Path(path)


def plot_pairwise(board: dict, path, dpi: int = 120) -> Path:
    """PNG of the pairwise matrix: row a, column b, the share of their common races in which
    a finished ahead of b (blank where they never met), in leaderboard order."""
    names = [r["agent"] for r in board["standings"]]
    ahead = board["pairwise"]["ahead"]
    m = np.array(
        [[np.nan if a == b or ahead[a][b] is None else ahead[a][b] for b in names] for a in names]
    )
    k = len(names)
    fig = _figure((2.5 + 0.8 * k, 2 + 0.7 * k))
    ax = fig.subplots()
    mesh = ax.imshow(np.ma.masked_invalid(m), cmap="RdBu", vmin=0.0, vmax=1.0)
    for i in range(k):
        for j in range(k):
            if np.isfinite(m[i, j]):
                ax.text(
                    j,
                    i,
                    f"{m[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize="small",
                    color="white" if abs(m[i, j] - 0.5) > 0.3 else "black",
                )
    ax.set_xticks(range(k), names, rotation=45, ha="right")
    ax.set_yticks(range(k), names)
    ax.set_xlabel("b")
    ax.set_ylabel("a")
    fig.colorbar(mesh, ax=ax, label="share of races a ahead of b")
    ax.set_title("Pairwise finishing order")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return Path(path)
