"""League: a balanced, seeded schedule; openskill ratings replayed in schedule order; outputs,
resume after a kill, refusal of another config, bad input."""

import json
import math
import shutil
from collections import Counter
from itertools import combinations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("openskill")

from experiments.cli import main  # noqa: E402
from experiments.evaluation import leaderboard as lb  # noqa: E402
from experiments.evaluation import league as lg  # noqa: E402
from experiments.evaluation import league_schedule as ls  # noqa: E402
from experiments.infra.artifacts import read_jsonl  # noqa: E402
from experiments.infra.parallel import Pool  # noqa: E402

RACELINES = (
    "raceline",
    "raceline:grip=0.6",
    "raceline:speed_scale=0.7",
    "raceline:line_fraction=0.5",
)
TINY = ls.LeagueConfig(agents=RACELINES, tracks=("default", "oval"), cars=3, steps=40, seed=4)


def _untimed(board: dict) -> dict:
    """A leaderboard without its wall-clock figures (they differ between identical runs)."""
    board = json.loads(json.dumps(board))
    board.pop("new_races", None)
    for row in board["standings"]:
        for key in lg.TIMING_KEYS:
            row.pop(key, None)
    return board


@pytest.fixture(scope="module")
def tiny_league(tmp_path_factory):
    out = tmp_path_factory.mktemp("league") / "tiny"
    board = lg.league(TINY, out, pool=Pool(workers=1, progress_bar=False))
    return out, board


# ---------------------------------------------------------------------------- schedule
@settings(max_examples=60, deadline=None)
@given(k=st.integers(2, 10), data=st.data())
def test_schedule_is_balanced(k, data):
    n = data.draw(st.integers(2, min(k, 8)), label="cars")
    cfg = ls.LeagueConfig(
        agents=tuple(f"a{i}" for i in range(k)),
        cars=n,
        tracks=("default", "oval")[: data.draw(st.integers(1, 2))],
        rounds=data.draw(st.integers(1, 2)),
        max_groups=data.draw(st.integers(1, 40), label="max_groups"),
        seed=data.draw(st.integers(0, 2**32 - 1), label="seed"),
    )
    races = ls.schedule(cfg)
    assert [r.index for r in races] == list(range(len(races)))
    assert all(r.seed == cfg.race_seed(r.index) for r in races)
    for r in races:
        assert len(set(r.agents)) == n and set(r.agents) <= set(cfg.agents)
        assert sorted(r.order) == list(range(n))
    # every agent as often as every other, from every region and on every track alike
    count = Counter(a for r in races for a in r.agents)
    assert set(count) == set(cfg.agents) and len(set(count.values())) == 1
    per = count[cfg.agents[0]]
    regions = Counter((a, reg) for r in races for a, reg in zip(r.agents, r.order))
    assert set(regions.values()) == {per // n} and per % n == 0
    tracks = Counter((a, r.track) for r in races for a in r.agents)
    assert set(tracks.values()) == {per // len(cfg.tracks)}
    groups = ls.round_groups(cfg, 0)
    assert len(races) == sum(len(ls.round_groups(cfg, i)) for i in range(cfg.rounds)) * n * len(
        cfg.tracks
    )
    if math.comb(k, n) <= cfg.max_groups:  # every subset: every pair alike too
        assert groups == list(combinations(range(k), n))
        pairs = Counter(p for r in races for p in combinations(sorted(r.agents), 2))
        assert len(pairs) == math.comb(k, 2) and len(set(pairs.values())) == 1
    else:  # whole balanced blocks, at least one
        block = math.lcm(k, n) // n
        assert len(groups) == block * max(1, cfg.max_groups // block)


def test_schedule_is_fixed_by_the_seed_and_rounds_differ():
    cfg = ls.LeagueConfig(
        agents=tuple(f"a{i}" for i in range(7)), cars=3, rounds=2, max_groups=14, seed=3
    )
    assert ls.schedule(cfg) == ls.schedule(cfg)
    other = ls.schedule(ls.LeagueConfig(**{**cfg.__dict__, "seed": 4}))
    assert [r.seed for r in other] != [r.seed for r in ls.schedule(cfg)]
    # C(7, 3) = 35 > 14: each round draws its own sample of two blocks of 7 groups
    assert len(ls.round_groups(cfg, 0)) == 14
    assert ls.round_groups(cfg, 0) != ls.round_groups(cfg, 1)
    # every subset fits: the same groups in every round, the races of a round shuffled
    full = ls.LeagueConfig(agents=("a", "b", "c", "d"), cars=3, rounds=2)
    assert ls.round_groups(full, 0) == ls.round_groups(full, 1)
    races = ls.schedule(full)
    assert [r.round for r in races] == [0] * 12 + [1] * 12
    assert [r.rotation for r in races[:12]] != sorted(r.rotation for r in races[:12])


def test_balanced_groups_by_hand():
    rng = np.random.default_rng(0)
    groups = ls.balanced_groups(5, 3, 5, rng)  # lcm(5, 3) / 3 = 5 groups, 3 each
    assert len(groups) == 5 and all(len(set(g)) == 3 for g in groups)
    assert Counter(a for g in groups for a in g) == {a: 3 for a in range(5)}
    assert len(ls.balanced_groups(6, 3, 5, rng)) == 4  # two blocks of 2: 4 <= 5
    with pytest.raises(ValueError, match="groups of 4"):
        ls.balanced_groups(3, 4, 5, rng)


# ---------------------------------------------------------------------------- rating
def test_finish_ranks_follow_progress_and_give_ties_to_the_lower_car():
    assert lg.finish_ranks([1.0, 3.0, 2.0]) == [3, 1, 2]
    assert lg.finish_ranks([2.0, 2.0, 1.0]) == [1, 2, 3]


def test_rate_is_openskill_plackett_luce_and_keeps_the_prior_without_races():
    from openskill.models import PlackettLuce

    rec = {"race": 0, "agents": ["b", "a"], "ranks": [1, 2]}
    r = lb.rate([rec], ["a", "b", "idle"])
    m = PlackettLuce(tau=0.0)
    (b,), (a,) = m.rate([[m.rating()], [m.rating()]], ranks=[1, 2])
    assert r["b"] == pytest.approx((b.mu, b.sigma)) and r["a"] == pytest.approx((a.mu, a.sigma))
    assert r["b"][0] > 25.0 > r["a"][0]
    assert r["idle"] == (25.0, 25.0 / 3.0)
    with pytest.raises(ValueError, match=r"agents \['x'\] outside the league"):
        lb.rate([{"race": 0, "agents": ["a", "x"], "ranks": [1, 2]}], ["a", "b"])


def test_ratings_do_not_depend_on_the_completion_order(tiny_league):
    out, _ = tiny_league
    records = read_jsonl(out / "races.jsonl")
    board = lb.leaderboard(records, TINY)
    for seed in range(3):
        shuffled = [records[i] for i in np.random.default_rng(seed).permutation(len(records))]
        assert lb.leaderboard(shuffled, TINY) == board
    # the online update itself is order-dependent: replayed backwards the numbers move, so
    # the replay in race-index order is what makes the ratings reproducible
    backwards = [dict(r, race=len(records) - 1 - r["race"]) for r in records]
    assert lb.rate(backwards, TINY.agents) != lb.rate(records, TINY.agents)


def test_a_clearly_slower_agent_is_rated_lower(tmp_path):
    cfg = ls.LeagueConfig(
        agents=("mpc", "raceline", "raceline:speed_scale=0.5"), cars=2, steps=60, seed=1
    )
    board = lg.league(cfg, tmp_path / "slow", pool=Pool(workers=1, progress_bar=False))
    rows = {r["agent"]: r for r in board["standings"]}
    slow = rows["raceline:speed_scale=0.5"]
    assert slow["rank"] == 3
    assert slow["mu"] < min(rows["mpc"]["mu"], rows["raceline"]["mu"])
    assert slow["progress_m"] < min(rows["mpc"]["progress_m"], rows["raceline"]["progress_m"])
    assert board["pairwise"]["ahead"]["mpc"]["raceline:speed_scale=0.5"] == 1.0


# ---------------------------------------------------------------------------- outputs
def test_tiny_league_writes_consistent_outputs(tiny_league):
    out, board = tiny_league
    races = ls.schedule(TINY)
    assert len(races) == 4 * 3 * 2 and board["new_races"] == len(races)
    records = read_jsonl(out / "races.jsonl")
    assert sorted(r["race"] for r in records) == list(range(len(races)))
    for rec in records:
        p = rec["progress_m"]
        assert sorted(rec["ranks"]) == [1, 2, 3]
        assert rec["winner"] == rec["agents"][int(np.argmax(p))]
        assert rec["start_regions"] == [f"R{r + 1}" for r in races[rec["race"]].order]
    stored = json.loads((out / "leaderboard.json").read_text())
    assert stored == json.loads(json.dumps({k: v for k, v in board.items() if k != "new_races"}))
    assert board["complete"] and board["races"] == len(races)
    rows = board["standings"]
    assert [r["rank"] for r in rows] == [1, 2, 3, 4]
    assert [r["ordinal"] for r in rows] == sorted((r["ordinal"] for r in rows), reverse=True)
    assert all(r["ordinal"] == pytest.approx(r["mu"] - 3 * r["sigma"]) for r in rows)
    assert sum(r["wins"] for r in rows) == len(races)
    assert all(r["races"] == 18 for r in rows)  # 3 groups of 4, 3 starts, 2 tracks
    for r in rows:
        assert r["win_ci95"][0] <= r["win_rate"] <= r["win_ci95"][1]
    pw = board["pairwise"]
    for a, b in combinations(TINY.agents, 2):
        assert pw["races"][a][b] == pw["races"][b][a] == 12
        assert pw["ahead"][a][b] + pw["ahead"][b][a] == pytest.approx(1.0)
    text = (out / "leaderboard.md").read_text()
    assert all(f"`{a}`" in text for a in TINY.agents) and "## Pairwise" in text
    for png in ("ratings.png", "pairwise.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_leaderboard_reports_strategy_metrics_and_says_when_old_records_lack_them(tiny_league):
    from experiments.evaluation.metrics import RECORD_KEYS

    out, board = tiny_league
    records = read_jsonl(out / "races.jsonl")
    for row in board["standings"]:
        mine = [
            (r, r["agents"].index(row["agent"])) for r in records if row["agent"] in r["agents"]
        ]
        assert row["strategy_races"] == row["races"] == len(mine)
        assert row["passes"] == sum(r["passes"][i] for r, i in mine)
        assert row["wins_from_behind"] == sum(
            r["won_from_behind"] and r["ranks"][i] == 1 for r, i in mine
        )
    assert sum(r["wins_from_behind"] for r in board["standings"]) == sum(
        r["won_from_behind"] for r in records
    )
    assert "| passes/race |" in (out / "leaderboard.md").read_text()
    # records of an older league (no metrics, no states): None and a note, never zeros
    old = [{k: v for k, v in r.items() if k not in RECORD_KEYS} for r in records]
    stale = lb.leaderboard(old[:10] + records[10:], TINY)
    assert all(0 < r["strategy_races"] < r["races"] for r in stale["standings"])
    none = lb.leaderboard(old, TINY)
    assert all(r["passes"] is None and r["wins_from_behind"] is None for r in none["standings"])
    md = lb.leaderboard_markdown(none)
    assert "missing for some races" in md and "over 0 of 18 races" in md


def test_resume_after_a_kill_runs_only_the_missing_races(tiny_league, tmp_path):
    out, board = tiny_league
    copy = tmp_path / "killed"
    shutil.copytree(out, copy)
    lines = (copy / "races.jsonl").read_text().splitlines(keepends=True)
    kept = lines[:9]
    (copy / "races.jsonl").write_text("".join(kept) + lines[9][:25])  # a torn last line
    again = lg.league(TINY, copy, pool=Pool(workers=1, progress_bar=False))
    assert again["new_races"] == len(lines) - 9
    done = {json.loads(line)["race"] for line in kept}
    appended = [r["race"] for r in read_jsonl(copy / "races.jsonl")][9:]
    assert sorted(appended) == sorted(set(range(len(lines))) - done)
    assert _untimed(again) == _untimed(board)
    assert lg.league(TINY, copy, pool=Pool(workers=1, progress_bar=False))["new_races"] == 0


def test_a_folder_of_another_config_is_refused(tiny_league, capsys):
    out, _ = tiny_league
    before = (out / "races.jsonl").read_text()
    with pytest.raises(ValueError, match="holds a league of another configuration"):
        lg.league(
            ls.LeagueConfig(**{**TINY.__dict__, "seed": 5}),
            out,
            pool=Pool(workers=1, progress_bar=False),
        )
    assert (
        main(
            [
                "league",
                "--agents",
                *TINY.agents,
                "--tracks",
                "default",
                "oval",
                "--steps",
                "41",
                "--seed",
                "4",
                "--workers",
                "1",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    assert "another configuration" in capsys.readouterr().err
    assert (out / "races.jsonl").read_text() == before


def test_records_of_another_schedule_are_refused(tiny_league, tmp_path):
    out, _ = tiny_league
    copy = tmp_path / "edited"
    shutil.copytree(out, copy)
    records = read_jsonl(copy / "races.jsonl")
    records[0]["seed"] += 1
    (copy / "races.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    with pytest.raises(ValueError, match=f"race {records[0]['race']} is not the race"):
        lg.league(TINY, copy, pool=Pool(workers=1, progress_bar=False))


# ---------------------------------------------------------------------------- input
@pytest.mark.parametrize(
    "args, message",
    [
        (["--agents", "raceline", "mpc"], "3 cars per race need at least 3 agent specs, got 2"),
        (["--agents", "mpc", "raceline", "mpc"], "given more than once: mpc"),
        (["--agents", "mpc", "raceline", "nope"], "unknown agent 'nope'"),
        (["--agents", "mpc", "raceline", "raceline:mux=1"], "unknown parameter(s) mux"),
        (
            ["--agents", "mpc", "raceline", "--cars", "1"],
            "cars per race must be an integer in 2..8, got 1",
        ),
        (
            ["--agents", "mpc", "raceline", "--cars", "2", "--tracks", "nope"],
            "unknown track 'nope'",
        ),
        (
            ["--agents", "mpc", "raceline", "--cars", "2", "--tracks", "oval", "oval"],
            "tracks must be distinct",
        ),
        (
            ["--agents", "mpc", "raceline", "--cars", "2", "--steps", "0"],
            "steps must be a positive integer, got 0",
        ),
        (
            ["--agents", "mpc", "raceline", "--cars", "2", "--max-groups", "0"],
            "max_groups must be a positive integer, got 0",
        ),
        (
            ["--agents", "mpc", "raceline", "--cars", "2", "--workers", "0"],
            "workers must be a positive integer, got 0",
        ),
        (
            ["--agents", "alpha:model=default", "mpc", "raceline", "--cars", "2"],
            "agent 'alpha:model=default' cannot race in a field of 2 cars on 'default': ValueError: "
            "alpha-potential model trained for 3 cars",
        ),
    ],
)
def test_bad_input_fails_before_any_race_with_a_clear_message(args, message, tmp_path, capsys):
    out = tmp_path / "bad"
    assert main(["league", *args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err and err.startswith("alpha-racer league: error:")
    assert not out.exists()


def test_imported_user_agents_race_in_the_league(tmp_path, monkeypatch):
    import sys

    from agents.base import _REGISTRY

    (tmp_path / "league_user_agents.py").write_text(
        "from agents import register_agent\nfrom agents.simple import RacelineFollower\n\n\n"
        "@register_agent('cautious_user')\ndef cautious(mu: float = 0.6):\n"
        "    return RacelineFollower(grip=mu)\n"
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.delitem(sys.modules, "league_user_agents", raising=False)
    try:
        assert (
            main(
                [
                    "league",
                    "--import",
                    "league_user_agents.py",
                    "--agents",
                    "raceline",
                    "cautious_user",
                    "--cars",
                    "2",
                    "--steps",
                    "20",
                    "--workers",
                    "1",
                    "--out",
                    "out",
                ]
            )
            == 0
        )
        board = json.loads((tmp_path / "out" / "leaderboard.json").read_text())
        assert {r["agent"] for r in board["standings"]} == {"raceline", "cautious_user"}
        # a worker that has not imported the module (spawned, Ray) imports it for its race
        del _REGISTRY["cautious_user"]
        del sys.modules["league_user_agents"]
        race = ls.schedule(ls.LeagueConfig(agents=("raceline", "cautious_user"), cars=2))[0]
        rec = lg.league_race(race, 5, (str(tmp_path / "league_user_agents.py"),))
        assert "cautious_user" in rec["agents"] and "cautious_user" in _REGISTRY
    finally:
        _REGISTRY.pop("cautious_user", None)
        sys.modules.pop("league_user_agents", None)


def test_league_races_in_a_batch_are_the_races_run_alone():
    """league_races (the pool's task: lockstep batches, one per track) gives each race's record
    as league_race gives it alone, but for the timings."""
    races = ls.schedule(TINY)[:5]
    skip = ("seconds", "decision_ms")
    batch = lg.league_races(races, 20)
    alone = [lg.league_race(r, 20) for r in races]
    for got, ref in zip(batch, alone):
        assert {k: v for k, v in got.items() if k not in skip} == {
            k: v for k, v in ref.items() if k not in skip
        }
