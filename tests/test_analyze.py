"""Nash analyses: regret by simulation, approximation gap, potential slices, figures."""

import json

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents.potential import load_model  # noqa: E402
from experiments.analysis.nash import (
    AnalyzeConfig,
    analyze,
    maximiser,
    regret_task,  # noqa: E402
    slice_state,
)
from experiments.cli import main  # noqa: E402
from experiments.infra.parallel import Pool
from racing_env.tracks import make_track  # noqa: E402

TINY = AnalyzeConfig(
    heldout_races=2,
    gap_pairs=400,
    regret_states=2,
    regret_horizon=10,
    cem_iterations=2,
    cem_samples=3,
    value_search=64,
    slice_points=9,
    slice_rollouts=3,
    slice_steps=10,
    steps=40,
)

# three cars side by side-ish on the main straight, rolling at 2 m/s
STATE = np.array(
    [
        [6.0, 0.10, 0.0, 2.0, 0.0, 0.0],
        [5.6, -0.10, 0.0, 2.0, 0.0, 0.0],
        [5.2, 0.05, 0.0, 2.0, 0.0, 0.0],
    ]
)


@pytest.fixture(scope="module")
def model():
    return load_model("default")


@pytest.mark.slow
def test_regret_detects_a_bad_theta_and_is_never_negative(model):
    track = make_track("default")
    good = maximiser(model, STATE, track, seed=0)
    cfg = AnalyzeConfig(regret_horizon=30, cem_iterations=1, cem_samples=6, value_search=256)
    bad = good.copy()
    bad[0, 1] = 0.7  # car 0 crawls: zeta at its lower bound
    r_bad = regret_task("default", "default", 0, STATE.tolist(), bad.tolist(), 0, cfg)
    r_good = regret_task("default", "default", 0, STATE.tolist(), good.tolist(), 0, cfg)
    assert r_bad["regret_rel"] > 0.005  # a faster theta of its own gains progress
    assert r_good["regret_rel"] >= 0.0 and r_bad["regret_rel"] >= 0.0
    assert r_bad["g_best"] >= r_bad["g_star"]
    assert r_good["regret_rel"] < r_bad["regret_rel"]
    assert r_bad["rollouts"] == 1 + 6


def test_careful_maximiser_beats_the_box_centre_and_stays_in_bounds(model):
    from agents.reference import THETA_HIGH, THETA_LOW

    track = make_track("default")
    th = maximiser(model, STATE, track, seed=0)
    assert np.all(th >= THETA_LOW - 1e-9) and np.all(th <= THETA_HIGH + 1e-9)
    centre = np.tile(0.5 * (np.asarray(THETA_LOW) + THETA_HIGH), (3, 1))
    assert model.potential(STATE, th, track) > model.potential(STATE, centre, track)


def test_slice_state_picks_the_closest_follower():
    X = np.zeros((2, 3, 6))
    X[0, :, 0] = [5.0, 3.0, 1.0]  # gaps 2 m
    X[1, :, 0] = [5.0, 4.9, 1.0]  # car 1 is 0.1 m behind car 0
    assert slice_state(X) == (1, 1)


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="regret_states must be a positive integer, got 0"):
        AnalyzeConfig(regret_states=0)
    with pytest.raises(ValueError, match="slice_rollouts"):
        AnalyzeConfig(slice_points=3, slice_rollouts=5)


@pytest.mark.slow
def test_tiny_analysis_end_to_end(tmp_path):
    s = analyze(TINY, tmp_path, pool=Pool(workers=1, progress_bar=False))
    for name in (
        "track.png",
        "fig2a_approximation_gap.png",
        "fig2b_nash_regret.png",
        "fig3_potential_slices.png",
        "summary.md",
        "summary.json",
    ):
        assert (tmp_path / name).stat().st_size > 0
    g = s["gap"]
    assert g["pairs"] == 400 and g["races"] == 2
    assert 0 <= g["median"] <= g["p95"] <= g["max"]
    assert g["median"] < g["const_median"]  # the learned potential beats a constant
    reg = json.loads((tmp_path / "regret.json").read_text())
    assert len(reg["regret_rel"]) == 2 * 3
    assert min(reg["regret_rel"]) >= 0.0 and min(reg["value_regret_rel"]) >= 0.0
    assert reg["regret_median"] <= reg["regret_max"]
    sl = json.loads((tmp_path / "slices.json").read_text())
    for d in sl["params"].values():
        assert len(d["phi"]) == 9 and np.isfinite(d["phi"]).all()
        assert min(d["grid"]) <= d["theta_star"] <= max(d["grid"])
        assert 1 <= d["maximiser_progress_rank"] <= 4
    # rerun: every part is already there, nothing is recomputed
    mtime = (tmp_path / "regret.jsonl").stat().st_mtime
    analyze(TINY, tmp_path, pool=Pool(workers=1, progress_bar=False))
    assert (tmp_path / "regret.jsonl").stat().st_mtime == mtime
    # another config is refused
    with pytest.raises(ValueError, match="another config"):
        analyze(AnalyzeConfig(regret_states=3), tmp_path, pool=Pool(workers=1, progress_bar=False))


@pytest.mark.slow
def test_reproduce_writes_every_table_and_figure_tiny(tmp_path, capsys, monkeypatch):
    from agents.best_theta import TABLE_ENV_VAR, lookup

    monkeypatch.setenv(TABLE_ENV_VAR, str(tmp_path / "best_fixed_theta.json"))  # empty table
    assert (
        main(
            [
                "reproduce",
                "--out",
                str(tmp_path),
                "--races",
                "3",
                "--steps",
                "30",
                "--heldout-races",
                "2",
                "--gap-pairs",
                "300",
                "--regret-states",
                "2",
                "--regret-horizon",
                "5",
                "--cem-iterations",
                "1",
                "--cem-samples",
                "2",
                "--slice-points",
                "5",
                "--policy-thetas",
                "2",
                "--control-thetas",
                "2",
                "--control-races",
                "3",
                "--control-refine",
                "1",
                "--workers",
                "1",
            ]
        )
        == 0
    )
    table = json.loads((tmp_path / "paper_table" / "paper_table.json").read_text())
    assert list(table["cases"]) == ["I", "II", "III", "IV", "V"]
    md = (tmp_path / "paper_table" / "paper_table.md").read_text()
    assert "61/28/10" in md and "`ibr`" in md and "`ppo`" in md
    for case in table["cases"].values():
        s = case["summary"]
        assert sum(w["wins"] for w in s["wins"].values()) == 3
    assert (tmp_path / "analysis" / "fig3_potential_slices.png").exists()
    # the control: the best fixed theta, selected first because the table lacked default
    sel = json.loads((tmp_path / "control" / "default" / "selection.json").read_text())
    assert lookup("default")["theta"] == sel["winner"]["theta"]
    # chosen from map rows that ran: not vacuous if every row had errored
    assert sel["map"]["rows"] > 0 and sel["map"]["errors"] == 0
    assert 1 <= sel["map"]["eligible_thetas"] <= sel["map"]["rows"]
    assert sel["config"]["refine"] == 1 and [r["round"] for r in sel["refine"]] == [1]
    control = json.loads((tmp_path / "paper_table_control" / "paper_table.json").read_text())
    assert control["ego"] == "mpc:theta=best" and list(control["cases"]) == list(table["cases"])
    for case in control["cases"].values():  # and its races were raced, every one
        s = case["summary"]
        assert s["races"] == 3 and sum(w["wins"] for w in s["wins"].values()) == 3
    for case in control["cases"]:  # each case's folder records the theta it raced
        claimed = json.loads(
            (
                tmp_path / "paper_table_control" / f"case_{case}" / "best_fixed_theta.json"
            ).read_text()
        )
        assert claimed["config"]["default"]["theta"] == sel["winner"]["theta"]
    extra = json.loads((tmp_path / "paper_table_mpc_ego" / "paper_table.json").read_text())
    assert extra["ego"] == "mpc" and list(extra["cases"]) == list(table["cases"])
    text = (tmp_path / "README.md").read_text()
    assert "Table 1" in text and "Nash regret" in text
    comparison = (tmp_path / "comparison.md").read_text()
    assert (
        comparison in text
        and "| alpha wins (R1/R2/R3) | best fixed wins (R1/R2/R3) | mpc "
        "wins (R1/R2/R3) | margin m (alpha / best fixed / mpc) |"
        in comparison
    )
    for c, case in table["cases"].items():
        s = case["summary"]
        reg = "/".join(str(s["by_region"][r]["ego"]["wins"]) for r in ("R1", "R2", "R3"))
        assert (
            f"| {c} | `{case['opponents']}` | {s['wins']['ego']['wins']}/3 ({reg}) |" in comparison
        )
    rows = [json.loads(line) for line in (tmp_path / "policy_map" / "rows.jsonl").open()]
    assert len(rows) == 2 * 2 * 4  # thetas x modes x default tracks
    assert all(r["steps"] == 30 for r in rows if "error" not in r)
    assert (tmp_path / "policy_map" / "summary.md").read_text() in text
