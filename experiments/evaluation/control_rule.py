"""The control's rule, as pure functions of measurements: which thetas of a track's policy map
are eligible (on track in both modes), the candidates taken to the playoff, and the playoff's
ranking (:data:`RULE` says it in one sentence)."""

from __future__ import annotations

import numpy as np

from experiments.evaluation.bench_config import REGIONS
from experiments.evaluation.policy_map_summary import OFF_TRACK_LIMIT
from experiments.evaluation.refine import score_key

RULE = (
    "map: Sobol thetas of the box, solo and as car_0 against two opponents (race); "
    f"candidates: thetas with at most {100 * OFF_TRACK_LIMIT:g}% of the steps off track in both modes, the top "
    "K by rank of race progress among the thetas from the same start region, then by race "
    "progress minus that region's median, then by the lower Sobol index, plus the best "
    "solo theta by progress; playoff: each candidate as ego in the "
    "same seeded races from every start region against two opponents, ranked by wins, then "
    "mean margin over the best opponent, then the lower Sobol index; refine (R rounds, the "
    "config's refine): from the playoff's first, each parameter moved down and up by step "
    "times its range (step 1, clipped to the box, then halved after a round without a better "
    "theta), plus the pattern move of every parameter whose best move beat the incumbent, "
    "each raced in the playoff's races; a theta with at most "
    f"{100 * OFF_TRACK_LIMIT:g}% of its steps off track that ranks above the incumbent by the "
    "playoff's order replaces it; the winner is the last incumbent"
)
"""The selection rule in one sentence (stored in every ``selection.json``)."""


def _on_track(row: dict) -> bool:
    return "error" not in row and row["off_track_frac"] <= OFF_TRACK_LIMIT


def eligible_indices(rows) -> list[int]:
    """Sorted indices of the thetas whose solo and race rows are both on track (no
    ``error``, at most :data:`~experiments.evaluation.policy_map_summary.OFF_TRACK_LIMIT` of the steps off
    track)."""
    rows = list(rows)
    solo = {r["index"]: r for r in rows if r["mode"] == "solo"}
    race = {r["index"]: r for r in rows if r["mode"] == "race"}
    return sorted(i for i in set(solo) & set(race) if _on_track(solo[i]) and _on_track(race[i]))


def choose_candidates(rows, k: int) -> list[dict]:
    """The playoff's candidates from the map rows of one track (both modes; rows as
    :func:`experiments.evaluation.policy_map.map_row` writes them).

    A theta is eligible when its solo and race rows are both on track (no ``error``, at most
    :data:`~experiments.evaluation.policy_map_summary.OFF_TRACK_LIMIT` of the steps off track). The top ``k``
    eligible thetas by their rank (1 = most race progress) among the eligible thetas from the
    same start region, then by region-adjusted race progress [m] (race progress minus the
    median race progress of all finished race rows from that region), then by the lower
    index; then the best eligible solo theta by progress if it is not among them. Returns
    dicts ``index, theta, reasons, solo_progress_m, race_progress_m, race_adjusted_m,
    region_rank, start_region, race_margin_m``; ``ValueError`` when no theta is eligible."""
    if not (isinstance(k, int) and k >= 1):
        raise ValueError(f"candidates must be a positive integer, got {k!r}")
    rows = list(rows)
    solo = {r["index"]: r for r in rows if r["mode"] == "solo"}
    race = {r["index"]: r for r in rows if r["mode"] == "race"}
    finished = [r for r in race.values() if "error" not in r]
    median = {
        reg: float(np.median([r["progress_m"] for r in finished if r["start_region"] == reg]))
        for reg in {r["start_region"] for r in finished}
    }
    eligible = eligible_indices(rows)
    if not eligible:
        tracks = sorted({r["track"] for r in rows})
        raise ValueError(
            f"no theta of the map on {tracks} stays on track in both modes "
            f"({len(solo)} solo and {len(race)} race rows); map more thetas"
        )

    adjusted = {i: race[i]["progress_m"] - median[race[i]["start_region"]] for i in eligible}
    rank = {}
    for reg in {race[i]["start_region"] for i in eligible}:
        mine = sorted(
            (i for i in eligible if race[i]["start_region"] == reg), key=lambda i: (-adjusted[i], i)
        )
        rank.update({i: r for r, i in enumerate(mine, 1)})

    def record(i, reason):
        s, r = solo[i], race[i]
        return {
            "index": i,
            "theta": r["theta"],
            "reasons": [reason],
            "solo_progress_m": s["progress_m"],
            "race_progress_m": r["progress_m"],
            "race_adjusted_m": round(adjusted[i], 4),
            "region_rank": rank[i],
            "start_region": r["start_region"],
            "race_margin_m": r["margin_m"],
        }

    by_race = sorted(eligible, key=lambda i: (rank[i], -adjusted[i], i))
    out = [record(i, "race") for i in by_race[:k]]
    best_solo = min(eligible, key=lambda i: (-solo[i]["progress_m"], i))
    chosen = {c["index"]: c for c in out}
    if best_solo in chosen:
        chosen[best_solo]["reasons"].append("solo")
    else:
        out.append(record(best_solo, "solo"))
    return out


def rank_playoff(scores) -> list[dict]:
    """Playoff scores (dicts with ``index``, ``wins``, ``margin_m_mean`` [m]) ranked by wins,
    then mean margin, then the lower index; returns copies with ``rank`` (1 = the winner).
    ``ValueError`` for no scores, a repeated index or a non-finite margin."""
    scores = list(scores)
    if not scores:
        raise ValueError("no playoff scores to rank")
    idx = [s["index"] for s in scores]
    if len(set(idx)) != len(idx):
        raise ValueError(f"repeated candidate index in the playoff scores: {idx}")
    bad = [s["index"] for s in scores if not np.isfinite(s["margin_m_mean"])]
    if bad:
        raise ValueError(f"non-finite playoff margin of candidate(s) {bad}")
    ranked = sorted(scores, key=score_key)
    return [{**s, "rank": r} for r, s in enumerate(ranked, 1)]


def playoff_score(summary: dict) -> dict:
    """A candidate's playoff score from its benchmark summary."""
    return {
        "wins": summary["wins"]["ego"]["wins"],
        "races": summary["races"],
        "wins_by_region": {
            reg: summary["by_region"][reg]["ego"]["wins"]
            for reg in REGIONS
            if reg in summary["by_region"]
        },
        "margin_m_mean": summary["margin_m"]["mean"],
        "margin_m_by_region": {
            reg: summary["by_region"][reg]["margin_m_mean"]
            for reg in REGIONS
            if reg in summary["by_region"]
        },
        "progress_m_mean": summary["progress_m"]["ego"],
        "off_track_steps_mean": summary["off_tracks"]["ego"],
        "contacts_mean": summary["contacts"]["ego"],
    }
