"""PettingZoo and Gymnasium environments: official checkers, determinism, options, errors."""

import sys

import gymnasium
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pettingzoo.test import (
    api_test,
    max_cycles_test,
    parallel_api_test,
    parallel_seed_test,
    render_test,
)

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
    assert not np.array_equal(a[0], c[0])  # another seed, another start


def test_reset_options_change_cars_and_start():
    env = RacingParallelEnv(n_cars=3)
    obs, _ = env.reset(seed=0, options={"n_cars": 5, "start": "grid"})
    assert env.agents == [f"car_{i}" for i in range(5)]
    assert obs["car_4"].shape == env.observation_space("car_4").shape == (6 * 5 + 10,)
    s = env.state().reshape(5, 6)[:, 0]
    assert np.all(np.diff(s) < 0)  # grid: car_0 on pole, the rest behind
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
    st[:, 0] = [2.0, 1.5, env.track.length + 1.0]  # car_2 a lap ahead, physically behind
    obs = env.core.observe()[0]
    assert obs[0, 0] == pytest.approx(2.0)
    assert obs[0, 6] == pytest.approx(-0.5)  # car_1 relative to car_0
    assert obs[0, 12] == pytest.approx(env.track.length - 1.0, rel=1e-6)
    assert obs[2, 0] == pytest.approx(1.0, rel=1e-5)  # own s is wrapped


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
    with pytest.raises(ValueError, match="action of car_1 is NaN"):
        env.step({"car_0": np.zeros(2), "car_1": np.array([np.nan, 0.0])})


def test_gymnasium_env_passes_checkers():
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = gymnasium.make("alpha_racer/HeadToHead-v2")
    check_env(env.unwrapped, skip_render_check=True)
    sb3_check_env(HeadToHeadEnv(max_cycles=50), warn=True)


def test_gymnasium_env_opponents_drive():
    env = HeadToHeadEnv(opponents=[RacelineFollower(grip=0.7)], max_cycles=80, start="grid")
    obs, info = env.reset(seed=1)
    assert obs.shape == env.observation_space.shape == (6 * 2 + 10,)
    total = 0.0
    for _ in range(80):
        obs, r, term, trunc, info = env.step(np.array([0.0, 0.0], np.float32))
        total += r
    assert trunc and not term
    assert env.race.core.progress()[0, 1] > 5.0  # the follower raced on
    assert total < 0  # standing still loses ground
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


# ---------------------------------------------------------------- issue 13: a dependable package
class Wobbler:
    """A stateful opponent: its steering follows its own count of calls (shared, it would
    advance once per env and every env would see a different sequence)."""

    def __init__(self, amplitude=0.4):
        self.amplitude = amplitude
        self.calls = 0

    def reset(self, track, agent_id, seed=None):
        self.calls = 0

    def act(self, observation):
        self.calls += 1
        return np.array([0.6, self.amplitude * np.sin(0.7 * self.calls)], np.float32)


def _vec_opponents():
    import functools

    return [Wobbler(0.4), functools.partial(Wobbler, -0.3), "raceline:grip=0.8"]


@pytest.mark.parametrize("mode", ["sync", "async", "vector_entry_point"])
def test_make_vec_matches_single_envs_step_for_step(mode):
    n_envs, steps, cycles = 3, 14, 6  # over two episode ends (autoreset included)
    kwargs = dict(opponents=_vec_opponents(), max_cycles=cycles, start="grid")
    venv = gymnasium.make_vec(
        "alpha_racer/HeadToHead-v2", num_envs=n_envs, vectorization_mode=mode, **kwargs
    )
    singles = [gymnasium.make("alpha_racer/HeadToHead-v2", **kwargs) for _ in range(n_envs)]
    obs, _ = venv.reset(seed=11)
    single_obs = [env.reset(seed=11 + b)[0] for b, env in enumerate(singles)]
    np.testing.assert_array_equal(obs, np.stack(single_obs))
    rng = np.random.default_rng(0)
    done = [False] * n_envs
    for _ in range(steps):
        actions = rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32)
        obs, rew, term, trunc, _ = venv.step(actions)
        for b, env in enumerate(singles):
            if done[b]:  # Gymnasium's next-step autoreset
                o, r, te, tr = env.reset()[0], 0.0, False, False
            else:
                o, r, te, tr, _ = env.step(actions[b])
            np.testing.assert_array_equal(obs[b], o)
            assert rew[b] == pytest.approx(r, abs=1e-12)
            assert (term[b], trunc[b]) == (te, tr)
            done[b] = te or tr
    venv.close()


def test_vector_envs_each_get_their_own_opponents():
    from racing_env.gym_vector import HeadToHeadVectorEnv
    from racing_env.vec_env import HeadToHeadVecEnv

    shared = Wobbler()
    venv = HeadToHeadVectorEnv(num_envs=2, opponents=[shared, Wobbler])
    a, b = (opp for opp in venv.opponents[0]), (opp for opp in venv.opponents[1])
    ids = {id(o) for o in [*a, *b, shared]}
    assert len(ids) == 5
    sb3 = HeadToHeadVecEnv(2, opponents=["raceline:grip=0.7"])
    assert sb3.opponents[0][0] is not sb3.opponents[0][1]
    env = HeadToHeadEnv(opponents=[shared])
    assert env.opponents[0] is not shared
    with pytest.raises(ValueError, match="opponent 0"):
        HeadToHeadEnv(opponents=[lambda: object()])
    with pytest.raises(ValueError, match="unknown agent"):
        HeadToHeadEnv(opponents=["no-such-agent"])


def test_registered_env_versions_and_episode_length():
    assert RacingParallelEnv.metadata["name"] == "alpha_racer_v2"
    spec = gymnasium.spec("alpha_racer/HeadToHead-v2")
    assert spec.max_episode_steps == 500
    assert spec.vector_entry_point is not None
    env = gymnasium.make("alpha_racer/HeadToHead-v2", opponents=[Wobbler()])
    raw = HeadToHeadEnv(opponents=[Wobbler()])
    env.reset(seed=3)
    raw.reset(seed=3)
    for t in range(1, 501):
        a = np.array([0.3, 0.0], np.float32)
        o1, r1, te1, tr1, _ = env.step(a)
        o2, r2, te2, tr2, _ = raw.step(a)
        np.testing.assert_array_equal(o1, o2)
        assert (r1, te1, tr1) == (r2, te2, tr2)
        assert tr1 == (t == 500)


@pytest.mark.parametrize("action", [0.5, np.array([0.5]), np.zeros(3), np.zeros((1, 2))])
def test_actions_of_the_wrong_shape_raise(action):
    env = RacingParallelEnv(n_cars=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action of car_1 must have shape \(2,\)"):
        env.step({"car_0": np.zeros(2), "car_1": action})


def test_actions_for_unknown_agents_raise():
    env = RacingParallelEnv(n_cars=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="unknown agents.*car_7"):
        env.step({"car_0": np.zeros(2), "car_1": np.zeros(2), "car_7": np.array([np.nan, 0.0])})


@settings(max_examples=20, deadline=None)
@given(
    throttle=st.sampled_from([-np.inf, np.inf, 0.3]),
    steer=st.sampled_from([-np.inf, np.inf, -0.2]),
    car=st.integers(0, 1),
)
def test_infinite_actions_are_clipped_like_any_out_of_range_value(throttle, steer, car):
    states = []
    for action in (np.array([throttle, steer]), np.clip([throttle, steer], -1.0, 1.0)):
        env = RacingParallelEnv(n_cars=2)
        env.reset(seed=4)
        acts = {"car_0": np.array([0.2, 0.0]), "car_1": np.array([0.2, 0.0])}
        acts[f"car_{car}"] = action
        env.step(acts)
        states.append(env.state())
    np.testing.assert_array_equal(*states)
    with pytest.raises(ValueError, match="action of car_1 is NaN"):
        env.step({"car_0": np.zeros(2), "car_1": np.array([0.0, np.nan])})


def test_messages_name_the_problem():
    with pytest.raises(RuntimeError, match=r"before reset\(\); call reset\(\) first"):
        RacingParallelEnv(n_cars=2).step({})
    with pytest.raises(ValueError, match="n_cars must be an integer in 1..8, got True"):
        RacingParallelEnv(n_cars=True)
    with pytest.raises(ValueError, match="max_cycles must be a positive integer, got True"):
        RacingParallelEnv(max_cycles=True)
    with pytest.raises(ValueError, match="seed must be a non-negative integer.*random:-1"):
        racing_env.make_track("random:-1")
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        racing_env.make_track("random:x")


def _reset_with_timeout(env, seconds=30.0):
    import threading

    box = []
    th = threading.Thread(target=lambda: box.append(env.reset(seed=0)), daemon=True)
    th.start()
    th.join(seconds)
    assert box, f"reset() did not return within {seconds} s"


def test_random_start_of_a_full_track_returns():
    env = racing_env.parallel_env(
        n_cars=8, track="oval", start=racing_env.StartConfig(mode="random", min_gap=2.4)
    )
    _reset_with_timeout(env)
    with pytest.raises(ValueError, match="do not fit"):
        racing_env.parallel_env(
            n_cars=8, track="oval", start=racing_env.StartConfig(mode="random", min_gap=2.7)
        ).reset(seed=0)


@settings(max_examples=30, deadline=None)
@given(n_cars=st.integers(2, 8), fill=st.floats(0.05, 1.0), seed=st.integers(0, 2**31 - 1))
def test_random_starts_keep_the_minimum_gap(n_cars, fill, seed):
    track = racing_env.make_track("oval")
    min_gap = fill * track.length / n_cars
    env = racing_env.parallel_env(
        n_cars=n_cars, track=track, start=racing_env.StartConfig(mode="random", min_gap=min_gap)
    )
    env.reset(seed=seed)
    s = np.sort(env.state().reshape(n_cars, 6)[:, 0].astype(np.float64) % track.length)
    gaps = np.diff(np.append(s, s[0] + track.length))
    assert gaps.min() >= min_gap - 1e-4  # state() is float32


def test_parallel_env_has_a_seeded_np_random():
    env = RacingParallelEnv(n_cars=2)
    assert isinstance(env.np_random, np.random.Generator)
    env.reset(seed=5)
    a = env.np_random.random(3)
    env.reset(seed=5)
    np.testing.assert_array_equal(a, env.np_random.random(3))


def test_supersuit_frame_skip_wraps_the_parallel_env():
    # its own test: a missing supersuit skips this, not the np_random check above
    supersuit = pytest.importorskip("supersuit")
    skipped = supersuit.frame_skip_v0(racing_env.parallel_env(n_cars=2, max_cycles=20), 2)
    skipped.reset(seed=0)
    skipped.step({a: np.zeros(2, np.float32) for a in skipped.agents})
