"""The ranker (value targets from paired rollouts): a room run keeps its oracle's choices,
a ranker learns a gain that depends on the state, and the ranked agent races on it; its
features do not depend on how the other cars are numbered; bad input is named."""

import json

import numpy as np
import pytest

from agents import make_agent_spec
from agents.ranked import RankedAgent, RankerModel, ranker_features
from experiments.evaluation.oracle import candidate_moves
from experiments.evaluation.race import run_race
from experiments.evaluation.room import RoomConfig, room
from experiments.evaluation.strategy import StrategyConfig, strategy
from experiments.infra.parallel import Pool
from experiments.learning.ranker import RankerConfig, load_choices, train_ranker

BASE = "mpc:q=20,zeta=0.95,s1=0.1,s2=4,s3=1"
TWIN = "mpc:q=20,zeta=0.95,s1=0,s2=4,s3=1"
N_PREVIEW = 10


def _obs(rng, n_cars=3):
    return rng.normal(size=6 * n_cars + N_PREVIEW).astype(np.float32)


def test_features_ignore_the_numbering_of_the_others():
    rng = np.random.default_rng(0)
    obs = _obs(rng)
    swapped = obs.copy()
    swapped[6:12], swapped[12:18] = obs[12:18], obs[6:12]
    a = ranker_features(obs, N_PREVIEW, 100.0)
    assert a.shape == (7 + 12 + N_PREVIEW,)
    assert np.array_equal(a, ranker_features(swapped, N_PREVIEW, 100.0))
    obs[0] = 25.0  # a quarter of the lap: sin 1, cos 0
    assert np.allclose(ranker_features(obs, N_PREVIEW, 100.0)[:2], [1.0, 0.0], atol=1e-6)
    with pytest.raises(ValueError, match="does not fit 6 N"):
        ranker_features(obs[:-1], N_PREVIEW, 100.0)
    with pytest.raises(ValueError, match="track_length"):
        ranker_features(obs, N_PREVIEW, 0.0)


def _fake_room(folder, races: int, rng) -> None:
    """A room folder whose second candidate gains 4 m where the car is left of the line
    (n > 0) and loses 4 m elsewhere, the third always loses 1 m."""
    (folder / "choices").mkdir(parents=True)
    (folder / "manifest.json").write_text(
        json.dumps({"room": {"every": 10, "lookahead": 3.0}, "suite": {"vehicle_class": "orca"}})
    )
    lines = []
    for k in range(races):
        obs = np.stack([_obs(rng) for _ in range(30)])
        left = obs[:, 1] > 0
        scores = np.stack([np.zeros(30), np.where(left, 4.0, -4.0), np.full(30, -1.0)], 1)
        scores += rng.normal(size=(30, 1))  # the state's own outlook: shared, cancels
        np.savez(folder / "choices" / f"equal_default_{k:05d}.npz", observations=obs, scores=scores)
        rec = {
            "bench": "equal",
            "track": "default",
            "race": k,
            "candidates": [BASE, TWIN, BASE + ",q=50"],
        }
        lines.append(json.dumps(rec))
    (folder / "races.jsonl").write_text("\n".join(lines) + "\n")


def test_a_state_dependent_gain_is_learned(tmp_path):
    rng = np.random.default_rng(1)
    folder = tmp_path / "room" / "control_T3_M3_k10"
    _fake_room(folder, 40, rng)
    data = load_choices([folder])
    assert data.features.shape == (1200, 7 + 12 + N_PREVIEW)
    assert np.all(data.gains[:, 0] == 0.0)
    out = tmp_path / "ranker.npz"
    f = train_ranker([folder], out, RankerConfig(epochs=400, holdout=4))
    v = f["validation"]
    assert f["races"] == {"train": 30, "validation": 10}
    assert v["gain_m"]["oracle"] == pytest.approx(2.0, abs=0.7)  # 4 m in half the states
    # the pick follows the state: 0.82-0.89 of the oracle's gain over three data draws and
    # two initial weights each, so the bound leaves room for another CPU's last bits
    assert v["gain_m"]["ranker"] > 0.6 * v["gain_m"]["oracle"]
    assert abs(v["gain_m"]["best_fixed_candidate"]) < 0.7  # no single candidate gains it
    model = RankerModel.load(out)
    x = ranker_features(_obs(rng), N_PREVIEW, 100.0)
    x_left, x_right = x.copy(), x.copy()
    x_left[2], x_right[2] = 1.5, -1.5  # n, after the lap phase's two features
    assert np.argmax(model.gains(x_left)) == 1
    assert np.argmax(model.gains(x_right)) == 0


def test_room_keeps_choices_and_the_ranked_agent_races(tmp_path):
    suite = tmp_path / "suite"
    config = StrategyConfig(
        ego=TWIN, control=BASE, tracks=("default",), scenarios=("equal",), races=2, steps=40
    )
    pool = Pool(workers=1, progress_bar=False)
    strategy(config, suite, pool)
    rc = RoomConfig(moves=1, lookahead=0.5, every=20, benches=("equal",))
    room(suite, rc, pool)
    folder = suite / "room" / rc.folder_name()
    data = load_choices([folder])
    assert data.gains.shape == (4, 2)  # 2 races, a choice at periods 0 and 20
    assert data.candidates == candidate_moves(BASE, 1)  # the base, then s1=0
    out = tmp_path / "ranker.npz"
    train_ranker([folder], out, RankerConfig(epochs=20, holdout=2))
    res, _ = run_race(
        [f"ranked:model={out}", BASE, BASE], max_cycles=30, seed=3, progress_bar=False
    )
    assert np.isfinite(res.progress).all() and res.progress[0] > 0
    share = res.agent_stats[0]["candidate_share"]
    assert len(share) == 2 and sum(share) == pytest.approx(1.0)  # choices at periods 0, 10, 20
    agent = make_agent_spec(f"ranked:model={out},every=10")
    assert isinstance(agent, RankedAgent) and agent.every == 10
    with pytest.raises(ValueError, match="trained on 'default' .orca., not on"):
        agent.reset("random:5")


def test_bad_settings_are_named(tmp_path):
    with pytest.raises(ValueError, match="holdout must be an integer >= 2"):
        RankerConfig(holdout=1)
    with pytest.raises(ValueError, match="ranked needs model=PATH"):
        make_agent_spec("ranked")
    with pytest.raises(ValueError, match="none.npz.*does not exist"):
        make_agent_spec(f"ranked:model={tmp_path / 'none.npz'}")
    with pytest.raises(ValueError, match="no kept choices"):
        (tmp_path / "r").mkdir()
        (tmp_path / "r" / "manifest.json").write_text(
            json.dumps({"room": {"every": 10, "lookahead": 3.0}, "suite": {}})
        )
        (tmp_path / "r" / "races.jsonl").write_text("")
        load_choices([tmp_path / "r"])
