"""``alpha-racer room``: the oracle in a finished strategy suite's seats. With no moves the
oracle is the base raced fixed, so its room is exactly 0 in every race; a killed run resumes;
candidates move one parameter of the base (its best theta written out); bad settings are
named."""

import json
from dataclasses import replace

import numpy as np
import pytest

from agents.theta import MOVES
from experiments.cli import main
from experiments.evaluation.oracle import candidate_moves
from experiments.evaluation.room import RoomConfig, explicit_theta, room
from experiments.evaluation.strategy import StrategyConfig, strategy
from experiments.infra.parallel import Pool

EGO = "mpc:q=20,zeta=1.0,s1=0.1,s2=4,s3=1"
CONTROL = "mpc:q=20,zeta=0.95,s1=0.1,s2=4,s3=1"


@pytest.fixture(scope="module")
def suite(tmp_path_factory):
    out = tmp_path_factory.mktemp("suite")
    config = StrategyConfig(
        ego=EGO, control=CONTROL, tracks=("default",), scenarios=("equal",), races=2, steps=40
    )
    strategy(config, out, Pool(workers=1, progress_bar=False))
    return out


def test_without_moves_the_room_is_zero_race_by_race(suite):
    t = room(suite, RoomConfig(moves=0, benches=("equal",)), Pool(workers=1, progress_bar=False))
    (row,) = t["rows"]
    assert row["races"] == 2
    assert row["room_m"]["mean"] == row["room_m"]["min"] == row["room_m"]["max"] == 0.0
    assert row["oracle_margin_m"] == row["control_margin_m"]
    assert row["oracle_wins_by_region"] == row["control_wins_by_region"]
    assert row["ego_share_of_room"] is None  # no room to share
    folder = suite / "room" / "control_T3_M1_k10"
    records = [json.loads(line) for line in (folder / "races.jsonl").read_text().splitlines()]
    control = [
        json.loads(line)
        for line in (
            suite / "equal" / "default" / "mpc_q_20_zeta_0.95_s1_0.1_s2_4_s3_1" / "races.jsonl"
        )
        .read_text()
        .splitlines()
    ]
    by_race = {r["race"]: r["progress_m"] for r in control}
    for rec in records:  # the oracle's progress is the control's, as stored (4 decimals)
        assert np.allclose(rec["progress_m"], by_race[rec["race"]], atol=1e-4, rtol=0)


def test_a_killed_run_resumes_and_a_choice_is_recorded(suite):
    config = RoomConfig(moves=1, lookahead=0.5, every=20, benches=("equal",), races=1)
    folder = suite / "room" / config.folder_name()
    first = room(suite, config, Pool(workers=1, progress_bar=False))
    assert first["new_races"] == 1
    (rec,) = [json.loads(line) for line in (folder / "races.jsonl").read_text().splitlines()]
    assert rec["candidates"] == candidate_moves(CONTROL, 1)
    assert sum(rec["choices"].values()) == 2  # steps 0 and 20 of 40
    again = room(suite, config, Pool(workers=1, progress_bar=False))
    assert again["new_races"] == 0
    assert (folder / "room.md").read_text().startswith("# The room")
    # more races of the same oracle grow the folder, also one whose manifest (as older
    # versions wrote it) names the benches and the number of races it was first run with
    manifest = folder / "manifest.json"
    meta = json.loads(manifest.read_text())
    assert "races" not in meta["room"] and "benches" not in meta["room"]
    meta["room"].update(races=1, benches=["equal"])
    manifest.write_text(json.dumps(meta))
    more = room(suite, replace(config, races=2), Pool(workers=1, progress_bar=False))
    assert more["new_races"] == 1 and more["rows"][0]["races"] == 2
    assert "races" not in json.loads(manifest.read_text())["room"]
    # the tables show every race the folder holds, whatever this call selects
    fewer = room(suite, config, Pool(workers=1, progress_bar=False))
    assert fewer["new_races"] == 0 and fewer["rows"][0]["races"] == 2


def test_the_control_s_oracle_races_serve_another_ego_s_suite(suite, tmp_path):
    """The oracle from the control races the control's seats: a suite of another ego with the
    same control and seats reuses them (no new race), and a manifest that stored the old
    suite's ego (made before they were shared) is read as the same run."""
    import shutil

    config = RoomConfig(moves=0, benches=("equal",))
    room(suite, config, Pool(workers=1, progress_bar=False))
    other = tmp_path / "other"
    strategy(
        StrategyConfig(
            ego="mpc:q=50,zeta=0.9,s1=0.0,s2=4,s3=1",
            control=CONTROL,
            tracks=("default",),
            scenarios=("equal",),
            races=2,
            steps=40,
        ),
        other,
        Pool(workers=1, progress_bar=False),
    )
    shutil.copytree(suite / "room", other / "room")
    manifest = other / "room" / config.folder_name() / "manifest.json"
    meta = json.loads(manifest.read_text())
    assert "ego" not in meta["suite"]
    meta["suite"]["ego"] = EGO  # as a folder made before the sharing stored it
    manifest.write_text(json.dumps(meta))
    t = room(other, config, Pool(workers=1, progress_bar=False))
    assert t["new_races"] == 0 and t["rows"][0]["races"] == 2
    assert "ego" not in json.loads(manifest.read_text())["suite"]


def test_a_bench_raced_again_without_its_states_counts_each_race_once(suite, tmp_path):
    """A bench folder copied without its ``states/`` (they are not committed) races again
    on resume and appends its races; the room reads each race once, its last line."""
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(suite, copy)
    folder = copy / "equal" / "default" / "mpc_q_20_zeta_0.95_s1_0.1_s2_4_s3_1"
    shutil.rmtree(folder / "states")
    strategy(
        StrategyConfig(
            ego=EGO, control=CONTROL, tracks=("default",), scenarios=("equal",), races=2, steps=40
        ),
        copy,
        Pool(workers=1, progress_bar=False),
    )
    lines = (folder / "races.jsonl").read_text().splitlines()
    assert len(lines) == 4 and sorted(json.loads(x)["race"] for x in lines) == [0, 0, 1, 1]
    t = room(copy, RoomConfig(moves=0, benches=("equal",)), Pool(workers=1, progress_bar=False))
    assert t["rows"][0]["races"] == 2 and t["rows"][0]["room_m"]["mean"] == 0.0


def test_candidates_move_one_parameter_each():
    cands = candidate_moves("mpc:space=extended,q=5,zeta=1.0,s1=0.3,s2=0.5,s3=0,b=1", 3)
    assert cands[1:] == [
        "mpc:space=extended,q=5,zeta=1.0,s2=0.5,s3=0,b=1,s1=0",
        "mpc:space=extended,zeta=1.0,s1=0.3,s2=0.5,s3=0,b=1,q=500",
        "mpc:space=extended,q=5,s1=0.3,s2=0.5,s3=0,b=1,zeta=0.95",
    ]
    assert candidate_moves(EGO, 2)[:2] == candidate_moves(EGO, 1)  # nested
    # a move that changes nothing (s1=0 of a base without the shift) is not simulated twice
    no_shift = "mpc:space=extended,q=5,zeta=1.0,s1=0.0,s2=0.5,s3=0,b=1"
    assert candidate_moves(no_shift, 3) == [
        no_shift,
        cands[2].replace("s1=0.3", "s1=0.0"),
        cands[3].replace("s1=0.3", "s1=0.0"),
    ]
    # nor one that a zeta ceiling makes the base again (both zetas capped at 0.88)
    capped = "mpc:space=extended,q=5,zeta=1.0,s1=0.3,s2=0.5,s3=0,b=1,zeta_max=0.88"
    assert [c.split(",")[-1] for c in candidate_moves(capped, 3)[1:]] == ["s1=0", "q=500"]
    assert len(candidate_moves(capped.replace("0.88", "0.97"), 3)) == 4  # 0.95 is below it
    with pytest.raises(ValueError, match=f"moves must be an integer in 0..{len(MOVES)}"):
        candidate_moves(EGO, len(MOVES) + 1)


def test_best_theta_is_written_out():
    from agents.best_theta import best_theta

    spec = explicit_theta("mpc:theta=best", "default")
    theta = best_theta("default")
    assert "theta=best" not in spec
    assert f"q={float(theta.q)!r}" in spec and f"s3={float(theta.s3)!r}" in spec
    assert explicit_theta(EGO, "default") == EGO


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"base": "alpha"}, "base must be 'control' or 'ego'"),
        ({"lookahead": 0}, r"lookahead must be a time in \(0, 60\] s, got 0"),
        ({"every": 0}, "every must be a number of control periods >= 1, got 0"),
        (
            {"benches": ("table1_ibr",)},
            r"benches must be names of pass, equal, defend, got \['table1_ibr'\]",
        ),
        ({"races": 0}, "races must be a positive number or None, got 0"),
        ({"model": "ibr"}, r"model must be one of \(None, 'self', 'control'\), got 'ibr'"),
    ],
)
def test_bad_settings_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        RoomConfig(**kw)


def test_a_folder_without_a_suite_or_bench_is_named(suite, tmp_path, capsys):
    with pytest.raises(ValueError, match="holds no finished strategy suite"):
        room(tmp_path, RoomConfig())
    with pytest.raises(ValueError, match=r"ran no pass, defend \(its scenarios: equal\)"):
        room(suite, RoomConfig(), Pool(workers=1, progress_bar=False))
    argv = ["room", str(suite), "--benches", "equal", "--moves", "0", "--workers", "1"]
    assert main(argv) == 0 and main(argv) == 0  # the second resumes a finished run
    assert capsys.readouterr().out.rstrip().splitlines()[-1].startswith("0 new oracle races")


def test_a_modelled_oracle_keeps_its_own_folder_and_names_its_model(suite):
    config = RoomConfig(moves=1, lookahead=0.5, every=20, benches=("equal",), races=1, model="self")
    t = room(suite, config, Pool(workers=1, progress_bar=False))
    folder = suite / "room" / "control_T0.5_M2_k20_model-self"
    assert t["folder"] == str(folder) and t["new_races"] == 1
    (rec,) = [json.loads(line) for line in (folder / "races.jsonl").read_text().splitlines()]
    assert rec["model"] == [rec["candidates"][0]] * (len(rec["progress_m"]) - 1)
