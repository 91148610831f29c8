"""The MPC agent's prediction of the other cars (agents.opponent_prediction)."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.opponent_prediction import SETTLE_TIME, LinePrediction
from racing_env.tracks import make_track


def _flat_line(track, vx=2.0, n=0.1, stretch=1.0):
    """A racing line at constant speed ``vx`` and offset ``n``, ``stretch`` times as long as
    the centre line everywhere."""
    s_track = track.s_grid
    return SimpleNamespace(
        s=stretch * s_track,
        length=stretch * track.length,
        s_track=s_track,
        vx=np.full(s_track.size, vx),
        n=np.full(s_track.size, n),
    )


@settings(max_examples=30, deadline=None)
@given(
    s0=st.floats(0.0, 100.0),
    n0=st.floats(-0.2, 0.2),
    c=st.floats(0.6, 1.4),
    stretch=st.floats(1.0, 1.2),
)
def test_a_constant_line_is_followed_at_its_rate_and_the_offset_settles(s0, n0, c, stretch):
    """Hand-derived: on a line at constant speed 2 m/s, ``stretch`` times longer than the
    centre line, the line's progress rate is 2 / stretch; a car going c times that advances
    c * 2 / stretch * dt per stage, and its offset from the line (0.1 m) decays like
    exp(-t / SETTLE_TIME)."""
    track = make_track("default")
    pred = LinePrediction(track, _flat_line(track, stretch=stretch))
    K, dt = 15, 0.1
    rate = 2.0 / stretch
    paths = pred.paths(np.array([s0]), np.array([n0]), np.array([c * rate]), K, dt)
    t = dt * np.arange(1, K + 1)
    np.testing.assert_allclose(paths[0, :, 0], s0 + c * rate * t, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        paths[0, :, 1], 0.1 + (n0 - 0.1) * np.exp(-t / SETTLE_TIME), atol=1e-12
    )


def test_the_rate_factor_is_bounded():
    """A stopped car is predicted at half the line's rate, not stopped for ever, and a car
    far faster than the line at 1.5 times it (RATE_SCALE)."""
    track = make_track("default")
    pred = LinePrediction(track, _flat_line(track))
    paths = pred.paths(np.array([5.0, 5.0]), np.zeros(2), np.array([0.0, 20.0]), 3, 0.1)
    np.testing.assert_allclose(paths[:, 0, 0], [5.0 + 0.5 * 0.2, 5.0 + 1.5 * 0.2])


def test_a_raceline_follower_is_predicted_where_it_goes():
    """On `default`, a `raceline` car alone: its lateral position 1 s later is predicted
    along the line within a few centimetres (the follower drives about 2 cm off its line),
    where the constant offset misses by several times more (the follower crosses the track
    between corners)."""
    from agents import make_agent_spec
    from racing_env import RacingParallelEnv
    from racing_env.raceline import get_raceline

    env = RacingParallelEnv(n_cars=1, max_cycles=200)
    obs, _ = env.reset(seed=0)
    car = make_agent_spec("raceline")
    car.reset(env.track, "car_0", 0)
    pred = LinePrediction(env.track, get_raceline(env.track))
    states = []
    while env.agents:
        states.append(env.state().reshape(1, 6)[0].copy())
        obs, *_ = env.step({"car_0": car.act(obs["car_0"])})
    states = np.array(states)
    from agents.mpc_agent import progress_rate

    err_line, err_const = [], []
    for i in range(20, 185, 5):
        x = states[i]
        p = pred.paths(x[:1], x[1:2], progress_rate(x, env.track)[None], 10, 0.1)
        err_line.append(abs(p[0, -1, 1] - states[i + 10, 1]))
        err_const.append(abs(x[1] - states[i + 10, 1]))
    assert np.median(err_line) < 0.04
    assert np.median(err_line) < 0.3 * np.median(err_const)


def test_the_mpc_agent_names_a_bad_prediction():
    from agents.mpc_agent import MPCAgent

    with pytest.raises(ValueError, match="predict must be one of .*'ballistic'"):
        MPCAgent(predict="ballistic")
