"""Policy map: Sobol thetas over the current box, rows, resume, determinism, summary, figures."""

import json

import numpy as np
import pytest

pytest.importorskip("daqp")

from experiments.cli import main  # noqa: E402
from experiments.evaluation import policy_map as pm  # noqa: E402
from experiments.evaluation import policy_map_summary as pms  # noqa: E402
from experiments.evaluation import thetas as pm_thetas  # noqa: E402
from experiments.infra.artifacts import read_jsonl  # noqa: E402
from experiments.infra.parallel import Pool  # noqa: E402

TINY = [
    "policy-map",
    "--thetas",
    "4",
    "--tracks",
    "default",
    "--steps",
    "30",
    "--modes",
    "solo",
    "race",
    "--workers",
    "1",
    "--seed",
    "5",
]


def _untimed(rows):
    return sorted(
        ({k: v for k, v in r.items() if k not in pm.TIMING_KEYS} for r in rows),
        key=lambda r: (r["mode"], r["track"], r["index"]),
    )


# ---------------------------------------------------------------------------- sampling
def test_sobol_thetas_fill_the_current_box_one_per_stratum():
    low, high = pm_thetas.theta_box()
    th = pm_thetas.sample_thetas(16, seed=3)
    assert th.shape == (16, 5)
    assert np.all(th >= low) and np.all(th < high)
    # a scrambled Sobol set of 2^m points has one point in each 1/2^m slice of every axis
    u = (th - low) / (high - low)
    assert all(sorted(np.floor(16 * u[:, d]).astype(int)) == list(range(16)) for d in range(5))
    assert np.array_equal(th, pm_thetas.sample_thetas(16, seed=3))
    assert not np.allclose(th, pm_thetas.sample_thetas(16, seed=4))


def test_box_is_read_at_run_time(monkeypatch):
    from agents import reference

    low = np.array([10.0, 0.8, 0.0, 1.0, 0.0])
    high = np.array([20.0, 1.1, 0.1, 2.0, 1.0])
    monkeypatch.setattr(reference, "THETA_LOW", low)
    monkeypatch.setattr(reference, "THETA_HIGH", high)
    th = pm_thetas.sample_thetas(8, seed=0)
    assert np.all(th >= low) and np.all(th < high)
    assert th[:, 1].max() > 1.05  # one point in the top eighth of the new zeta range


def test_theta_spec_is_exact():
    from agents import make_agent_spec

    th = pm_thetas.sample_thetas(2, seed=1)[1]
    agent = make_agent_spec(pm_thetas.theta_spec(th))
    assert np.array_equal(agent.theta.as_array(), th)


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="modes"):
        pm.PolicyMapConfig(modes=("solo", "duel"))
    with pytest.raises(ValueError, match="thetas must be a positive integer, got 0"):
        pm.PolicyMapConfig(thetas=0)
    with pytest.raises(ValueError, match="tracks"):
        pm.PolicyMapConfig(tracks=("oval", "oval"))


# ---------------------------------------------------------------------------- statistics
def test_best_flying_lap_skips_the_standing_start_lap():
    assert pm.best_flying_lap([10.0, 18.0, 25.5]) == pytest.approx(7.5)
    assert pm.best_flying_lap([10.0]) is None
    assert pm.best_flying_lap([]) is None


def test_binned_means_by_hand():
    x = [0.1, 0.2, 0.9, 1.0]  # 1.0 sits on the upper edge: last cell
    y = [0.1, 0.1, 0.9, 0.6]
    xe, ye, m = pms.binned_means(x, y, [1.0, 3.0, 5.0, 7.0], (0, 1), (0, 1), 2)
    assert xe.tolist() == [0.0, 0.5, 1.0] and ye.tolist() == [0.0, 0.5, 1.0]
    assert m[0, 0] == 2.0 and m[1, 1] == 6.0
    assert np.isnan(m[0, 1]) and np.isnan(m[1, 0])


def test_a_failing_run_becomes_an_error_row(monkeypatch):
    import experiments.evaluation.race

    def boom(*a, **k):
        raise FloatingPointError("solver diverged")

    monkeypatch.setattr(experiments.evaluation.race, "run_race", boom)
    cfg = pm.PolicyMapConfig(thetas=2, tracks=("default",), modes=("race",), steps=5)
    row = pm.map_row(cfg, "race", "default", 1, pm_thetas.sample_thetas(2, 0)[1])
    assert row["error"] == "FloatingPointError: solver diverged" and row["start_region"] == "R2"
    s = pms.summarise([row], cfg)
    assert s["maps"]["race"]["default"]["errors"] == 1
    assert "errors" in pms.summary_markdown(s)


def test_rows_raced_in_a_batch_are_the_rows_raced_alone(monkeypatch):
    """map_rows (the pool's task: a lockstep batch of both modes) gives each row map_row gives
    alone; a batch in which one race fails is raced again row by row, the failure an error
    row."""
    cfg = pm.PolicyMapConfig(thetas=3, tracks=("default",), steps=20, seed=2)
    thetas = pm_thetas.sample_thetas(3, 2)
    items = [(mode, "default", k, thetas[k]) for mode in ("solo", "race") for k in range(3)]
    skip = ("seconds", "decision_ms")
    batch = pm.map_rows(cfg, items)
    alone = [pm.map_row(cfg, *item) for item in items]
    for got, ref in zip(batch, alone):
        assert {k: v for k, v in got.items() if k not in skip} == {
            k: v for k, v in ref.items() if k not in skip
        }
    import experiments.evaluation.races

    def boom(specs):
        raise FloatingPointError("solver diverged")

    monkeypatch.setattr(experiments.evaluation.races, "run_races", boom)
    again = pm.map_rows(cfg, items[:2])
    assert [r["progress_m"] for r in again] == [r["progress_m"] for r in alone[:2]]


# ---------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def tiny_map(tmp_path_factory):
    out = tmp_path_factory.mktemp("pm") / "map"
    assert main(TINY + ["--out", str(out)]) == 0
    return out


def test_tiny_map_writes_rows_summary_and_heat_maps(tiny_map):
    rows = read_jsonl(tiny_map / "rows.jsonl")
    assert len(rows) == 8
    assert {(r["mode"], r["index"]) for r in rows} == {(m, k) for m in pm.MODES for k in range(4)}
    low, high = pm_thetas.theta_box()
    for r in rows:
        assert "error" not in r
        th = np.array(list(r["theta"].values()))
        assert np.all(th >= low) and np.all(th <= high)
        assert r["steps"] == 30 and 0.0 <= r["off_track_frac"] <= 1.0
        assert r["off_track_frac"] == pytest.approx(r["off_track_steps"] / 30)
        assert r["progress_m"] > 0
    race = sorted((r for r in rows if r["mode"] == "race"), key=lambda r: r["index"])
    assert [r["start_region"] for r in race] == ["R1", "R2", "R3", "R1"]
    for r in race:
        assert r["rank"] in (1, 2, 3)
        assert r["margin_m"] == pytest.approx(
            r["progress_m"] - max(r["opponents_progress_m"]), abs=1e-3
        )
        assert (r["rank"] == 1) == (r["margin_m"] >= 0)
    manifest = json.loads((tiny_map / "manifest.json").read_text())
    box = manifest["config"]["theta_box"]
    assert box["low"] == low.tolist() and box["high"] == high.tolist()
    s = json.loads((tiny_map / "summary.json").read_text())
    assert s["complete"] and s["rows"] == 8
    for mode in pm.MODES:
        g = s["maps"][mode]["default"]
        assert 0.0 <= g["off_track_share"] <= 1.0
        assert sum(b["thetas"] for b in g["by_zeta"]) == 4
        progress = [t["progress_m"] for t in g["top10"]]
        assert progress == sorted(progress, reverse=True)
        if g["best"] is not None:
            assert g["best"]["progress_m"] == max(progress)
    md = (tiny_map / "summary.md").read_text()
    assert "| solo | `default` | 4 |" in md and "| race | `default` | 4 |" in md
    for mode in pm.MODES:
        png = tiny_map / f"heatmap_{mode}_default.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_rerun_resumes_without_recomputing(tiny_map):
    before = (tiny_map / "rows.jsonl").read_bytes()
    cfg = pm.PolicyMapConfig(thetas=4, tracks=("default",), steps=30, seed=5)
    s = pm.policy_map(cfg, tiny_map, pool=Pool(workers=1, progress_bar=False))
    assert s["new_rows"] == 0
    assert (tiny_map / "rows.jsonl").read_bytes() == before


def test_another_config_is_refused(tiny_map, capsys):
    args = [a if a != "30" else "31" for a in TINY]
    assert main(args + ["--out", str(tiny_map)]) == 2
    assert "policy map of another configuration" in capsys.readouterr().err


def test_a_map_of_another_theta_box_is_refused(tiny_map, monkeypatch):
    from agents import reference

    monkeypatch.setattr(reference, "THETA_HIGH", np.array(reference.THETA_HIGH) + 0.05)
    cfg = pm.PolicyMapConfig(thetas=4, tracks=("default",), steps=30, seed=5)
    with pytest.raises(ValueError, match="another configuration.*theta_box"):
        pm.policy_map(cfg, tiny_map, pool=Pool(workers=1, progress_bar=False))


@pytest.mark.slow
def test_same_seed_same_rows_and_a_torn_row_is_redone(tiny_map, tmp_path):
    out = tmp_path / "again"
    cfg = pm.PolicyMapConfig(thetas=4, tracks=("default",), steps=30, seed=5)
    pm.policy_map(cfg, out, pool=Pool(workers=1, progress_bar=False))
    first = read_jsonl(tiny_map / "rows.jsonl")
    assert _untimed(read_jsonl(out / "rows.jsonl")) == _untimed(first)
    # a kill while writing the last row: a torn line; the rerun computes that row only
    lines = (out / "rows.jsonl").read_text().splitlines()
    (out / "rows.jsonl").write_text("\n".join(lines[:-1]) + "\n" + lines[-1][:25])
    s = pm.policy_map(cfg, out, pool=Pool(workers=1, progress_bar=False))
    assert s["new_rows"] == 1
    assert _untimed(read_jsonl(out / "rows.jsonl")) == _untimed(first)


def test_every_option_says_its_default():
    from experiments.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command")
    pm = sub.choices["policy-map"]
    opts = [a for a in pm._actions if a.dest not in ("help",)]
    assert {a.dest for a in opts} >= {
        "thetas",
        "tracks",
        "modes",
        "steps",
        "seed",
        "workers",
        "backend",
        "out",
    }
    text = " ".join(pm.format_help().split())
    for shown in (
        "(default: 256)",
        "(default: 500)",
        "(default: results/policy_map)",
        "(default: local)",
    ):
        assert shown in text, shown


def test_cli_races_the_theta_against_the_opponents_named(tmp_path):
    out = tmp_path / "pm"
    assert (
        main(
            [
                "policy-map",
                "--thetas",
                "2",
                "--tracks",
                "oval",
                "--modes",
                "race",
                "--opponents",
                "raceline",
                "--steps",
                "20",
                "--workers",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["config"]["opponents"] == "raceline"
    rows = [json.loads(line) for line in (out / "rows.jsonl").open()]
    assert len(rows) == 2 and all(len(r["opponents_progress_m"]) == 2 for r in rows)
    assert "race opponents: two `raceline`" in (out / "summary.md").read_text()


def test_an_extended_map_samples_b_and_races_it():
    from agents import make_agent_spec

    cfg = pm.PolicyMapConfig(
        thetas=2, tracks=("default",), modes=("solo",), steps=5, space="extended"
    )
    low, high = pm_thetas.theta_box("extended")
    assert low.shape == (6,) and (low[5], high[5]) == (0.0, 1.0)
    th = pm_thetas.sample_thetas(2, 0, low, high)
    spec = pm_thetas.theta_spec(th[0])
    assert spec.startswith("mpc:space=extended,") and f"b={float(th[0][5])!r}" in spec
    assert make_agent_spec(spec).theta.b == th[0][5]
    row = pm.map_row(cfg, "solo", "default", 0, th[0])
    assert row["theta"]["b"] == th[0][5] and row["progress_m"] > 0
    with pytest.raises(ValueError, match="policy space must be one of"):
        pm.PolicyMapConfig(space="big")
