"""The control's compass search (experiments.evaluation.refine): the moves, the pattern move, the order
of scores and the search driven by hand-made score functions."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.theta import EXTENDED_HIGH, EXTENDED_LOW, THETA_HIGH, THETA_LOW
from experiments.evaluation.refine import (
    compass_moves,
    compass_search,
    eligible,
    pattern_move,
    score_key,
)

NAMES = ("q", "zeta", "s1", "s2", "s3")
EXT_NAMES = NAMES + ("b",)
STEPS = 500


def _score(index, wins, margin=0.0, off=0.0, theta=None):
    return {
        "index": index,
        "wins": wins,
        "margin_m_mean": margin,
        "off_track_steps_mean": off,
        "theta": theta,
    }


@settings(max_examples=60, deadline=None)
@given(
    u=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    step=st.sampled_from([1.0, 0.5, 0.25, 0.125]),
)
def test_compass_moves_stay_in_the_box_and_move_one_parameter_each(u, step):
    low, high = EXTENDED_LOW, EXTENDED_HIGH
    theta = low + np.array(u) * (high - low)
    moves = compass_moves(theta, step, low, high, EXT_NAMES)
    labels = [label for label, _ in moves]
    assert len(set(labels)) == len(labels)
    for label, t in moves:
        changed = np.flatnonzero(t != theta)
        assert changed.size == 1
        i = int(changed[0])
        assert label == EXT_NAMES[i] + ("-" if t[i] < theta[i] else "+")
        assert low[i] <= t[i] <= high[i]
        # the full step reaches the face, a shorter one moves step x range unless clipped
        want = theta[i] + (-1 if label.endswith("-") else 1) * step * (high[i] - low[i])
        assert t[i] == np.clip(want, low[i], high[i])
    # a parameter on a face has only the move away from it
    on_faces = int(np.sum(theta == low) + np.sum(theta == high))
    assert len(moves) == 2 * len(EXT_NAMES) - on_faces


def test_the_first_step_puts_each_parameter_on_a_face_of_the_box():
    theta = (THETA_LOW + THETA_HIGH) / 2
    moves = dict(compass_moves(theta, 1.0, THETA_LOW, THETA_HIGH, NAMES))
    assert moves["q-"][0] == 5.0 and moves["q+"][0] == 500.0
    assert moves["zeta+"][1] == 1.05 and moves["s3-"][4] == 0.0
    corner = THETA_LOW.copy()
    assert [label for label, _ in compass_moves(corner, 1.0, THETA_LOW, THETA_HIGH, NAMES)] == [
        "q+",
        "zeta+",
        "s1+",
        "s2+",
        "s3+",
    ]


def test_compass_moves_reject_bad_steps_and_shapes():
    with pytest.raises(ValueError, match=r"step must be in \(0, 1\].*got 0"):
        compass_moves(THETA_LOW, 0.0, THETA_LOW, THETA_HIGH, NAMES)
    with pytest.raises(ValueError, match="one value per name"):
        compass_moves(THETA_LOW[:4], 1.0, THETA_LOW, THETA_HIGH, NAMES)


def test_scores_rank_by_wins_then_margin_then_index_and_off_track_thetas_are_not_eligible():
    a, b, c = _score(3, 10, 0.5), _score(1, 10, 0.2), _score(2, 11, -3.0)
    assert sorted([a, b, c], key=score_key) == [c, a, b]
    assert score_key(_score(1, 10, 0.5)) < score_key(_score(7, 10, 0.5))  # ties: lower index
    assert eligible(_score(0, 1, off=5.0), STEPS)  # 1% of 500 steps
    assert not eligible(_score(0, 1, off=5.1), STEPS)
    assert not eligible(_score(0, 1, margin=float("nan")), STEPS)


def test_pattern_move_takes_each_improving_parameter_once_best_first():
    x = np.array([1.0, 1.0, 1.0])
    moves = [  # best first
        ("a+", np.array([2.0, 1.0, 1.0]), True),
        ("a-", np.array([0.0, 1.0, 1.0]), True),  # a's second move: not taken
        ("c-", np.array([1.0, 1.0, 0.0]), True),
        ("b+", np.array([1.0, 2.0, 1.0]), False),  # did not beat the incumbent
    ]
    np.testing.assert_array_equal(pattern_move(x, moves), [2.0, 1.0, 0.0])
    assert pattern_move(x, moves[:2]) is None  # one parameter only: already raced
    assert pattern_move(x, []) is None


def _drive(search, score_of):
    """Run a compass_search generator against ``score_of(theta) -> score`` (one index per new
    theta, as the control assigns them); returns the result and the thetas raced."""
    raced, index = {}, [100]

    def score(theta):
        k = tuple(theta)
        if k not in raced:
            raced[k] = {**score_of(theta), "index": index[0], "theta": tuple(theta)}
            index[0] += 1
        return raced[k]

    try:
        props, _ = next(search)
        while True:
            props, _ = search.send([(label, score(t)) for label, t in props])
    except StopIteration as done:
        return done.value, raced


def _search(start, score_of, rounds=2, low=THETA_LOW, high=THETA_HIGH, names=NAMES):
    inc = {**score_of(start), "index": 7, "theta": tuple(start)}
    return _drive(
        compass_search(inc, lambda s: np.array(s["theta"]), low, high, names, rounds, STEPS),
        score_of,
    )


def test_the_search_reaches_a_corner_the_sobol_points_miss_by_the_pattern_move():
    # wins grow with every parameter toward its target face: each face move alone improves,
    # the pattern move combines them, so the first round ends on the corner
    target = np.array([THETA_LOW[0], THETA_HIGH[1], THETA_HIGH[2], THETA_LOW[3], THETA_LOW[4]])

    def score_of(theta):
        near = 1.0 - np.abs(theta - target) / (THETA_HIGH - THETA_LOW)
        return _score(None, int(np.round(10 * near.sum())), margin=float(near.sum()))

    start = THETA_LOW + 0.4 * (THETA_HIGH - THETA_LOW)
    result, raced = _search(start, score_of, rounds=1)
    np.testing.assert_array_equal(result["winner"]["theta"], target)
    (r,) = result["rounds"]
    assert r["from"] == 7 and r["to"] == result["winner"]["index"] and r["step"] == 1.0
    assert [m["move"] for m in r["moves"]][-1] == "pattern" and len(r["moves"]) == 11
    assert len(raced) == 11


def test_an_off_track_theta_never_wins_and_a_round_without_a_better_theta_halves_the_step():
    start = (THETA_LOW + THETA_HIGH) / 2

    def score_of(theta):  # only q at its top face wins more, but it leaves the track
        if theta[0] == THETA_HIGH[0]:
            return _score(None, 30, off=0.02 * STEPS)
        return _score(None, 10, margin=-float(np.abs(theta - start).sum()))

    result, _ = _search(start, score_of, rounds=3)
    assert result["winner"]["index"] == 7  # the incumbent stays
    assert [r["step"] for r in result["rounds"]] == [1.0, 0.5, 0.25]
    first = {m["move"]: m for m in result["rounds"][0]["moves"]}
    assert first["q+"]["wins"] == 30 and not first["q+"]["eligible"]
    assert "pattern" not in first


def test_ties_stay_with_the_incumbent_and_a_theta_raced_before_is_not_raced_again():
    start = (THETA_LOW + THETA_HIGH) / 2
    result, raced = _search(start, lambda theta: _score(None, 10, 1.0), rounds=3)
    assert result["winner"]["index"] == 7
    # steps 1, 0.5 (the same faces from the middle: raced before), 0.25
    assert len(raced) == 10 + 10
    assert result["rounds"][1]["moves"][0]["index"] == result["rounds"][0]["moves"][0]["index"]
