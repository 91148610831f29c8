"""How far the lap-time racing line runs from the minimum-curvature line, track by track, beside
the passes of strategy suites raced there.

    python benchmarks/line_gap.py                       # the tracks of the pass suites in results/
    python benchmarks/line_gap.py --tracks default random:20002 --strategy results/strategy_pass_survey

The extended space's ``b`` blends the lap-time line (``RacelineConfig(objective="lap_time")``:
the minimum-curvature problem plus a path-length term whose weight is searched for the
shortest lap estimate) into the minimum-curvature line that the ``raceline`` followers drive.
Where the search keeps weight 0 the two lines are the same, and a car at ``b = 1`` drives
where the follower drives. Printed per track: both lines' lap estimates [s] (speed profile at
the nominal envelope), the weight found, the lateral distance between the lines (mean and
90th percentile over the track's grid [m], share of the grid more than 6 cm apart, about a
car width) and, for each ``--strategy`` folder with a ``pass`` bench on the track, the ego's
wins from behind out of its races and its passes (``strategy.json``).
"""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

from racing_env.raceline import RacelineConfig, get_raceline
from racing_env.tracks import make_track

SUITES = (
    "results/strategy_pass_damped",
    "results/strategy_pass_damped_seed41",
    "results/strategy_pass_damped_heldout",
    "results/strategy_pass_survey",
)
APART = 0.06  # [m] about a car's width (0.06 m): the lines are apart where they differ by more


def line_gap(track_name: str) -> dict:
    """Both lines of ``track_name`` and their lateral distance (module docstring)."""
    track = make_track(track_name)
    curvature = get_raceline(track)
    lap_time = get_raceline(track, config=RacelineConfig(objective="lap_time"))
    gap = np.abs(curvature.n - lap_time.offset_at(curvature.s_track))
    return {
        "track": track_name,
        "lap_curvature_s": curvature.lap_time,
        "lap_lap_time_s": lap_time.lap_time,
        "weight": lap_time.length_weight,
        "gap_mean_m": float(gap.mean()),
        "gap_p90_m": float(np.percentile(gap, 90)),
        "apart": float(np.mean(gap > APART)),
    }


def pass_results(folders) -> dict[str, list[str]]:
    """``track -> ["wins/races (passes)", ...]`` of the ego of every ``pass`` bench in the
    ``strategy.json`` of ``folders`` (missing folders are skipped)."""
    out: dict[str, list[str]] = {}
    for folder in folders:
        path = Path(folder) / "strategy.json"
        if not path.is_file():
            continue
        for row in json.loads(path.read_text())["rows"]:
            if row["bench"] == "pass":
                ego = row["ego"]
                out.setdefault(row["track"], []).append(
                    f"{ego['wins_from_behind']}/{ego['races']} ({ego['passes']})"
                )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tracks", nargs="+", help="track specs (default: the suites' tracks)")
    parser.add_argument(
        "--strategy", nargs="+", default=list(SUITES), help="strategy folders with pass benches"
    )
    args = parser.parse_args()
    passes = pass_results(args.strategy)
    tracks = args.tracks or sorted(passes, key=lambda t: (t != "default", t))
    if not tracks:
        raise SystemExit(f"no --tracks given and no pass bench in {args.strategy}")
    print(
        f"{'track':14s} {'lap curv':>8s} {'lap l-t':>8s} {'weight':>7s} {'gap mean':>8s} "
        f"{'gap p90':>8s} {'>6 cm':>6s}  ego wins from behind (passes)"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a line's convergence note is not this table's subject
        for name in tracks:
            g = line_gap(name)
            print(
                f"{name:14s} {g['lap_curvature_s']:8.2f} {g['lap_lap_time_s']:8.2f} "
                f"{g['weight']:7.3f} {g['gap_mean_m']:8.3f} {g['gap_p90_m']:8.3f} "
                f"{100 * g['apart']:5.0f}%  {'  '.join(passes.get(name, ['-']))}"
            )


if __name__ == "__main__":
    main()
