"""The alpha-racer command line, the race runner, the fuzz, the README example."""

import json
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agents import make_agent_spec
from experiments.cli import main
from experiments.evaluation.fuzz import run_fuzz
from experiments.evaluation.race import run_race
from racing_env.tracks import tumftm_dir

ROOT = Path(__file__).resolve().parents[1]


def test_race_command_writes_table_animation_and_plot(tmp_path, capsys):
    out = tmp_path / "race"
    assert (
        main(
            [
                "race",
                "--agents",
                "raceline",
                "raceline:grip=0.7",
                "--steps",
                "40",
                "--seed",
                "3",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "progress m" in text and "car_1" in text
    summary = json.loads((out / "result.json").read_text())
    assert summary["steps"] == 40 and len(summary["order"]) == 2
    assert (out / "race.gif").stat().st_size > 10_000
    assert (out / "trajectories.png").stat().st_size > 10_000


def test_race_result_orders_by_position_on_track():
    result, frames = run_race(
        ["raceline", "constant:throttle=0.0"], max_cycles=60, seed=1, progress_bar=False
    )
    assert frames == []
    assert result.order.tolist() == [0, 1]  # the parked car loses
    assert result.progress[0] > 10.0
    assert result.states.shape == (61, 2, 6)


def test_bad_agent_specs_give_clear_errors(capsys):
    assert main(["race", "--agents", "nobody", "--steps", "5", "--no-animation"]) == 2
    assert "unknown agent 'nobody'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="expected key=value"):
        make_agent_spec("raceline:mu")
    with pytest.raises(ValueError, match="unknown parameter.*wings.*line_fraction"):
        make_agent_spec("raceline:wings=2")


def test_tracks_and_raceline_commands(tmp_path, capsys):
    assert main(["tracks"]) == 0
    assert "default" in capsys.readouterr().out
    assert main(["raceline", "--track", "oval", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "lap time estimate" in text
    csv = tmp_path / "oval_raceline.csv"
    header = [line for line in csv.read_text().splitlines() if line.startswith("#")][-1]
    assert header.startswith("# s_m,x_m,y_m,psi_rad,kappa_radpm,vx_mps,ax_mps2,n_m")
    rows = np.loadtxt(csv, delimiter=",", comments="#")
    assert rows.shape[1] == 9 and np.isfinite(rows).all()
    curvature_lap = float(text.split("lap time estimate ")[1].split(" s")[0])
    assert (
        main(
            [
                "raceline",
                "--track",
                "oval",
                "--objective",
                "lap_time",
                "--out",
                str(tmp_path / "fast"),
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    assert "shortest-path weight" in text
    assert float(text.split("lap time estimate ")[1].split(" s")[0]) <= curvature_lap


@pytest.mark.slow
def test_short_fuzz_finds_nothing():
    report = run_fuzz(steps=20_000, n_races=64, n_cars=3, seed=1, progress_bar=False)
    assert report.ok, report.text()
    assert report.steps >= 20_000 and report.maxima["vx"] > 1.0


def test_fuzz_catches_a_drive_through_and_nothing_else():
    from experiments.evaluation.fuzz import drive_through

    L = 20.0
    before = np.array([[[5.0, 0.0, 0, 0, 0, 0], [4.8, 0.02, 0, 0, 0, 0], [4.9, 0.2, 0, 0, 0, 0]]])
    through = before.copy()
    through[0, 1, 0] = 5.2  # car 1 ends 0.2 m ahead, still in line
    assert drive_through(before, through, L, 0.12, 0.06) == (
        0,
        0,
        1,
        "swapped places while overlapping laterally",
    )
    inside = before.copy()
    inside[0, 1, 0] = 4.95  # car 1 inside car 0's body
    assert drive_through(before, inside, L, 0.12, 0.06)[3] == "bodies overlap"
    beside = before.copy()
    beside[0, 2, 0] = 5.3  # car 2 passes car 0 beside it: free space
    assert drive_through(before, beside, L, 0.12, 0.06) is None
    half_lap = np.array([[[0.1, 0.0, 0, 0, 0, 0], [10.05, 0.0, 0, 0, 0, 0]]])
    moved = half_lap.copy()
    moved[0, 1, 0] = 10.15  # half a lap apart: the wrap flips the sign
    assert drive_through(half_lap, moved, L, 0.12, 0.06) is None


@pytest.mark.slow
def test_short_eight_car_fuzz_finds_no_drive_through():
    report = run_fuzz(steps=20_000, n_races=64, n_cars=8, seed=2, progress_bar=False)
    assert report.ok, report.text()


def test_custom_agent_example_runs(capsys):
    runpy.run_path(str(ROOT / "examples" / "custom_agent.py"), run_name="__main__")
    assert "wiggle" in capsys.readouterr().out


@pytest.mark.slow
def test_readme_main_job(tmp_path):
    """The README's main job, as a user runs it: a 50 s race with the default agents."""
    proc = subprocess.run(
        ["alpha-racer", "race", "--out", str(tmp_path / "race")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert "pos  car" in proc.stdout and " alpha " in proc.stdout
    assert (tmp_path / "race" / "race.gif").exists()
    summary = json.loads((tmp_path / "race" / "result.json").read_text())
    assert summary["steps"] == 500
    # the finishing order is the cars sorted by total progress (who wins is the race's result:
    # the README reports it, and races at the limit differ between CPU types)
    progress = summary["progress_m"]
    assert np.isfinite(progress).all() and len(progress) == 3
    assert summary["order"] == [
        f"car_{i}" for i in np.argsort(-np.asarray(progress), kind="stable")
    ]


@pytest.mark.slow
@pytest.mark.parametrize("n_cars, steps", [(3, 1_000_000), (8, 200_000)])
def test_long_fuzz(n_cars, steps):
    # (the full 1M race steps with 8 cars take about 7 min on 2 cores: a README command)
    report = run_fuzz(steps=steps, n_races=512, n_cars=n_cars, seed=0, progress_bar=False)
    assert report.ok, report.text()


@pytest.mark.slow
@pytest.mark.skipif(tumftm_dir() is None, reason="TUMFTM racetrack-database folder not present")
def test_raceline_on_a_tumftm_circuit(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "experiments.cli",
            "raceline",
            "--track",
            "tumftm:Monza",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "Monza_raceline.csv").exists() and (tmp_path / "Monza_raceline.png").exists()
