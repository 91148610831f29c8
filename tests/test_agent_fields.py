"""An RL researcher's own policy in our races: plain SB3 zips, field sizes, errors that name
the agent and its car, ``adapt_observation`` public."""

import zipfile

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
import torch  # noqa: E402

import agents  # noqa: E402
from agents import make_agent_spec  # noqa: E402
from experiments.evaluation.race import run_race  # noqa: E402

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def sb3_run(tmp_path_factory):
    """A tiny SB3 PPO on HeadToHead-v2 (3 cars) with VecNormalize, saved the plain SB3 way."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from racing_env.vec_env import HeadToHeadVecEnv

    out = tmp_path_factory.mktemp("sb3")
    venv = VecNormalize(VecMonitor(HeadToHeadVecEnv(2, max_cycles=20)))
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=32, n_epochs=1, seed=0, device="cpu")
    model.learn(64)
    model.save(out / "model.zip")
    venv.save(str(out / "vecnormalize.pkl"))
    return out, model, venv


def test_plain_sb3_zip_races_with_its_normalisation(sb3_run):
    out, model, venv = sb3_run
    agent = make_agent_spec(
        f"ppo:checkpoint={out / 'model.zip'},vecnormalize={out / 'vecnormalize.pkl'}"
    )
    assert agent.n_cars == 3 and agent.meta["kind"] == "sb3"
    assert agent.model_files() == [out / "model.zip", out / "vecnormalize.pkl"]
    from racing_env import parallel_env

    env = parallel_env(n_cars=3)
    obs, _ = env.reset(seed=0)
    agent.reset(env.track, "car_0")
    expected, _ = model.predict(venv.normalize_obs(obs["car_0"][None]), deterministic=True)
    np.testing.assert_allclose(agent.act(obs["car_0"]), np.clip(expected[0], -1, 1), atol=1e-5)
    raw = make_agent_spec(f"ppo:checkpoint={out / 'model.zip'},vecnormalize=none")
    assert raw.norm is None


def test_plain_sb3_zip_errors_say_what_to_give(sb3_run, tmp_path):
    out, *_ = sb3_run
    with pytest.raises(ValueError, match="vecnormalize=PATH.*vecnormalize=none"):
        make_agent_spec(f"ppo:checkpoint={out / 'model.zip'}")
    with pytest.raises(ValueError, match="does not exist"):
        make_agent_spec(f"ppo:checkpoint={out / 'model.zip'},vecnormalize={tmp_path / 'no.pkl'}")
    junk = tmp_path / "junk.zip"
    with zipfile.ZipFile(junk, "w") as z:
        z.writestr("something.txt", "x")
    with pytest.raises(ValueError, match="save_checkpoint"):
        make_agent_spec(f"ppo:checkpoint={junk}")
    with pytest.raises(ValueError, match="carries its own normalisation"):
        make_agent_spec(f"ppo:vecnormalize={out / 'vecnormalize.pkl'}")


def test_save_checkpoint_output_races_as_ppo_checkpoint(sb3_run, tmp_path):
    from agents.ppo_agent import save_checkpoint

    out, model, venv = sb3_run
    with pytest.raises(ValueError, match="n_preview"):
        save_checkpoint(model, venv, tmp_path / "x.zip", {"n_cars": 3})
    path = save_checkpoint(model, venv, tmp_path / "mine.zip", {"n_cars": 3, "n_preview": 10})
    a = make_agent_spec(f"ppo:checkpoint={path}")
    b = make_agent_spec(
        f"ppo:checkpoint={out / 'model.zip'},vecnormalize={out / 'vecnormalize.pkl'}"
    )
    obs = np.random.default_rng(0).normal(size=(4, 28)).astype(np.float32)
    np.testing.assert_array_equal(a.act_batch(obs), b.act_batch(obs))


def test_a_three_car_policy_in_a_two_car_vector_env(sb3_run):
    """act_batch (the vector envs' path) adapts other field sizes too; before the fix this was
    'operands could not be broadcast together with shapes (22,) (28,)'."""
    from racing_env.vec_env import HeadToHeadVecEnv

    out, *_ = sb3_run
    policy = make_agent_spec(
        f"ppo:checkpoint={out / 'model.zip'},vecnormalize={out / 'vecnormalize.pkl'}"
    )
    with pytest.raises(
        ValueError, match=r"observations of 22 values, its policy reads 28 \(3 cars\)"
    ):
        policy.act_batch(np.zeros((2, 22), np.float32))
    env = HeadToHeadVecEnv(2, opponents=[policy], n_cars=2)
    env.reset()
    obs, rew, done, info = env.step(np.zeros((2, 2), np.float32))
    assert obs.shape == (2, 22) and np.isfinite(rew).all()


class Fixed3:
    """A user agent made for 3-car fields that does not adapt."""

    field_sizes = {3}
    name = "fixed3"

    def __init__(self):
        self.w = np.ones(28, np.float32)

    def reset(self, track, agent_id, seed=None):
        pass

    def act(self, observation):
        return np.array([np.tanh((self.w * observation).sum() * 0.0), 0.0], np.float32)


class Undeclared(Fixed3):
    field_sizes = None


def test_field_sizes_are_checked_before_the_race_and_errors_name_agent_and_car():
    agents.register_agent("fixed3", Fixed3)
    agents.register_agent("undeclared3", Undeclared)
    with pytest.raises(
        ValueError,
        match=r"agent 'fixed3' driving car_1 cannot race in a field of 2 "
        r"cars: it supports 3 cars",
    ):
        run_race(["raceline", "fixed3"], max_cycles=2, progress_bar=False)
    with pytest.raises(
        ValueError,
        match=r"agent 'undeclared3' driving car_1 \(observation of 22 "
        r"values\): .*broadcast",
    ):
        run_race(["raceline", "undeclared3"], max_cycles=2, progress_bar=False)
    result, _ = run_race(["raceline", "fixed3", "raceline"], max_cycles=2, progress_bar=False)
    assert len(result.agents) == 3
    with pytest.raises(ValueError, match="field_sizes must be a container"):
        agents.check_field_size(type("A", (), {"field_sizes": 3})(), 2, "car_0")


def test_gym_env_opponent_errors_name_the_opponent_and_car():
    from racing_env.gym_env import HeadToHeadEnv

    env = HeadToHeadEnv(opponents=[Undeclared()])
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"agent 'fixed3' driving car_1"):
        env.step(np.zeros(2, np.float32))


class BatchUndeclared(Undeclared):
    def act_batch(self, observations):
        return np.stack([self.act(o) for o in observations])


@pytest.mark.parametrize("opponent", [Undeclared, BatchUndeclared])
def test_vector_env_opponent_errors_name_the_opponent_and_car(opponent):
    """Both vector envs take the opponents' actions through one loop that names the agent, per
    race (act) and batched (act_batch) alike."""
    from racing_env.gym_vector import HeadToHeadVectorEnv

    env = HeadToHeadVectorEnv(2, opponents=[opponent()])
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"agent 'fixed3' driving car_1 \(observation of 22"):
        env.step(np.zeros((2, 2), np.float32))
    pytest.importorskip("stable_baselines3")
    from racing_env.vec_env import HeadToHeadVecEnv

    venv = HeadToHeadVecEnv(2, opponents=[opponent()])
    venv.reset()
    with pytest.raises(ValueError, match=r"agent 'fixed3' driving car_1 \(observation of 22"):
        venv.step(np.zeros((2, 2), np.float32))


def test_adapt_observation_is_public_with_the_old_names():
    from agents import adapt_observation
    from agents.observations import _adapt_observation
    from agents.ppo_agent import adapt_observation as from_ppo

    assert adapt_observation is _adapt_observation is from_ppo
    obs = np.arange(22, dtype=np.float32)  # 2 cars, 10 preview values
    three = adapt_observation(obs, 3, 10, track_length=40.0)
    assert three.shape == (28,) and three[12] == -20.0
    np.testing.assert_array_equal(three[:12], obs[:12])
    np.testing.assert_array_equal(three[18:], obs[12:])
    with pytest.raises(ValueError, match="does not fit 6 N"):
        adapt_observation(np.zeros(21), 3, 10, 40.0)
