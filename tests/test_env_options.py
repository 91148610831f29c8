"""The envs as a library: make_vec without the learn extra, atomic resets, errors before reset,
the off-track reward options and the observation bounds."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium
import numpy as np
import pytest

import racing_env
from racing_env.gym_env import HeadToHeadEnv

ROOT = Path(__file__).resolve().parents[1]

BLOCK_LEARN = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("stable_baselines3", "torch"):
            raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)
sys.meta_path.insert(0, Block())
"""


def test_make_vec_default_mode_needs_no_stable_baselines3():
    code = BLOCK_LEARN + textwrap.dedent("""
        import gymnasium, numpy as np, racing_env
        v = gymnasium.make_vec("alpha_racer/HeadToHead-v2", num_envs=2)
        obs, info = v.reset(seed=0)
        assert obs.shape == (2, v.single_observation_space.shape[0]), obs.shape
        obs, rew, term, trunc, info = v.step(np.zeros((2, 2), np.float32))
        assert rew.shape == (2,) and np.isfinite(rew).all()
        assert type(v.unwrapped).__name__ == "HeadToHeadVectorEnv"
        assert "stable_baselines3" not in sys.modules and "torch" not in sys.modules
        try:
            import racing_env.vec_env
        except ImportError as e:
            print("vec_env:", e)
        print("OK")
    """)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip().endswith("OK")
    assert "vec_env:" in r.stdout and "learn" in r.stdout  # the SB3 VecEnv stays behind the extra


@pytest.mark.parametrize(
    "options, match",
    [
        ({"n_cars": 2, "start": "pole"}, "start mode must be"),
        ({"n_cars": 2, "order": [0, 0]}, "permutation"),
        ({"n_cars": 9}, "n_cars must be an integer"),
        ({"order": [0, 1, 5]}, "permutation"),
        (
            {"n_cars": 8, "start": racing_env.StartConfig(mode="regions", region_length=3.0)},
            "start regions span",
        ),
    ],
)
def test_failed_parallel_reset_leaves_the_env_as_it_was(options, match):
    env = racing_env.parallel_env(n_cars=3)
    env.reset(seed=4)
    env.step({a: np.array([0.5, 0.1]) for a in env.agents})
    before = (
        env.state().copy(),
        list(env.agents),
        list(env.possible_agents),
        env.config,
        env.core.rng.bit_generator.state,
        env.core.t.copy(),
    )
    with pytest.raises(ValueError, match=match):
        env.reset(seed=9, options=options)
    after = (
        env.state(),
        env.agents,
        env.possible_agents,
        env.config,
        env.core.rng.bit_generator.state,
        env.core.t,
    )
    np.testing.assert_array_equal(before[0], after[0])
    assert before[1:5] == after[1:5]
    np.testing.assert_array_equal(before[5], after[5])
    obs, *_ = env.step({a: np.array([0.5, 0.1]) for a in env.agents})  # still racing
    assert sorted(obs) == ["car_0", "car_1", "car_2"]


def test_failed_gym_reset_keeps_the_random_stream():
    env, ref = HeadToHeadEnv(), HeadToHeadEnv()
    env.reset(seed=1)
    ref.reset(seed=1)
    with pytest.raises(ValueError, match="permutation"):
        env.reset(options={"order": [1, 1, 0]})
    with pytest.raises(ValueError, match="n_cars = 4"):
        env.reset(options={"n_cars": 4})
    with pytest.raises(ValueError, match="unknown reset options"):
        env.reset(options={"laps": 2})
    np.testing.assert_array_equal(env.reset()[0], ref.reset()[0])


def test_state_and_render_before_reset_raise():
    env = racing_env.parallel_env(render_mode="rgb_array")
    with pytest.raises(RuntimeError, match=r"state\(\) called before reset"):
        env.state()
    with pytest.raises(RuntimeError, match=r"render\(\) called before reset"):
        env.render()
    gym_env = HeadToHeadEnv(render_mode="rgb_array")
    with pytest.raises(RuntimeError, match="before reset"):
        gym_env.render()
    with pytest.raises(RuntimeError, match="before reset"):
        gym_env.state()
    env.reset(seed=0)
    assert env.state().shape == (18,) and env.render().ndim == 3


def test_public_env_methods_have_numpy_docstrings():
    for cls in (racing_env.RacingParallelEnv, HeadToHeadEnv):
        for name in ("reset", "step", "close", "render", "state"):
            doc = getattr(cls, name).__doc__
            assert doc and len(doc) > 40, f"{cls.__name__}.{name}"
            if name not in ("close",):
                assert "Returns\n        -------" in doc, f"{cls.__name__}.{name}"
    for name in ("observation_space", "action_space"):
        assert "Returns\n        -------" in getattr(racing_env.RacingParallelEnv, name).__doc__
        assert name in HeadToHeadEnv.__doc__


def test_offtrack_penalty_and_termination_in_the_gym_env():
    base = HeadToHeadEnv(start="grid")
    pen = HeadToHeadEnv(start="grid", offtrack_penalty=0.25)
    base.reset(seed=2)
    pen.reset(seed=2)
    off_seen = False
    for _ in range(60):
        o1, r1, te1, tr1, i1 = base.step(np.array([1.0, 1.0], np.float32))
        o2, r2, te2, tr2, i2 = pen.step(np.array([1.0, 1.0], np.float32))
        np.testing.assert_array_equal(o1, o2)  # the penalty changes rewards only
        assert r2 == pytest.approx(r1 - 0.25 * i1["off_track"], abs=1e-12)
        off_seen |= i1["off_track"]
    assert off_seen
    term = HeadToHeadEnv(start="grid", terminate_off_track=True)
    term.reset(seed=2)
    steps = []
    while not (steps and (steps[-1][2] or steps[-1][3])):
        steps.append(term.step(np.array([1.0, 1.0], np.float32)))  # hard left: leaves the track
    assert steps[-1][2] and steps[-1][4]["off_track"] and len(steps) < 60
    assert not any(s[4]["off_track"] for s in steps[:-1])
    with pytest.raises(RuntimeError, match="finished episode"):
        term.step(np.zeros(2, np.float32))


def test_offtrack_options_in_the_parallel_and_vector_envs():
    env = racing_env.parallel_env(
        n_cars=2, start="grid", terminate_off_track=True, offtrack_penalty=1.0
    )
    ref = racing_env.parallel_env(n_cars=2, start="grid")
    env.reset(seed=3)
    ref.reset(seed=3)
    acts = {"car_0": np.array([1.0, 1.0]), "car_1": np.array([0.2, 0.0])}
    for _ in range(60):
        o, r, te, tr, inf = env.step(acts)
        _, r0, _, _, _ = ref.step(acts)
        for a in o:
            assert r[a] == pytest.approx(r0[a] - inf[a]["off_track"], abs=1e-12)
        if te["car_0"]:
            assert inf["car_0"]["off_track"] and te["car_1"] and not env.agents
            break
    else:
        pytest.fail("the parallel env never terminated off track")
    v = gymnasium.make_vec(
        "alpha_racer/HeadToHead-v2",
        num_envs=2,
        start="grid",
        terminate_off_track=True,
        offtrack_penalty=0.5,
    )
    single = HeadToHeadEnv(start="grid", terminate_off_track=True, offtrack_penalty=0.5)
    v.reset(seed=5)
    single.reset(seed=5)
    for _ in range(60):
        _, rv, tv, _, _ = v.step(np.tile([1.0, 1.0], (2, 1)).astype(np.float32))
        _, rs, ts, _, _ = single.step(np.array([1.0, 1.0], np.float32))
        assert rv[0] == pytest.approx(rs, abs=1e-12) and tv[0] == ts
        if ts:
            break
    else:
        pytest.fail("the vector env never terminated off track")


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"offtrack_penalty": -1.0}, "offtrack_penalty"),
        ({"offtrack_penalty": float("nan")}, "offtrack_penalty"),
        ({"terminate_off_track": "yes"}, "terminate_off_track"),
    ],
)
def test_bad_offtrack_options(kw, match):
    with pytest.raises(ValueError, match=match):
        racing_env.parallel_env(**kw)
    with pytest.raises(ValueError, match=match):
        HeadToHeadEnv(**kw)
