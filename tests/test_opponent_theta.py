"""The opponents' thetas from their observed play (``alpha:others=estimate``,
:class:`agents.opponent_theta.ThetaEstimator`): the opponent's observation rebuilt from the
ego's, the prior kept on ties, and the type an opponent races found from its play."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents import make_agent_spec
from agents.best_theta import best_theta
from agents.mpc_agent import MPCAgent
from agents.opponent_theta import PRIOR_FLOOR, PRIOR_RATIO, ThetaEstimator
from agents.theta import moved_thetas
from racing_env import RacingParallelEnv
from racing_env.observation import split_observation
from racing_env.tracks import make_track


def _race(opponent_theta, steps: int, seed: int = 4):
    """A 3-car race on ``default`` (extended space): car_0 the best fixed theta, the two
    others ``opponent_theta``; the estimator fed car_0's view each period. Returns the
    estimator and the per-period max difference between the rebuilt and true observations
    of car_1."""
    track = make_track("default")
    base = best_theta(track, space="extended")
    env = RacingParallelEnv(track="default", n_cars=3, max_cycles=steps)
    obs, _ = env.reset(seed=seed)
    cars = []
    for k, agent_id in enumerate(env.possible_agents):
        car = MPCAgent(space="extended")
        car.theta = base if k == 0 else opponent_theta
        car.reset(track, agent_id, seed)
        cars.append(car)
    est = ThetaEstimator(moved_thetas(base, 4), "extended", n_preview=cars[0].n_preview)
    est.reset(track, ego_index=0)
    gaps = []
    while env.agents:
        ego, others = split_observation(obs["car_0"], cars[0].n_preview)
        rebuilt = est.observation_of(0, ego, others)
        true = np.asarray(obs["car_1"], dtype=float)
        gaps.append(np.abs(rebuilt[:18] - true[:18]).max())
        est.update(ego, others)
        actions = {a: car.act(obs[a]) for a, car in zip(env.possible_agents, cars)}
        obs, *_ = env.step(actions)
    return est, np.array(gaps)


@pytest.fixture(scope="module")
def base():
    return best_theta(make_track("default"), space="extended")


def test_rebuilt_observation_is_the_opponents_own(base):
    """An opponent's observation (its state, the others' relative to it in agent order)
    rebuilt from car_0's float32 view: equal up to float32 rounding."""
    _, gaps = _race(base, steps=40)
    assert gaps.max() < 1e-4


def test_the_published_control_is_estimated_as_itself(base):
    est, _ = _race(base, steps=150)
    assert est.index.tolist() == [0, 0]
    # the copy of the true type replays its plans: its score stays the least
    assert np.all(est.scores[:, 0] <= est.scores.min(axis=1) + 1e-9)


def test_a_slower_opponent_is_found_out(base):
    """Opponents racing the ``zeta=0.95`` move are estimated as that type (index 3 of the
    best theta and its first four moves), not as the prior."""
    types = moved_thetas(base, 4)
    assert types[3] == replace(base, zeta=0.95)
    est, _ = _race(types[3], steps=150)
    assert est.index.tolist() == [3, 3]


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(0.0, 10.0), min_size=2, max_size=6),
    st.integers(0, 5),
    st.floats(0.0, 1.0),
)
def test_choose_keeps_the_prior_unless_another_type_is_clearly_better(scores, k, shrink):
    """Ties and near-ties go to the first type (the published control); a type whose score
    is clearly below the first's (``PRIOR_RATIO``, ``PRIOR_FLOOR``) is chosen."""
    row = np.array(scores)
    k = k % len(row)
    chosen = ThetaEstimator.choose(row[None])[0]
    best = int(np.argmin(row))
    clear = row[best] < (1 - PRIOR_RATIO) * row[0] - PRIOR_FLOOR
    assert chosen == (best if clear else 0)
    tied = np.full_like(row, row[k])  # every type predicts alike: the prior
    assert ThetaEstimator.choose(tied[None])[0] == 0
    if k:
        lower = row.copy()
        lower[k] = (1 - PRIOR_RATIO) * lower[0] * shrink - 2 * PRIOR_FLOOR
        if lower[k] == lower.min() and np.sum(lower == lower[k]) == 1:
            assert ThetaEstimator.choose(lower[None])[0] == k


def test_bad_arguments_name_the_value(base):
    with pytest.raises(ValueError, match="at least one type"):
        ThetaEstimator([], "extended", 10)
    with pytest.raises(ValueError, match=r"forget must be in \[0, 1\), got 1.5"):
        ThetaEstimator([base], "extended", 10, forget=1.5)
    with pytest.raises(ValueError, match="'maximise', 'best', 'estimate'"):
        make_agent_spec("alpha:space=extended,others=guess")


def test_alpha_estimating_the_others_reports_their_types():
    """``alpha:others=estimate`` races, drives a candidate with an anchor, and reports the
    share of (decision, opponent) per estimated type and the estimate's time."""
    from experiments.evaluation.race import run_race

    result, _ = run_race(
        ["alpha:space=extended,anchor=best,others=estimate", "mpc:space=extended,theta=best"]
        + ["mpc:space=extended,theta=best"],
        track="default",
        seed=2,
        max_cycles=150,
        progress_bar=False,
    )
    stats = result.agent_stats[0]
    assert len(stats["type_share"]) == 5 and abs(sum(stats["type_share"]) - 1) < 1e-3
    # the control raced: taken for itself but where a copy's plans part from the car's own
    # in traffic (an SQP warm-started from float32-rounded views; 95% in this race)
    assert stats["type_share"][0] >= 0.8
    assert stats["estimate_ms_median"] > 0 and len(stats["candidate_share"]) == 5
    assert np.isfinite(result.progress).all()
