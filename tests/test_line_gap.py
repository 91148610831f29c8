"""benchmarks/line_gap.py: the distance between the lap-time and minimum-curvature lines, and
the pass suites' results read beside it."""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from line_gap import line_gap, pass_results  # noqa: E402


def test_where_the_weight_search_keeps_the_minimum_curvature_line_the_lines_coincide():
    g = line_gap("random:20002")  # the lap-time search's best weight there is 0
    assert g["weight"] == 0.0
    assert g["gap_mean_m"] == g["gap_p90_m"] == g["apart"] == 0.0
    assert g["lap_lap_time_s"] == pytest.approx(g["lap_curvature_s"])


def test_where_the_lap_time_line_gains_it_runs_apart():
    g = line_gap("default")
    assert g["weight"] > 0 and g["lap_lap_time_s"] < g["lap_curvature_s"]
    assert g["gap_p90_m"] > g["gap_mean_m"] > 0.03 and 0 < g["apart"] < 1


def _suite(folder: Path, rows) -> None:
    folder.mkdir()
    (folder / "strategy.json").write_text(json.dumps({"rows": rows}))


def test_pass_results_read_each_suites_pass_benches_and_skip_the_rest(tmp_path):
    ego = {"wins_from_behind": 3, "races": 4, "passes": 5}
    _suite(
        tmp_path / "a",
        [
            {"bench": "pass", "track": "default", "ego": ego},
            {"bench": "equal", "track": "default", "ego": {**ego, "passes": 9}},
        ],
    )
    _suite(tmp_path / "b", [{"bench": "pass", "track": "default", "ego": {**ego, "races": 8}}])
    got = pass_results([tmp_path / "a", tmp_path / "missing", tmp_path / "b"])
    assert got == {"default": ["3/4 (5)", "3/8 (5)"]}
