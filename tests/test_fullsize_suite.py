"""The vehicle class and the wake through the race commands: ``--vehicle-class`` and
``--wake`` reach the env, are recorded in a run's manifest (the paper's world keeps its keys),
and a resume with another class or wake is refused; the pass report's track sections."""

from __future__ import annotations

import numpy as np
import pytest

from experiments.cli import build_parser
from experiments.cli.options import config_from
from experiments.evaluation.bench import BenchRun
from experiments.evaluation.bench_config import BenchConfig
from experiments.evaluation.pass_report import section_at, track_sections
from experiments.evaluation.race import run_race
from experiments.evaluation.strategy import StrategyConfig, pace_specs, pass_report_on

FULL = dict(track="tumftm:Monza", ego="raceline", opponents="raceline", races=1, steps=5)


def test_the_paper_world_keeps_its_stored_keys():
    for cfg in (BenchConfig(), StrategyConfig()):
        d = cfg.to_dict()
        assert "vehicle_class" not in d and "wake" not in d
        assert cfg.wake == 0.0
    assert not pass_report_on(StrategyConfig(scenarios=("pass",)))
    assert BenchConfig(wake=0.5).to_dict()["wake"] == 0.5  # a wake on ORCA is recorded


def test_the_class_default_wake_is_stored_resolved():
    cfg = BenchConfig(vehicle_class="fullsize", **FULL)
    assert cfg.wake == 1.0
    assert cfg.to_dict()["vehicle_class"] == "fullsize" and cfg.to_dict()["wake"] == 1.0
    assert BenchConfig(vehicle_class="fullsize", wake=0, **FULL).to_dict()["wake"] == 0.0
    with pytest.raises(ValueError, match="vehicle_class"):
        BenchConfig(vehicle_class="kart")
    with pytest.raises(ValueError, match="wake"):
        StrategyConfig(vehicle_class="fullsize", wake=-1.0)
    s = StrategyConfig(vehicle_class="fullsize", scenarios=("pass",), ego="mpc", control="raceline")
    assert pass_report_on(s)
    assert pace_specs(s) == ["mpc", "raceline"]  # ego, control, opponents (raceline twice)


def test_a_resume_with_another_class_or_wake_is_refused(tmp_path):
    BenchRun(tmp_path, BenchConfig(vehicle_class="fullsize", **FULL))
    BenchRun(tmp_path, BenchConfig(vehicle_class="fullsize", wake=1.0, **FULL))  # the same
    with pytest.raises(ValueError, match="another configuration.*wake"):
        BenchRun(tmp_path, BenchConfig(vehicle_class="fullsize", wake=0.0, **FULL))
    with pytest.raises(ValueError, match="another configuration.*vehicle_class"):
        BenchRun(tmp_path, BenchConfig(**FULL))


def test_the_options_reach_the_configs():
    p = build_parser()
    args = p.parse_args(["strategy", "--vehicle-class", "fullsize", "--wake", "0"])
    cfg = config_from(StrategyConfig, args)
    assert (cfg.vehicle_class, cfg.wake) == ("fullsize", 0.0)
    args = p.parse_args(["strategy"])
    assert config_from(StrategyConfig, args) == StrategyConfig()
    args = p.parse_args(["bench", "--vehicle-class", "fullsize", "--track", "tumftm:Spa"])
    cfg = config_from(BenchConfig, args, {"cars": "n_cars"}, races=3)
    assert (cfg.vehicle_class, cfg.wake) == ("fullsize", 1.0)
    args = p.parse_args(["race", "--vehicle-class", "fullsize", "--wake", "0.5"])
    assert (args.vehicle_class, args.wake) == ("fullsize", 0.5)


def test_the_class_and_wake_reach_the_env():
    result, _ = run_race(
        ["raceline", "raceline"],
        track="tumftm:Monza",
        max_cycles=3,
        order=[1, 0],
        progress_bar=False,
        vehicle_class="fullsize",
        wake=0.5,
    )
    assert (result.vehicle_class, result.wake) == ("fullsize", 0.5)
    assert result.summary()["vehicle_class"] == "fullsize"
    assert result.contact_dn > 1.0  # a full-size car's width, not 1:43's 6 cm
    assert np.ptp(result.states[0, :, 0]) > 5.0  # the start regions at full scale
    orca, _ = run_race(["raceline"], max_cycles=2, progress_bar=False)
    assert "vehicle_class" not in orca.summary() and orca.wake == 0.0


def test_track_sections_cover_the_lap_in_order():
    from racing_env.tracks import make_track

    track = make_track("tumftm:Monza", vehicle_class="fullsize")
    secs = track_sections(track, 4.7)
    assert secs[0]["s0"] == 0.0 and secs[-1]["s1"] == pytest.approx(track.length)
    assert all(a["s1"] == b["s0"] for a, b in zip(secs, secs[1:]))
    assert all(a["straight"] != b["straight"] for a, b in zip(secs, secs[1:]))
    assert secs[0]["name"] == "straight 1" and secs[0]["s1"] > 800  # the main straight
    assert not section_at(secs, 950.0)["straight"]  # the first chicane
