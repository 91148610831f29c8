"""Bad input to the command line: one-line errors (exit code 2) before any race, and help
that describes every option."""

import argparse

import pytest

import experiments.evaluation.race
from experiments.cli import build_parser, main


def _no_race(*args, **kwargs):
    raise AssertionError("the race started before the input was checked")


def _one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    return err


def test_missing_model_names_the_value_and_the_shipped_models(capsys):
    err = _one_line_error(
        capsys, ["race", "--agents", "alpha:model=nosuch", "mpc", "--steps", "5", "--no-animation"]
    )
    assert "'nosuch'" in err
    for name in ("default", "gamma0.98", "gamma0.995", "races400"):
        assert name in err


def test_missing_model_fails_before_the_benchmark(capsys, tmp_path):
    err = _one_line_error(
        capsys,
        [
            "bench",
            "--opponents",
            "alpha:model=nosuch",
            "--races",
            "1",
            "--steps",
            "5",
            "--workers",
            "1",
            "--out",
            str(tmp_path),
        ],
    )
    assert "'nosuch'" in err and "default" in err


def test_bad_family_collection_input_names_the_value_and_what_is_expected(capsys, tmp_path):
    out = str(tmp_path / "data")
    err = _one_line_error(capsys, ["collect", "--cars", "1-9", "--races", "2", "--out", out])
    assert "'1-9'" in err and "2..8" in err and "1, 9" in err
    err = _one_line_error(
        capsys,
        ["collect", "--tracks", "default", "nosuch", "--cars", "2-3", "--races", "2", "--out", out],
    )
    assert "'nosuch'" in err and "random:SEED" in err and "random:A-B" in err
    err = _one_line_error(
        capsys, ["collect", "--tracks", "random:7-3", "--races", "2", "--out", out]
    )
    assert "'random:7-3'" in err and "A <= B" in err
    err = _one_line_error(
        capsys, ["collect", "--track", "oval", "--tracks", "default", "--races", "2", "--out", out]
    )
    assert "--track" in err and "--tracks" in err
    assert not (tmp_path / "data").exists()


def test_bad_n_car_benchmark_input_is_refused(capsys, tmp_path):
    err = _one_line_error(capsys, ["bench", "--cars", "4", "--races", "6", "--out", str(tmp_path)])
    assert "multiple of n_cars = 4" in err and "6" in err
    err = _one_line_error(capsys, ["bench", "--cars", "4", "--paper-table", "--out", str(tmp_path)])
    assert "3-car" in err and "4" in err


def test_general_report_refuses_a_single_track_model(capsys, tmp_path):
    err = _one_line_error(capsys, ["general-report", "--model", "races400", "--out", str(tmp_path)])
    assert "'races400'" in err and "single-track" in err


def test_unknown_agent_key_lists_the_valid_keys(capsys):
    err = _one_line_error(
        capsys, ["race", "--agents", "mpc:foo=1", "--steps", "5", "--no-animation"]
    )
    assert "foo" in err
    for key in ("q", "zeta", "s1", "s2", "s3"):
        assert key in err
    err = _one_line_error(
        capsys, ["race", "--agents", "alpha:zetta=1", "--steps", "5", "--no-animation"]
    )
    assert "zetta" in err and "model" in err and "zeta" in err


def test_mp4_without_ffmpeg_fails_before_the_race(capsys, monkeypatch, tmp_path):
    import racing_env.animation

    monkeypatch.setattr(racing_env.animation, "_find_ffmpeg", lambda: None)
    monkeypatch.setattr(experiments.evaluation.race, "run_race", _no_race)
    err = _one_line_error(
        capsys,
        ["race", "--agents", "raceline", "--steps", "5", "--format", "mp4", "--out", str(tmp_path)],
    )
    assert "mp4" in err and "ffmpeg" in err and "gif" in err
    assert not any(tmp_path.iterdir())


def _subcommands():
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


@pytest.mark.parametrize("name", sorted(_subcommands()))
def test_every_option_has_help_and_shows_its_default(name):
    parser = _subcommands()[name]
    assert parser.description, name
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        assert action.help and action.help.strip(), f"{name} {action.option_strings} has no help"
    text = parser.format_help()
    for action in parser._actions:
        if action.default not in (None, [], argparse.SUPPRESS) and action.help:
            assert f"(default: {action.default})" in " ".join(text.split()), (
                f"{name} {action.option_strings}: default not shown"
            )


def test_start_regions_of_a_race_are_checked_before_it_and_map_to_the_order(capsys, monkeypatch):
    from experiments.evaluation.race import start_order

    assert start_order(["R2", "R1", "R3"], 3) == [1, 0, 2]
    assert start_order(None, 3) is None
    monkeypatch.setattr(experiments.evaluation.race, "run_race", _no_race)
    base = ["race", "--agents", "mpc", "raceline", "--steps", "5", "--no-animation"]
    err = _one_line_error(capsys, base + ["--regions", "R2", "R3"])
    assert "must name each of R1 R2 once" in err and "got R2 R3" in err
    err = _one_line_error(capsys, base + ["--regions", "R2", "R1", "--start", "grid"])
    assert "need start='regions'" in err
