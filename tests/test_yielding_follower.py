"""The racing-line follower's opt-in yield (``raceline:yield_gap=...``): it leaves room to a car
in its window and is the plain follower otherwise."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from racing_env.controllers import RacelineFollower
from racing_env.tracks import make_track

TRACK = make_track("default")


def _follower(**kw):
    f = RacelineFollower(**kw)
    f.reset(TRACK, "car_0")
    return f


def _obs(ego, others, n_preview=10):
    """An env observation: ego state, the others relative to it, a zero curvature preview."""
    ego = np.asarray(ego, dtype=float)
    rel = [np.asarray(o, dtype=float) - ego for o in others]
    return np.concatenate([ego, *rel, np.zeros(n_preview)])


def test_without_a_car_in_its_window_it_is_the_plain_follower():
    plain, yielding = _follower(), _follower(yield_gap=0.12)
    ego = [5.0, 0.02, 0.0, 2.5, 0.0, 0.0]
    far_behind = [4.0, 0.02, 0.0, 2.5, 0.0, 0.0]  # 1 m behind: outside the 0.2 m window
    for others in ([], [far_behind]):
        obs = _obs(ego, others)
        assert yielding.yield_shift(obs) == 0.0
        assert np.array_equal(yielding.act(obs), plain.act(obs))


@settings(max_examples=40, deadline=None)
@given(
    s=st.floats(0.0, 30.0),
    ds=st.floats(-0.25, 0.45),
    n_other=st.floats(-0.15, 0.15),
    n_ego=st.floats(-0.15, 0.15),
)
# equal offsets at the window's rear edge, where the observed gap 2.8 - 3.0 is 2e-16 past 0.2 m
@example(s=3.0, ds=-0.2, n_other=0.0, n_ego=0.0)
@example(s=3.0, ds=-0.1, n_other=0.0, n_ego=0.0)  # a tie inside the window: it keeps left
def test_its_target_keeps_the_gap_on_its_own_side_of_a_car_in_its_window(s, ds, n_other, n_ego):
    f = _follower(yield_gap=0.12)
    ego = [s, n_ego, 0.0, 2.5, 0.0, 0.0]
    other = [s + ds, n_other, 0.0, 2.5, 0.0, 0.0]
    obs = _obs(ego, [other])
    line = float(np.interp(s % TRACK.length, TRACK.s_grid, f.tables()[0]))
    target = line + f.yield_shift(obs)
    if not -0.2 <= obs[6] <= 0.4:  # outside the window, as observed: the plain line
        assert f.yield_shift(obs) == 0.0
        return
    side = 1.0 if n_ego >= n_other else -1.0  # a tie goes left
    w_left, w_right = TRACK.widths(s)
    half = 0.03  # half the car's width
    assert -w_right + half - 1e-9 <= target <= w_left - half + 1e-9  # never past an edge
    if -w_right + half < n_other + side * 0.12 < w_left - half:  # room on its side
        assert side * (target - n_other) >= 0.12 - 1e-3  # at least the gap, on its side
    # it moves only as far as it must: the line where it already keeps clear, else the gap
    assert (
        target == pytest.approx(line, abs=2e-3)
        or abs(target - n_other) == pytest.approx(0.12, abs=1e-9)
        or min(abs(target + w_right - half), abs(target - w_left + half)) < 1e-9
    )


def test_bad_yield_options_name_the_value():
    with pytest.raises(ValueError, match=r"yield_gap must be a number in \[0, 0.3\] m, got 0.5"):
        RacelineFollower(yield_gap=0.5)
    with pytest.raises(ValueError, match=r"yield_behind must be a number in \[0, 2.0\] m, got -1"):
        RacelineFollower(yield_behind=-1)
    with pytest.raises(ValueError, match="n_preview must be a non-negative integer, got 1.5"):
        RacelineFollower(n_preview=1.5)
    # a bool is no distance and no count, although Python counts it an int
    with pytest.raises(ValueError, match="yield_behind must be a number .* got True"):
        RacelineFollower(yield_behind=True)
    with pytest.raises(ValueError, match="n_preview must be a non-negative integer, got True"):
        RacelineFollower(n_preview=True)
    assert RacelineFollower(n_preview=np.int64(2)).n_preview == 2
    f = _follower(yield_gap=0.1)
    with pytest.raises(ValueError, match=r"does not fit 6 N \+ n_preview with n_preview = 10"):
        f.act(np.zeros(13))
