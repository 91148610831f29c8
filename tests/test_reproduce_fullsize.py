"""``alpha-racer reproduce --vehicle-class fullsize``: the full-size world's suites in one
folder, and its clear refusals."""

import json
import math

import pytest

from experiments.cli import main
from experiments.cli.reproduce_fullsize import FULLSIZE_MODELS, fullsize_ego


@pytest.mark.parametrize(
    "extra, says",
    [
        (["--space", "paper"], "extended or the wake policy space"),
        (["--space", "extended", "--strategy-races", "0"], "got 0"),
        (["--space", "extended", "--alpha-options", "others=guess"], "got 'guess'"),
    ],
)
def test_refuses_what_it_cannot_reproduce(extra, says, tmp_path, capsys):
    with pytest.raises(SystemExit) as err:
        main(["reproduce", "--vehicle-class", "fullsize", "--out", str(tmp_path), *extra])
    assert says in str(err.value)
    assert not any(tmp_path.iterdir())  # refused before anything ran


def test_alpha_options_are_for_the_full_size_world(tmp_path):
    with pytest.raises(SystemExit) as err:
        main(["reproduce", "--alpha-options", "anchor=best", "--out", str(tmp_path)])
    assert "is for --vehicle-class fullsize" in str(err.value)
    assert not any(tmp_path.iterdir())


def test_the_ego_is_the_spaces_shipped_model_or_the_named_one():
    assert fullsize_ego("extended", None) == f"alpha:model={FULLSIZE_MODELS['extended']}"
    assert fullsize_ego("wake", None) == "alpha:model=fullsize_monza_wake"
    assert fullsize_ego("wake", "my/model.npz") == "alpha:model=my/model.npz"
    assert (
        fullsize_ego("extended", None, "anchor=best,others=estimate")
        == "alpha:model=fullsize_monza,anchor=best,others=estimate"
    )


@pytest.mark.slow
def test_reproduce_fullsize_tiny_writes_suite_room_and_ladder(tmp_path, capsys):
    """End to end, tiny, on Monza (the control from the shipped best-theta table): the
    strategy suite of the full-size alpha against the class's best fixed theta, the room of
    its equal and defend races, the ladder and Table 1 of the class with alpha and with the
    control as ego, joined in README.md; every margin finite."""
    out = tmp_path / "fs"
    tiny = ["--strategy-races", "1", "--strategy-steps", "8", "--room-races", "1"]
    tiny += ["--ladder-races", "1", "--fullsize-tracks", "tumftm:Monza", "--races", "1"]
    argv = ["reproduce", "--vehicle-class", "fullsize", "--space", "extended", "--out", str(out)]
    assert main([*argv, *tiny, "--workers", "1"]) == 0
    strat = json.loads((out / "strategy" / "strategy.json").read_text())
    cfg = strat["config"]
    assert cfg["ego"] == "alpha:model=fullsize_monza"
    assert cfg["control"] == "mpc:space=extended,theta=best"
    assert cfg["vehicle_class"] == "fullsize" and cfg["steps"] == 8
    assert cfg["scenarios"] == ["pass", "equal", "defend"]
    room = json.loads(next((out / "strategy" / "room").glob("*/room.json")).read_text())
    assert {r["bench"] for r in room["rows"]} == {"equal", "defend"}
    for row in room["rows"]:
        assert math.isfinite(row["room_m"]["mean"]) and row["races"] == 1
    ladder = json.loads((out / "ladder" / "ladder.json").read_text())
    assert ladder["config"]["egos"] == [cfg["ego"], cfg["control"]]
    text = (out / "README.md").read_text()
    assert "# Strategy benchmark" in text and "# The room" in text and "# Pass ladder" in text
    assert "the paper's Table 1" in text and "what maximising the potential adds" in text
    table1 = json.loads((out / "paper_table" / "paper_table.json").read_text())
    control = json.loads((out / "paper_table_control" / "paper_table.json").read_text())
    assert table1["vehicle_class"] == control["vehicle_class"] == "fullsize"
    assert table1["ego"] == cfg["ego"] and control["ego"] == cfg["control"]
    assert table1["cases"]["I"]["opponents"] == "alpha:model=fullsize_monza_gamma0.98"
    assert table1["cases"]["V"]["opponents"] == "ppo"
    assert not (out / "control").exists()  # Monza's control came from the table
