"""The best fixed theta per track: the selection rule, the table, mpc:theta=best, the command."""

import json

import numpy as np
import pytest

from experiments.infra.artifacts import claim_best_thetas
from experiments.infra.parallel import Pool

pytest.importorskip("daqp")

from agents import best_theta, make_agent_spec  # noqa: E402
from agents.best_theta import TABLE_ENV_VAR  # noqa: E402
from experiments.cli import main  # noqa: E402
from experiments.evaluation import control as ct  # noqa: E402
from experiments.evaluation import control_rule as ct_rule  # noqa: E402

NAMES = ("q", "zeta", "s1", "s2", "s3")


def _theta(k: int) -> dict:
    return {"q": 10.0 + k, "zeta": 0.9 + 0.01 * k, "s1": 0.1, "s2": 4.0, "s3": 1.0}


def _rows(race: dict, solo: dict, off=(), solo_off=(), errors=()) -> list[dict]:
    """Hand-made map rows: ``race[k] = (start region, progress)``, ``solo[k] = progress``."""
    rows = []
    for k, (reg, p) in race.items():
        r = {
            "mode": "race",
            "track": "default",
            "index": k,
            "theta": _theta(k),
            "start_region": reg,
            "progress_m": p,
            "margin_m": p - 100.0,
            "off_track_frac": 0.05 if k in off else 0.0,
        }
        if k in errors:
            r = {
                "mode": "race",
                "track": "default",
                "index": k,
                "theta": _theta(k),
                "start_region": reg,
                "error": "RuntimeError: boom",
            }
        rows.append(r)
    for k, p in solo.items():
        rows.append(
            {
                "mode": "solo",
                "track": "default",
                "index": k,
                "theta": _theta(k),
                "progress_m": p,
                "off_track_frac": 0.02 if k in solo_off else 0.0,
            }
        )
    return rows


# ---------------------------------------------------------------------------- the rule
def test_candidates_are_ranked_within_their_start_region_then_by_adjusted_progress():
    # R1 starts are worth more raw progress than R3 starts: adjusted, theta 3 (R3) is the best
    race = {
        0: ("R1", 110.0),
        1: ("R1", 104.0),
        2: ("R1", 100.0),
        3: ("R3", 99.0),
        4: ("R3", 90.0),
        5: ("R3", 91.0),
    }
    solo = {k: 150.0 for k in race}
    cands = ct_rule.choose_candidates(_rows(race, solo), k=2)
    assert [c["index"] for c in cands] == [3, 0]  # +8.0 (99 - 91), +6.0 (110 - 104)
    assert cands[0]["race_adjusted_m"] == pytest.approx(8.0)
    assert [c["region_rank"] for c in cands] == [1, 1]
    # the best solo theta (index 0 on a tie of all: the lower index) is already in: no extra
    assert cands[1]["reasons"] == ["race", "solo"]
    # a wide spread from R1 (free road) does not crowd out the best from R3 (in traffic):
    # theta 1 is +14.5 m over R1's median, theta 3 only +1 m over R3's, but it is R3's best
    race = {
        0: ("R1", 130.0),
        1: ("R1", 129.0),
        2: ("R1", 100.0),
        9: ("R1", 90.0),
        3: ("R3", 96.0),
        4: ("R3", 95.0),
        5: ("R3", 94.0),
    }
    cands = ct_rule.choose_candidates(_rows(race, {k: 150.0 for k in race}), k=3)
    assert [(c["index"], c["region_rank"]) for c in cands] == [(0, 1), (3, 1), (1, 2)]


def test_best_solo_theta_joins_and_off_track_or_failed_thetas_never_do():
    race = {
        0: ("R1", 110.0),
        1: ("R1", 105.0),
        2: ("R2", 103.0),
        3: ("R2", 100.0),
        4: ("R3", 95.0),
        5: ("R3", 96.0),
    }
    solo = {0: 150.0, 1: 140.0, 2: 160.0, 3: 190.0, 4: 145.0, 5: 170.0}
    # theta 0 leaves the track in the race, 3 alone (although best alone), 5 failed its race
    rows = _rows(race, solo, off={0}, solo_off={3}, errors={5})
    assert ct_rule.eligible_indices(rows) == [1, 2, 4]
    cands = ct_rule.choose_candidates(rows, k=1)
    assert [(c["index"], c["reasons"]) for c in cands] == [(2, ["race", "solo"])]
    cands = ct_rule.choose_candidates(_rows(race, solo, off={0}, errors={5}), k=1)
    assert [(c["index"], c["reasons"]) for c in cands] == [(2, ["race"]), (3, ["solo"])]
    with pytest.raises(ValueError, match="no theta of the map on \\['default'\\] stays on track"):
        ct_rule.choose_candidates(_rows(race, solo, off=set(race)), k=2)


def test_candidate_ties_go_to_the_lower_index():
    race = {4: ("R1", 100.0), 1: ("R1", 100.0), 7: ("R1", 100.0)}
    cands = ct_rule.choose_candidates(_rows(race, {k: 120.0 for k in race}), k=2)
    assert [c["index"] for c in cands] == [1, 4]


def test_playoff_ranks_wins_then_margin_then_index():
    scores = [
        {"index": 9, "wins": 10, "margin_m_mean": -1.0},
        {"index": 3, "wins": 11, "margin_m_mean": -5.0},
        {"index": 5, "wins": 10, "margin_m_mean": 0.5},
        {"index": 2, "wins": 10, "margin_m_mean": 0.5},
    ]
    ranked = ct_rule.rank_playoff(scores)
    assert [(s["index"], s["rank"]) for s in ranked] == [(3, 1), (2, 2), (5, 3), (9, 4)]
    assert ct_rule.rank_playoff(list(reversed(scores))) == ranked
    with pytest.raises(ValueError, match="non-finite playoff margin of candidate\\(s\\) \\[5\\]"):
        ct_rule.rank_playoff([{"index": 5, "wins": 1, "margin_m_mean": float("nan")}])
    with pytest.raises(ValueError, match="repeated candidate index"):
        ct_rule.rank_playoff([scores[0], scores[0]])
    with pytest.raises(ValueError, match="no playoff scores"):
        ct_rule.rank_playoff([])


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="seed 0 is the benchmarks' seed"):
        ct.ControlConfig(seed=0)
    with pytest.raises(ValueError, match="races must be a multiple of 3.*got 10"):
        ct.ControlConfig(races=10)
    with pytest.raises(ValueError, match="candidates must be a positive integer, got 0"):
        ct.ControlConfig(candidates=0)
    for bad in (-1, True, 1.5):
        with pytest.raises(ValueError, match="refine must be a non-negative integer"):
            ct.ControlConfig(refine=bad)
    assert ct.ControlConfig().playoff_config("oval", np.array([5, 1.0, 0.2, 3, 1])).seed == 100


# ---------------------------------------------------------------------------- theta=best
def _entry(track: str, theta: dict, env: str | None = None) -> dict:
    from racing_env.tracks import make_track

    t = make_track(track)
    return {
        "track": track,
        "name": t.name,
        "fingerprint": t.fingerprint(),
        "env": env or best_theta.env_name(),
        "theta": theta,
        "package_version": "test",
        "selection": {"file": "hand-made", "sha256": "0"},
    }


@pytest.fixture
def table(tmp_path, monkeypatch):
    path = tmp_path / "table.json"
    monkeypatch.setenv(TABLE_ENV_VAR, str(path))
    return path


def _write(path, *entries):
    path.write_text(json.dumps({"schema_version": 1, "tracks": {e["track"]: e for e in entries}}))


def test_theta_best_resolves_per_track_at_reset(table):
    a = {"q": 5.0, "zeta": 1.04, "s1": 0.3, "s2": 0.5, "s3": 4.0}
    b = {"q": 300.0, "zeta": 1.01, "s1": 0.0, "s2": 10.0, "s3": 0.0}
    _write(table, _entry("default", a), _entry("oval", b))
    agent = make_agent_spec("mpc:theta=best")
    for track, want in (("default", a), ("oval", b), ("default", a)):  # one agent, a league
        agent.reset(track, "car_0", 0)
        assert agent.theta.as_array().tolist() == [want[n] for n in NAMES]
    obs = np.zeros(6 + 10, dtype=np.float32)
    obs[3] = 1.0
    assert agent.act(obs).shape == (2,)


def test_theta_best_errors_name_the_track_and_the_command(table):
    _write(table, _entry("default", _theta(0)))
    agent = make_agent_spec("mpc:theta=best")
    with pytest.raises(
        ValueError,
        match="no best fixed theta for track 'oval'.*it has: default.*"
        "alpha-racer control --tracks oval",
    ):
        agent.reset("oval")
    _write(table, _entry("default", _theta(0), env="alpha_racer_v0"))
    with pytest.raises(
        ValueError,
        match="track 'default'.*chosen on env 'alpha_racer_v0', this is "
        "'alpha_racer_v\\d+'.*alpha-racer control --tracks default",
    ):
        agent.reset("default")
    e = _entry("default", _theta(0))
    e["fingerprint"] = "0123456789abcdef"
    _write(table, e)
    with pytest.raises(ValueError, match="track 'default'.*another geometry"):
        agent.reset("default")
    with pytest.raises(ValueError, match="drop zeta=1.0"):
        make_agent_spec("mpc:theta=best,zeta=1.0")
    with pytest.raises(ValueError, match="theta must be 'best'.*got 'good'"):
        make_agent_spec("mpc:theta=good")
    with pytest.raises(ValueError, match="alpha chooses its theta online"):
        make_agent_spec("alpha:theta=best")
    table.write_text("{}")
    with pytest.raises(ValueError, match="not a table of schema version 1"):
        agent.reset("default")


def test_explicit_theta_keywords_and_the_listing_keep_their_defaults(capsys):
    agent = make_agent_spec("mpc:zeta=1.02")
    assert agent.theta.as_array().tolist() == [20.0, 1.02, 0.1, 4.0, 1.0] and not agent.best
    assert main(["agents"]) == 0
    text = capsys.readouterr().out
    assert (
        "theta = None  ('best': the track's best fixed theta of the agent's space, chosen by "
        "alpha-racer control)" in text
    )


def test_bench_with_theta_best_fails_before_racing_on_a_track_missing_from_the_table(
    table, tmp_path, capsys
):
    _write(table, _entry("default", _theta(0)))
    assert (
        main(
            [
                "bench",
                "--ego",
                "mpc:theta=best",
                "--opponents",
                "raceline",
                "--track",
                "oval",
                "--races",
                "1",
                "--steps",
                "5",
                "--workers",
                "1",
                "--out",
                str(tmp_path / "b"),
            ]
        )
        == 2
    )
    assert "no best fixed theta for track 'oval'" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


def test_shipped_table_is_a_valid_table():
    table = best_theta.read_table(best_theta.DEFAULT_TABLE)
    for spec, e in table["tracks"].items():
        assert e["track"] == spec and set(e["theta"]) == set(NAMES)
        assert e["selection"]["sha256"] and e["selection"]["config"]["seed"] != 0


# ---------------------------------------------------------------------------- the command
TINY = [
    "control",
    "--tracks",
    "default",
    "--thetas",
    "2",
    "--candidates",
    "1",
    "--races",
    "3",
    "--steps",
    "20",
    "--workers",
    "1",
]


@pytest.mark.slow
def test_control_command_selects_installs_and_resumes(table, tmp_path, capsys):
    out = tmp_path / "ctl"
    assert main(TINY + ["--out", str(out)]) == 0
    sel_path = out / "default" / "selection.json"
    sel = json.loads(sel_path.read_text())
    assert sel["env"] == best_theta.env_name() and sel["config"]["thetas"] == 2
    # the playoff's first starts the compass search (2 rounds by default); its last
    # incumbent wins, and ranks at least as high as the playoff's first
    assert sel["candidates"][0]["rank"] == 1 and sel["config"]["refine"] == 2
    rounds = sel["refine"]
    assert [r["round"] for r in rounds] == [1, 2]
    assert rounds[0]["from"] == sel["candidates"][0]["index"]
    assert rounds[1]["from"] == rounds[0]["to"] and rounds[1]["to"] == sel["winner"]["index"]
    first = sel["candidates"][0]
    assert (-sel["winner"]["wins"], -sel["winner"]["margin_m_mean"]) <= (
        -first["wins"],
        -first["margin_m_mean"],
    )
    assert {c["index"] for c in sel["candidates"]} <= {0, 1}
    refined = {m["index"] for r in rounds for m in r["moves"]}
    assert min(refined) == 2  # after the map's indices
    assert len(list((out / "default" / "refine").glob("theta_*/races.jsonl"))) == len(refined)
    for c in sel["candidates"]:
        assert c["races"] == 3 and sum(c["wins_by_region"].values()) == c["wins"]
        assert np.isfinite(c["margin_m_mean"])
    entry = best_theta.lookup("default")
    assert entry["theta"] == sel["winner"]["theta"]
    assert entry["selection"]["sha256"] == ct.selection_sha256(sel_path)
    assert make_agent_spec("mpc:theta=best").check_track("default") is None
    rows = (out / "default" / "map" / "rows.jsonl").read_text()
    before = sel_path.read_bytes()
    capsys.readouterr()
    assert main(TINY + ["--out", str(out)]) == 0  # resume: nothing runs again
    assert "0 new map runs and 0 new playoff races" in capsys.readouterr().out
    assert (out / "default" / "map" / "rows.jsonl").read_text() == rows
    assert sel_path.read_bytes() == before
    assert main(TINY[:-2] + ["--workers", "1", "--races", "6", "--out", str(out)]) == 2
    assert "another configuration" in capsys.readouterr().err


@pytest.mark.slow
def test_ensure_selects_only_missing_tracks_and_claim_refuses_a_changed_table(table, tmp_path):
    cfg = ct.ControlConfig(thetas=2, candidates=1, races=3, steps=20, refine=0)
    _write(table, _entry("oval", _theta(1)))
    got = ct.ensure_best_thetas(
        ["oval", "default"], cfg, tmp_path / "ctl", pool=Pool(workers=1, progress_bar=False)
    )
    assert got["oval"]["theta"] == _theta(1) and got["default"]["selection"]["index"] in (0, 1)
    assert [p.parent.name for p in (tmp_path / "ctl").glob("*/selection.json")] == ["default"]
    claim_best_thetas(tmp_path / "run", ["oval", "default"])
    claim_best_thetas(tmp_path / "run", ["oval", "default"])  # same: resumes
    table_now = json.loads(table.read_text())
    table_now["tracks"]["oval"]["theta"] = _theta(2)
    table.write_text(json.dumps(table_now))
    with pytest.raises(ValueError, match="races of a best fixed theta of another configuration"):
        claim_best_thetas(tmp_path / "run", ["oval", "default"])
    # a bench that races mpc:theta=best claims its folder the same way
    from experiments.evaluation.bench import BenchRun
    from experiments.evaluation.bench_config import BenchConfig

    cfg = BenchConfig(ego="mpc:theta=best", opponents="raceline", races=3, steps=5, track="oval")
    with pytest.raises(ValueError, match="races of a best fixed theta of another configuration"):
        BenchRun(tmp_path / "run", cfg)
    BenchRun(tmp_path / "bench", cfg)
    assert json.loads((tmp_path / "bench" / "best_fixed_theta.json").read_text())["config"] == {
        "oval": {"theta": _theta(2), "env": table_now["tracks"]["oval"]["env"]}
    }


def test_one_theta_best_player_races_each_track_of_a_league_with_its_own_theta(table, tmp_path):
    from experiments.evaluation.league import league
    from experiments.evaluation.league_schedule import LeagueConfig

    a = {"q": 5.0, "zeta": 1.04, "s1": 0.3, "s2": 0.5, "s3": 4.0}
    b = {"q": 300.0, "zeta": 0.85, "s1": 0.0, "s2": 10.0, "s3": 0.0}
    _write(table, _entry("default", a), _entry("oval", b))
    cfg = LeagueConfig(
        agents=("mpc:theta=best", "raceline"), tracks=("default", "oval"), cars=2, steps=20
    )
    board = league(cfg, tmp_path / "lg", pool=Pool(workers=1, progress_bar=False))
    recs = [json.loads(x) for x in (tmp_path / "lg" / "races.jsonl").read_text().splitlines()]
    assert {r["track"] for r in recs} == {"default", "oval"} and board["new_races"] == len(recs)
    # the same theta alone on each track: the progress of the theta=best car in the league
    from experiments.evaluation.race import run_race

    for r in recs:
        car = r["agents"].index("mpc:theta=best")
        theta = a if r["track"] == "default" else b
        explicit = "mpc:" + ",".join(f"{k}={v!r}" for k, v in theta.items())
        agents = [explicit if x == "mpc:theta=best" else x for x in r["agents"]]
        res, _ = run_race(
            agents,
            track=r["track"],
            seed=r["seed"],
            max_cycles=20,
            start="regions",
            order=[int(s[1:]) - 1 for s in r["start_regions"]],
            progress_bar=False,
        )
        assert round(float(res.progress[car]), 4) == r["progress_m"][car]
    _write(table, _entry("default", a))
    with pytest.raises(ValueError, match="'mpc:theta=best': no best fixed theta for track 'oval'"):
        league(cfg, tmp_path / "lg2", pool=Pool(workers=1, progress_bar=False))
