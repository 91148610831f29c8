"""Strategy benchmark: a tiny suite of every scenario, its outputs' structure and behaviour
(same races for ego and control, seats per scenario, the defend ceiling and pace measurement,
metrics equal to those recomputed from the stored states, resume without new races)."""

import json

import numpy as np
import pytest

pytest.importorskip("daqp")

from experiments.cli import build_parser, main  # noqa: E402
from experiments.evaluation import strategy as sg  # noqa: E402
from experiments.evaluation.bench import BenchRun  # noqa: E402
from experiments.evaluation.metrics import RECORD_KEYS, record_metrics  # noqa: E402
from experiments.infra.parallel import Pool  # noqa: E402

TINY = sg.StrategyConfig(
    ego="alpha", control="mpc:zeta=1.02", tracks=("default",), races=3, steps=20, seed=7
)
ARGS = [
    "strategy",
    "--ego",
    "alpha",
    "--control",
    "mpc:zeta=1.02",
    "--tracks",
    "default",
    "--races",
    "3",
    "--steps",
    "20",
    "--seed",
    "7",
    "--workers",
    "1",
]


@pytest.fixture(scope="module")
def tiny_suite(tmp_path_factory):
    out = tmp_path_factory.mktemp("strategy")
    assert main(ARGS + ["--out", str(out)]) == 0
    return out, json.loads((out / "strategy.json").read_text())


def _runs(out, config=TINY):
    return {(c.bench, c.track, c.role): BenchRun(c.folder(out), c.config) for c in sg.cells(config)}


@pytest.mark.slow
def test_the_suite_has_a_row_per_bench_and_track_and_the_cli_wrote_it(tiny_suite):
    out, table = tiny_suite
    assert [r["bench"] for r in table["rows"]] == [
        "pass",
        "equal",
        "defend",
        "table1_ibr",
        "table1_ppo",
        "table1_alpha",
    ]
    assert table["config"] == TINY.to_dict()
    md = (out / "strategy.md").read_text()
    assert md.count("\n| ") == 1 + 6 + 1 + 3  # table header + rows, pace header + rows
    for r in table["rows"]:
        n = 1 if r["bench"].startswith("table1_") else 3  # table1 shares its 3 races
        for side in ("ego", "control"):
            assert r[side]["races"] == n and r[side]["complete"]
            assert sum(r[side]["races_by_region"].values()) == n
        assert (out / r["ego_dir"] / "summary.md").exists()
        assert (out / r["control_dir"] / "summary.md").exists()
        assert f"| {r['bench']} | `default` |" in md


@pytest.mark.slow
def test_ego_and_control_race_the_same_seeds_seats_and_opponents(tiny_suite):
    out, table = tiny_suite
    runs = _runs(out)
    seats = {"pass": ["R2", "R3", "R2"], "defend": ["R1"] * 3}
    opponents = {
        "pass": "raceline",
        "equal": "mpc:zeta=1.02",
        "defend": "mpc:zeta=1.02",
        "table1_ibr": "ibr",
        "table1_ppo": "ppo",
        "table1_alpha": "alpha",
    }
    for bench in opponents:
        ego, control = runs[(bench, "default", "ego")], runs[(bench, "default", "control")]
        e, c = ego.records(), control.records()
        assert sorted(e) == sorted(c) == ([0] if bench.startswith("table1_") else [0, 1, 2])
        for k in e:
            assert (e[k]["seed"], e[k]["start_regions"]) == (c[k]["seed"], c[k]["start_regions"])
            assert e[k]["agents"][1:] == c[k]["agents"][1:] == [opponents[bench]] * 2
            # the same start positions: the opponents' cars start where they did for the other
            np.testing.assert_array_equal(ego.states(k)[0, 1:], control.states(k)[0, 1:])
        assert [e[k]["ego_region"] for k in sorted(e)] == seats.get(bench, ["R1", "R2", "R3"])[
            : len(e)
        ]
    assert runs[("defend", "default", "ego")].config.ego == "alpha:zeta_max=0.94"
    assert runs[("defend", "default", "control")].config.ego == "mpc:zeta=1.02,zeta_max=0.94"


@pytest.mark.slow
def test_the_table_equals_the_metrics_recomputed_from_the_stored_states(tiny_suite):
    out, table = tiny_suite
    runs = _runs(out)
    for row in table["rows"]:
        for side in ("ego", "control"):
            run = runs[(row["bench"], row["track"], side)]
            recs = run.records()
            m = {k: record_metrics(run.states(k)) for k in recs}
            for k, rec in recs.items():
                assert {key: rec[key] for key in RECORD_KEYS} == m[k]
            got = row[side]
            assert got["passes"] == sum(m[k]["passes"][0] for k in m)
            assert got["passes_contact"] == sum(m[k]["passes_contact"][0] for k in m)
            assert got["opponent_passes"] == sum(sum(m[k]["passes"][1:]) for k in m)
            assert got["wins_from_behind"] == sum(
                m[k]["won_from_behind"] and recs[k]["winner"] == "ego" for k in m
            )
            assert got["behind_1m_s"] == pytest.approx(np.mean([m[k]["behind_1m_s"][0] for k in m]))
            s = [run.states(k) for k in sorted(recs)]
            margin = [st[-1, 0, 0] - st[-1, 1:, 0].max() for st in s]
            assert got["margin_m_mean"] == pytest.approx(np.mean(margin), abs=1e-3)
            assert got["wins"] == sum(int(np.argmax(st[-1, :, 0])) == 0 for st in s)


@pytest.mark.slow
def test_defend_measures_the_pace_gap_and_flags_a_small_one(tiny_suite):
    out, table = tiny_suite
    pace = table["pace"]["default"]
    capped_ego, capped_control, opponent = sg.pace_specs(TINY)
    assert pace["progress_m"][capped_ego] is None  # alpha cannot race alone
    assert "cannot race alone" in pace["reasons"][capped_ego]
    m_ctl, m_opp = pace["progress_m"][capped_control], pace["progress_m"][opponent]
    assert m_ctl > 0 and m_opp > 0
    assert pace["gaps"][capped_control] == pytest.approx(m_opp / m_ctl - 1)
    assert pace["ok"] == (m_opp / m_ctl - 1 >= sg.PACE_GAP)
    flagged = any("defend on default" in f for f in table["flags"])
    assert flagged == (not pace["ok"])
    if flagged:
        assert "**Flags:**" in (out / "strategy.md").read_text()
    recs = [json.loads(line) for line in (out / "pace.jsonl").read_text().splitlines()]
    assert sorted(r["spec"] for r in recs) == sorted(sg.pace_specs(TINY))


@pytest.mark.slow
def test_a_resumed_suite_runs_no_race_and_writes_the_same_table(tiny_suite):
    out, table = tiny_suite
    lines = {p: p.read_text() for p in out.rglob("*.jsonl")}
    again = sg.strategy(TINY, out, pool=Pool(workers=1, progress_bar=False))
    assert again["new_races"] == 0
    assert {p: p.read_text() for p in out.rglob("*.jsonl")} == lines
    assert again["rows"] == table["rows"] and again["pace"] == table["pace"]


def test_parser_defaults_are_the_config_defaults():
    args = build_parser().parse_args(["strategy"])
    d = sg.config_defaults()
    assert (
        args.ego,
        args.control,
        tuple(args.tracks),
        tuple(args.scenarios),
        args.races,
        args.steps,
        args.seed,
        args.zeta_max,
    ) == (
        d["ego"],
        d["control"],
        d["tracks"],
        d["scenarios"],
        d["races"],
        d["steps"],
        d["seed"],
        d["zeta_max"],
    )
    assert d["control"] == "mpc:theta=best" and d["races"] == 99


def test_bad_suites_are_refused_naming_the_value(tmp_path, capsys):
    with pytest.raises(ValueError, match="same spec 'mpc'"):
        sg.StrategyConfig(ego="mpc", control="mpc")
    with pytest.raises(ValueError, match=r"scenarios must be .* got \['pass', 'pass'\]"):
        sg.StrategyConfig(scenarios=("pass", "pass"))
    with pytest.raises(ValueError, match="zeta_max must be .* got 1.2"):
        sg.StrategyConfig(zeta_max=1.2)
    with pytest.raises(ValueError, match="races must be a positive integer, got 0"):
        sg.StrategyConfig(races=0)
    with pytest.raises(ValueError, match="sets zeta_max already"):
        sg.StrategyConfig(ego="mpc:zeta_max=0.9", control="mpc:zeta=1.0").capped("mpc:zeta_max=0.9")
    assert sg.with_option("alpha", "zeta_max", 0.94) == "alpha:zeta_max=0.94"
    assert sg.with_option("mpc:zeta=1.0", "zeta_max", 0.94) == "mpc:zeta=1.0,zeta_max=0.94"
    assert main(["strategy", "--ego", "nosuchagent", "--out", str(tmp_path)]) == 2
    assert "unknown agent 'nosuchagent'" in capsys.readouterr().err
    assert not list(tmp_path.rglob("races.jsonl"))  # refused before any race


def test_pass_opponents_name_the_pass_benches_followers_only():
    config = sg.StrategyConfig(
        ego="mpc", control="mpc:zeta=1.02", tracks=("default",), pass_opponents="raceline:grip=0.9"
    )
    opponents = {c.bench: c.config.opponents for c in sg.cells(config)}
    assert opponents["pass"] == "raceline:grip=0.9"
    assert opponents["equal"] == opponents["defend"] == "mpc:zeta=1.02"
    with pytest.raises(ValueError, match="pass_opponents"):
        sg.StrategyConfig(pass_opponents="")
