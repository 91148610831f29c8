"""PettingZoo and Gymnasium environments: official checkers, determinism, options, errors."""
import sys

import gymnasium
import numpy as np
import pytest
from pettingzoo.test import api_test, max_cycles_test, parallel_api_test, parallel_seed_test, render_test

import racing_env
from racing_env import RacingParallelEnv
from racing_env.controllers import RacelineFollower
from racing_env.gym_env import HeadToHeadEnv


def test_parallel_api():
    parallel_api_test(racing_env.parallel_env(n_cars=3), num_cycles=200)


@pytest.mark.parametrize("n_cars", [1, 2, 8])
def test_parallel_api_other_sizes(n_cars):
    parallel_api_test(racing_env.parallel_env(n_cars=n_cars, max_cycles=60), num_cycles=80)


def test_aec_api():
    api_test(racing_env.env(n_cars=3, max_cycles=100), num_cycles=120)


def test_parallel_seed():
    parallel_seed_test(lambda: racing_env.parallel_env(n_cars=3, max_cycles=100), num_cycles=100)


def test_max_cycles():
    max_cycles_test(sys.modules["racing_env"])


@pytest.mark.filterwarnings("ignore:human rendering needs a display")
def test_render_modes():
    render_test(lambda render_mode=None: racing_env.env(n_cars=3, render_mode=render_mode))
    env = racing_env.parallel_env(n_cars=2, render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3


def _rollout(env, seed, steps, rng_seed=0):
    rng = np.random.default_rng(rng_seed)
    obs, _ = env.reset(seed=seed)
    trace = [np.concatenate([obs[a] for a in env.agents])]
    for _ in range(steps):
        acts = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in env.agents}
        obs, rew, term, trunc, _ = env.step(acts)
        trace.append(np.concatenate([obs[a] for a in obs] + [np.array(list(rew.values()))]))
        if not env.agents:
            break
    return np.concatenate(trace), env.state()


def test_multi_step_determinism():
    a, sa = _rollout(racing_env.parallel_env(n_cars=4), seed=7, steps=300)
    b, sb = _rollout(racing_env.parallel_env(n_cars=4), seed=7, steps=300)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(sa, sb)
    c, _ = _rollout(racing_env.parallel_env(n_cars=4), seed=8, steps=300)
    assert not np.array_equal(a[0], c[0])          # another seed, another start


def test_reset_options_change_cars_and_start():
    env = RacingParallelEnv(n_cars=3)
    obs, _ = env.reset(seed=0, options={"n_cars": 5, "start": "grid"})
    assert env.agents == [f"car_{i}" for i in range(5)]
    assert obs["car_4"].shape == env.observation_space("car_4").shape == (6 * 5 + 10,)
    s = env.state().reshape(5, 6)[:, 0]
    assert np.all(np.diff(s) < 0)                  # grid: car_0 on pole, the rest behind
    env.reset(seed=0, options={"start": "regions", "order": [1, 2, 0, 3, 4]})
    s = env.state().reshape(5, 6)[:, 0]
    assert s[2] > s[0] > s[1]
    with pytest.warns(UserWarning, match="ignoring unknown reset options"):
        env.reset(options={"cars": 2})


def test_laps_terminate_every_agent():
    env = RacingParallelEnv(track="oval", n_cars=2, laps=1, start="grid")
    env.reset(seed=0)
    env.core.state[0, 0, 0] = env.core.s_line[0] + env.track.length - 0.01
    env.core.state[0, 0, 3] = 2.0
    _, _, term, trunc, info = env.step({a: np.zeros(2, np.float32) for a in env.agents})
    assert all(term.values()) and not any(trunc.values())
    assert info["car_0"]["laps"] == 1 and env.agents == []


def test_observation_reports_relative_states():
    env = RacingParallelEnv(track="oval", n_cars=3, start="grid")
    env.reset(seed=0)
    st = env.core.state[0]
    st[:, 0] = [2.0, 1.5, env.track.length + 1.0]      # car_2 a lap ahead, physically behind
    obs = env.core.observe()[0]
    assert obs[0, 0] == pytest.approx(2.0)
    assert obs[0, 6] == pytest.approx(-0.5)              # car_1 relative to car_0
    assert obs[0, 12] == pytest.approx(env.track.length - 1.0, rel=1e-6)
    assert obs[2, 0] == pytest.approx(1.0, rel=1e-5)     # own s is wrapped


def test_bad_arguments_raise_clear_errors():
    with pytest.raises(ValueError, match="n_cars must be an integer in 1..8, got 0"):
        RacingParallelEnv(n_cars=0)
    with pytest.raises(ValueError, match="render_mode"):
        RacingParallelEnv(render_mode="ascii")
    with pytest.raises(ValueError, match="unknown track"):
        RacingParallelEnv(track="nowhere")
    env = RacingParallelEnv(n_cars=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="missing action for car_1"):
        env.step({"car_0": np.zeros(2)})
    with pytest.raises(ValueError, match="not finite"):
        env.step({"car_0": np.zeros(2), "car_1": np.array([np.nan, 0.0])})


def test_gymnasium_env_passes_checkers():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env
    env = gymnasium.make("alpha_racer/HeadToHead-v0")
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(HeadToHeadEnv(max_cycles=50), warn=True)


def test_gymnasium_env_opponents_drive():
    env = HeadToHeadEnv(opponents=[RacelineFollower(mu=0.7)], max_cycles=80, start="grid")
    obs, info = env.reset(seed=1)
    assert obs.shape == env.observation_space.shape == (6 * 2 + 10,)
    total = 0.0
    for _ in range(80):
        obs, r, term, trunc, info = env.step(np.array([0.0, 0.0], np.float32))
        total += r
    assert trunc and not term
    assert env.race.core.progress()[0, 1] > 5.0        # the follower raced on
    assert total < 0                                     # standing still loses ground
    with pytest.raises(ValueError, match="n_cars"):
        HeadToHeadEnv(opponents=[RacelineFollower()], n_cars=3)
    with pytest.raises(ValueError, match="act"):
        HeadToHeadEnv(opponents=[object()])


def test_raceline_follower_laps_the_default_track_cleanly():
    env = RacingParallelEnv(n_cars=1, max_cycles=400, start="grid")
    obs, _ = env.reset(seed=0)
    drv = RacelineFollower()
    drv.reset(env.track, "car_0", 0)
    while env.agents:
        obs, _, _, _, info = env.step({"car_0": drv.act(obs["car_0"])})
    assert info["car_0"]["off_tracks"] == 0
    assert info["car_0"]["laps"] >= 2
