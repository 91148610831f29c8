"""The pipeline on the extended policy space: the best-theta table's entries per space (and
its backward compatibility), ``control --space extended``, a tiny strategy suite with the
extended ego and a tiny ``reproduce --space extended``."""

import json
import math

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents import best_theta, make_agent_spec  # noqa: E402
from agents.best_theta import TABLE_ENV_VAR  # noqa: E402
from agents.theta import EXTENDED_HIGH, EXTENDED_LOW, EXTENDED_NAMES, THETA_NAMES  # noqa: E402
from experiments.cli import main  # noqa: E402
from experiments.evaluation import control as ct  # noqa: E402
from experiments.evaluation import control_rule as ct_rule  # noqa: E402
from experiments.infra.parallel import Pool  # noqa: E402

PAPER_THETA = {"q": 20.0, "zeta": 0.95, "s1": 0.1, "s2": 4.0, "s3": 1.0}
EXTENDED_THETA = {**PAPER_THETA, "zeta": 1.0, "b": 0.6}


def _entry(track: str, theta: dict, space: str | None = None) -> dict:
    from racing_env.tracks import make_track

    t = make_track(track)
    entry = {
        "track": track,
        "name": t.name,
        "fingerprint": t.fingerprint(),
        "env": best_theta.env_name(),
        "theta": theta,
        "package_version": "test",
        "selection": {"file": "hand-made", "sha256": "0" * 64},
    }
    return entry if space is None else {**entry, "space": space}


@pytest.fixture
def table(tmp_path, monkeypatch):
    path = tmp_path / "table.json"
    monkeypatch.setenv(TABLE_ENV_VAR, str(path))
    return path


def _old_table(path, *entries) -> None:
    """A table as written before policy spaces: paper entries under ``tracks`` only."""
    path.write_text(json.dumps({"schema_version": 1, "tracks": {e["track"]: e for e in entries}}))


def _both_spaces_table(path) -> None:
    """A table with a paper and an extended entry for ``default``."""
    _old_table(path, _entry("default", PAPER_THETA))
    t = best_theta.read_table(path)
    best_theta.set_space_entries(
        t, "extended", {"default": _entry("default", EXTENDED_THETA, "extended")}
    )
    path.write_text(json.dumps(t))


# ---------------------------------------------------------------------------- the table
def test_an_old_table_still_reads_and_names_the_command_for_the_extended_entry(table):
    _old_table(table, _entry("default", PAPER_THETA))
    assert best_theta.best_theta("default").as_array().tolist() == list(PAPER_THETA.values())
    assert best_theta.space_entries(best_theta.read_table(), "extended") == {}
    with pytest.raises(ValueError) as err:
        best_theta.lookup("default", space="extended")
    msg = str(err.value)
    assert "no best fixed theta of the 'extended' policy space for track 'default'" in msg
    assert "alpha-racer control --space extended --tracks default" in msg
    with pytest.raises(ValueError, match="policy space must be one of"):
        best_theta.lookup("default", space="huge")


def test_entries_of_each_space_are_kept_apart_and_raced_by_their_own_spec(table):
    _both_spaces_table(table)
    # a reader that knows only "tracks" (the schema before spaces) sees the paper entries
    raw = json.loads(table.read_text())
    assert raw["schema_version"] == 1 and raw["tracks"]["default"]["theta"] == PAPER_THETA
    ext = best_theta.best_theta("default", space="extended")
    assert ext.b == 0.6 and ext.zeta == 1.0
    assert best_theta.best_theta("default").b == 0.0
    agent = make_agent_spec("mpc:space=extended,theta=best")
    agent.reset("default")
    assert agent.theta == ext
    paper = make_agent_spec("mpc:theta=best")
    paper.reset("default")
    assert paper.theta.as_array().tolist() == list(PAPER_THETA.values())


def test_an_entry_of_another_space_s_theta_or_an_unknown_space_is_refused(table):
    bad = {
        "schema_version": 1,
        "tracks": {},
        "spaces": {"extended": {"default": _entry("default", PAPER_THETA, "extended")}},
    }
    table.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match="entry 'default' under the 'extended' space.*expected"):
        best_theta.read_table()
    bad["spaces"] = {"huge": {}}
    table.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"unknown policy space\(s\) \['huge'\]"):
        best_theta.read_table()


def test_the_shipped_table_holds_an_extended_entry_for_default_inside_the_box():
    table = best_theta.read_table(best_theta.DEFAULT_TABLE)
    assert set(table["tracks"]["default"]["theta"]) == set(THETA_NAMES)
    entry = best_theta.space_entries(table, "extended")["default"]
    assert entry["space"] == "extended" and entry["selection"]["config"]["space"] == "extended"
    theta = np.array([entry["theta"][n] for n in EXTENDED_NAMES])
    assert np.all((EXTENDED_LOW <= theta) & (theta <= EXTENDED_HIGH))


def test_install_adds_an_extended_winner_beside_the_paper_entries(table, tmp_path):
    _old_table(table, _entry("default", PAPER_THETA))
    sel = {
        "track": "default",
        "name": "default",
        "fingerprint": _entry("default", PAPER_THETA)["fingerprint"],
        "env": best_theta.env_name(),
        "package_version": "test",
        "rule": ct_rule.RULE,
        "config": {**ct.stored_config(ct.ControlConfig(space="extended"))},
        "candidates": [{}],
        "winner": {
            "theta": EXTENDED_THETA,
            "index": 3,
            "wins": 2,
            "races": 3,
            "margin_m_mean": 0.1,
        },
    }
    path = tmp_path / "selection.json"
    path.write_text(json.dumps(sel))
    entry = ct.install(path)
    assert entry["space"] == "extended" and entry["theta"] == EXTENDED_THETA
    t = best_theta.read_table()
    assert t["tracks"]["default"]["theta"] == PAPER_THETA  # the paper entry is untouched
    assert best_theta.lookup("default", space="extended")["selection"]["index"] == 3
    # a paper config's stored form is the one written before spaces (folders resume)
    assert "space" not in ct.stored_config(ct.ControlConfig())
    assert ct.best_fixed_spec("extended") == "mpc:space=extended,theta=best"
    assert ct.best_fixed_spec() == ct.BEST_FIXED_SPEC == "mpc:theta=best"


# ---------------------------------------------------------------------------- control
def test_control_on_the_extended_space_picks_a_theta_in_the_extended_box_with_b(table, tmp_path):
    _old_table(table, _entry("default", PAPER_THETA))
    cfg = ct.ControlConfig(thetas=2, candidates=1, races=3, steps=15, space="extended")
    out = tmp_path / "ctl"
    ct.select_best_thetas(cfg, ["default"], out, Pool(workers=1, progress_bar=False))
    sel = json.loads((out / "default" / "selection.json").read_text())
    assert sel["config"]["space"] == "extended" and sel["map"]["errors"] == 0
    entry = best_theta.lookup("default", space="extended")
    assert entry["theta"] == sel["winner"]["theta"] and set(entry["theta"]) == set(EXTENDED_NAMES)
    theta = np.array([entry["theta"][n] for n in EXTENDED_NAMES])
    assert np.all((EXTENDED_LOW <= theta) & (theta <= EXTENDED_HIGH))
    assert best_theta.lookup("default")["theta"] == PAPER_THETA  # paper entry kept
    summary = (out / "summary.md").read_text()
    assert "of the extended policy space" in summary and "s3, b)" in summary
    # the playoff raced the extended spec of the candidate
    manifest = json.loads(next((out / "default" / "playoff").glob("*/manifest.json")).read_text())
    assert manifest["config"]["ego"].startswith("mpc:space=extended,")
    # the compass search moves b too, and races extended specs
    moves = {m["move"] for m in sel["refine"][0]["moves"]}
    assert moves & {"b-", "b+"} and moves & {"q-", "q+"}
    for f in (out / "default" / "refine").glob("*/manifest.json"):
        assert json.loads(f.read_text())["config"]["ego"].startswith("mpc:space=extended,")
    # a paper folder is not resumed with the extended config, nor the other way round
    with pytest.raises(ValueError, match="another configuration"):
        ct.select_best_thetas(
            ct.ControlConfig(thetas=2, candidates=1, races=3, steps=15),
            ["default"],
            out,
            Pool(workers=1, progress_bar=False),
        )


def test_control_command_defaults_to_its_own_folder_per_space():
    assert ct.default_out("paper") == "results/control"
    assert ct.default_out("extended") == "results/control_extended"


# ---------------------------------------------------------------------------- strategy
def test_a_tiny_strategy_suite_with_the_extended_ego_and_control(table, tmp_path, capsys):
    _both_spaces_table(table)
    out = tmp_path / "strategy"
    args = [
        "strategy",
        "--ego",
        "alpha:space=extended",
        "--control",
        "mpc:space=extended,theta=best",
    ]
    args += ["--tracks", "default", "--scenarios", "pass", "equal", "--races", "2"]
    assert main(args + ["--steps", "8", "--workers", "1", "--out", str(out)]) == 0
    s = json.loads((out / "strategy.json").read_text())
    assert [r["bench"] for r in s["rows"]] == ["pass", "equal"]
    for r in s["rows"]:
        assert r["ego_spec"] == "alpha:space=extended"
        assert r["control_spec"] == "mpc:space=extended,theta=best"
        assert r["ego"]["races"] == r["control"]["races"] == 2
        assert math.isfinite(r["ego"]["margin_m_mean"]) and math.isfinite(
            r["control"]["margin_m_mean"]
        )
    claimed = json.loads((out / s["rows"][0]["control_dir"] / "best_fixed_theta.json").read_text())
    assert claimed["spaces"]["extended"]["default"]["theta"] == EXTENDED_THETA
    assert claimed["config"] == {}  # the suite raced no paper best theta


# ---------------------------------------------------------------------------- reproduce
def _numbers(md: str) -> list[str]:
    """The table cells of a Markdown file (rows starting with ``|``, header rules left out)."""
    return [
        cell.strip()
        for line in md.splitlines()
        if line.startswith("|") and not line.startswith("|---")
        for cell in line.strip("|").split("|")
    ]


def test_reproduce_on_the_extended_space_writes_every_table_tiny(table, tmp_path, capsys):
    """``reproduce --space extended`` end to end, tiny: the extended ego and control in
    Table 1 and the comparison, the analyses of the extended model, the strategy suite and
    the extended policy map; every number finite."""
    _both_spaces_table(table)
    out = tmp_path / "rep"
    tiny = ["--races", "1", "--steps", "22", "--heldout-races", "1", "--gap-pairs", "40"]
    tiny += ["--regret-states", "1", "--regret-horizon", "2", "--cem-iterations", "1"]
    tiny += ["--cem-samples", "2", "--slice-points", "5", "--policy-thetas", "1"]
    tiny += ["--strategy-races", "1", "--strategy-steps", "8", "--control-ego", "raceline"]
    assert (
        main(["reproduce", "--space", "extended", "--out", str(out), *tiny, "--workers", "1"]) == 0
    )
    table1 = json.loads((out / "paper_table" / "paper_table.json").read_text())
    control = json.loads((out / "paper_table_control" / "paper_table.json").read_text())
    assert table1["ego"] == "alpha:space=extended"
    assert control["ego"] == "mpc:space=extended,theta=best"
    assert list(table1["cases"]) == list(control["cases"]) == ["I", "II", "III", "IV", "V"]
    for t in (table1, control):  # cases I-III against the extended space's own models
        assert t["space"] == "extended"
        assert t["cases"]["I"]["opponents"] == "alpha:space=extended,model=extended_gamma0.98"
        assert t["cases"]["IV"]["opponents"] == "ibr"
    for case in control["cases"]:  # each case's folder records the extended theta it raced
        claimed = json.loads(
            (out / "paper_table_control" / f"case_{case}" / "best_fixed_theta.json").read_text()
        )
        assert claimed["spaces"]["extended"]["default"]["theta"] == EXTENDED_THETA
    comparison = (out / "comparison.md").read_text()
    assert "alpha = `alpha:space=extended`" in comparison
    assert "best fixed = `mpc:space=extended,theta=best`" in comparison
    assert "alpha-racer control --space extended --tracks default" in comparison
    summary = json.loads((out / "analysis" / "summary.json").read_text())
    assert summary["config"]["model"] == "extended"
    assert set(summary["slices"]) == set(EXTENDED_NAMES)  # the model's six parameters
    heldout = json.loads((out / "analysis" / "heldout" / "manifest.json").read_text())
    assert heldout["config"]["space"] == "extended" and heldout["config"]["start"] == "close"
    for key in ("median", "p95", "max"):
        assert math.isfinite(summary["gap"][key])
    assert math.isfinite(summary["regret"]["regret_max"])
    strat = json.loads((out / "strategy" / "strategy.json").read_text())
    assert strat["config"]["ego"] == "alpha:space=extended"
    assert strat["config"]["control"] == "mpc:space=extended,theta=best"
    pm = json.loads((out / "policy_map" / "manifest.json").read_text())
    assert pm["config"]["space"] == "extended" and pm["config"]["theta_box"]["names"][-1] == "b"
    text = (out / "README.md").read_text()
    for md in (
        out / "paper_table" / "paper_table.md",
        out / "paper_table_control" / "paper_table.md",
        out / "comparison.md",
        out / "strategy" / "strategy.md",
    ):
        assert md.read_text() in text
        cells = _numbers(md.read_text())
        assert cells and not any(c in ("nan", "+nan", "inf", "-inf") for c in cells)
    assert "nan" not in (out / "analysis" / "summary.md").read_text()
