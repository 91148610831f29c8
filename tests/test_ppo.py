"""PPO self-play: the batched learning env, the frozen policy, the pipeline end to end,
resume after an interruption, the shipped ``ppo`` agent, config errors."""

import csv
import json
import zipfile

import numpy as np
import pytest
import torch

from agents import make_agent_spec
from agents.ppo_agent import (
    FrozenPolicy,
    PPOAgent,
    adapt_observation,
    default_checkpoint,
    read_checkpoint_meta,
)
from experiments.cli import main
from experiments.learning import config as sp_config
from experiments.learning import envs as sp_envs
from experiments.learning.config import SelfPlayConfig
from experiments.learning.selfplay import selfplay
from racing_env import RaceConfig, RacingParallelEnv
from racing_env.controllers import RacelineFollower
from racing_env.gym_env import HeadToHeadEnv
from racing_env.vec_env import HeadToHeadVecEnv

torch.set_num_threads(1)

TINY = dict(
    n_cars=2,
    cycles=1,
    steps_per_turn=128,
    n_envs=2,
    n_steps=64,
    batch_size=64,
    n_epochs=1,
    max_cycles=40,
    eval_races=1,
    mpc_reference=False,
)
TINY_ARGS = [
    "--cars",
    "2",
    "--cycles",
    "1",
    "--steps-per-turn",
    "128",
    "--envs",
    "2",
    "--n-steps",
    "64",
    "--batch-size",
    "64",
    "--epochs",
    "1",
    "--race-steps",
    "40",
    "--eval-races",
    "1",
    "--no-mpc-reference",
]


# ---------------------------------------------------------------------- the batched env
def test_batched_vec_env_equals_dummy_vec_env_over_the_gym_env():
    from stable_baselines3.common.vec_env import DummyVecEnv

    cfg = RaceConfig(n_cars=3, max_cycles=25)
    opps = [RacelineFollower(grip=0.75), RacelineFollower(grip=0.8)]
    ref = DummyVecEnv(
        [
            lambda: HeadToHeadEnv(
                opponents=[RacelineFollower(grip=0.75), RacelineFollower(grip=0.8)], config=cfg
            )
        ]
        * 3
    )
    bat = HeadToHeadVecEnv(3, opponents=opps, config=cfg)
    assert bat.observation_space == ref.observation_space and bat.action_space == ref.action_space
    ref.seed(11)
    bat.seed(11)
    np.testing.assert_array_equal(ref.reset(), bat.reset())
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(60):  # two episode ends per race
        a = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
        o1, r1, d1, i1 = ref.step(a)
        o2, r2, d2, i2 = bat.step(a)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_allclose(r1, r2, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(d1, d2)
        for x, y in zip(i1, i2):
            assert x.keys() == y.keys()
            for k in x:
                np.testing.assert_allclose(x[k], y[k], rtol=0, atol=1e-6)
        ends += int(d2.sum())
    assert ends == 6


def test_batched_vec_env_errors():
    with pytest.raises(ValueError, match="n_envs must be a positive integer, got 0"):
        HeadToHeadVecEnv(0)
    with pytest.raises(ValueError, match="n_cars = 4"):
        HeadToHeadVecEnv(2, n_cars=4)
    with pytest.raises(ValueError, match=r"unknown arguments \['foo'\]"):
        HeadToHeadVecEnv(2, foo=1)
    env = HeadToHeadVecEnv(2)
    env.set_options({"order": [0, 1, 1]})
    with pytest.raises(ValueError, match="permutation"):
        env.reset()


# ---------------------------------------------------------------------- frozen policies
@pytest.fixture(scope="module")
def trained_model():
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    env = VecNormalize(HeadToHeadVecEnv(2, max_cycles=30))
    model = PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, device="cpu", seed=0)
    model.learn(64)
    return model, env


def test_frozen_policy_equals_sb3_predict(trained_model):
    model, env = trained_model
    frozen = FrozenPolicy(model.policy, env, n_cars=3)
    assert frozen.layers is not None  # the numpy actor
    obs = HeadToHeadVecEnv(4).reset()
    expected, _ = model.policy.predict(env.normalize_obs(obs), deterministic=True)
    np.testing.assert_allclose(frozen.act_batch(obs), np.clip(expected, -1, 1), atol=1e-5)
    frozen.layers = None  # the generic path: policy.predict
    np.testing.assert_allclose(frozen.act_batch(obs), np.clip(expected, -1, 1), atol=1e-6)


def test_adapt_observation_pads_phantoms_and_keeps_nearest():
    length, k = 40.0, 10
    own = np.arange(6, dtype=np.float32)
    prev = np.full(k, 0.5, np.float32)
    solo = np.concatenate([own, prev])
    a = adapt_observation(solo, 3, k, length)
    assert a.shape == (6 * 3 + k,)
    np.testing.assert_array_equal(a[:6], own)
    np.testing.assert_array_equal(a[-k:], prev)
    np.testing.assert_array_equal(a[6:18].reshape(2, 6)[:, 0], [-20.0, -20.0])
    assert not a[6:18].reshape(2, 6)[:, 1:].any()
    others = np.array(
        [[5.0, 1, 1, 1, 1, 1], [-0.5, 2, 2, 2, 2, 2], [0.2, 3, 3, 3, 3, 3]], np.float32
    )
    five = np.concatenate([own, others.ravel(), prev])
    b = adapt_observation(five, 3, k, length)
    np.testing.assert_array_equal(b[6:18].reshape(2, 6), others[1:])  # the two nearest, index order
    with pytest.raises(ValueError, match="does not fit"):
        adapt_observation(np.zeros(13), 3, k, length)


# ---------------------------------------------------------------------- the pipeline
def _assert_learning_curve_drawn(path):
    """The figure of :func:`experiments.learning.report.plot_learning_curve`: 8 x 9 in at 110 dpi,
    three panels with coloured curves on white."""
    from PIL import Image

    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert img.shape == (990, 880, 3)
    white = (img == 255).all(axis=2)
    assert 0.5 < white.mean() < 0.99  # mostly background, not blank
    coloured = np.ptp(img, axis=2) > 60  # saturated pixels: curves, not text
    assert coloured.sum() > 200
    rows = np.flatnonzero(coloured.any(axis=1))
    # curves in the top and the bottom panel (the middle one holds the 5% line)
    assert rows.min() < img.shape[0] // 3 and rows.max() > 2 * img.shape[0] // 3


def test_selfplay_tiny_end_to_end(tmp_path, capsys):
    out = tmp_path / "run"
    assert (
        main(["selfplay", "--out", str(out), "--init", "bc", "--bc-steps", "96"] + TINY_ARGS) == 0
    )
    assert "2/2 turns" in capsys.readouterr().out
    for name in (
        "config.json",
        "state.json",
        "summary.json",
        "evals.csv",
        "learning_curve.png",
        "MODEL_CARD.md",
        "best.zip",
        "final/car_0.zip",
        "final/car_1.zip",
        "checkpoints/bc_init.zip",
        "checkpoints/turn_000_car_0.zip",
        "checkpoints/turn_001_car_1.zip",
    ):
        assert (out / name).is_file(), name
    _assert_learning_curve_drawn(out / "learning_curve.png")
    assert list((out / "logs" / "car_0").glob("events.out.tfevents.*"))  # TensorBoard
    assert list((out / "logs" / "eval").glob("events.out.tfevents.*"))
    progress = list((out / "logs" / "car_1").glob("progress_*.csv"))
    assert progress and "rollout/ep_rew_mean" in progress[0].read_text().splitlines()[0]
    rows = list(csv.DictReader(open(out / "evals.csv")))
    assert [(r["phase"], int(r["car"])) for r in rows] == [("bc", -1), ("ppo", 0), ("ppo", 1)]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["done"] and summary["total_steps"] == 2 * 128 and summary["steps_per_s"] > 0
    # every checkpoint carries its config and the VecNormalize statistics
    meta = read_checkpoint_meta(out / "final" / "car_1.zip")
    assert meta["selfplay_config"] == SelfPlayConfig(**TINY, init="bc", bc_steps=96).to_dict()
    assert meta["n_cars"] == 2 and meta["car"] == 1 and meta["evaluation"]["distance_m"] >= 0
    assert "vecnormalize.pkl" in zipfile.ZipFile(out / "best.zip").namelist()
    # the checkpoint drives as the ppo agent
    agent = make_agent_spec(f"ppo:checkpoint={out / 'best.zip'}")
    env = RacingParallelEnv(n_cars=2, max_cycles=5)
    obs, _ = env.reset(seed=0)
    agent.reset(env.track, "car_0", 0)
    a = agent.act(obs["car_0"])
    assert a.shape == (2,) and a.dtype == np.float32 and np.all(np.abs(a) <= 1)


def test_selfplay_resumes_from_the_last_checkpoint(tmp_path, monkeypatch):
    cfg = SelfPlayConfig(**{**TINY, "steps_per_turn": 256})  # 2 rollouts per turn
    real_write = sp_config.write_json

    def interrupt_after_in_turn_checkpoint(path, obj):
        real_write(path, obj)
        if path.name == "state.json" and obj.get("turn") == 1 and obj.get("current"):
            raise KeyboardInterrupt  # killed in the middle of turn 2

    monkeypatch.setattr(sp_config, "write_json", interrupt_after_in_turn_checkpoint)
    with pytest.raises(KeyboardInterrupt):
        selfplay(cfg, tmp_path, progress_bar=False)
    monkeypatch.setattr(sp_config, "write_json", real_write)
    state = json.loads((tmp_path / "state.json").read_text())
    assert state["turn"] == 1 and state["turn_steps"] == 128 and state["total_steps"] == 384
    first_turn = (tmp_path / "checkpoints" / "turn_000_car_0.zip").stat().st_mtime_ns
    summary = selfplay(cfg, tmp_path, progress_bar=False)
    assert summary["done"] and summary["total_steps"] == 512  # nothing trained twice
    assert (tmp_path / "checkpoints" / "turn_000_car_0.zip").stat().st_mtime_ns == first_turn
    # the resumed half-turn logged from step 128 on, and car 1's step counter went on
    assert (tmp_path / "logs" / "car_1" / "progress_turn001_000000128.csv").is_file()
    assert read_checkpoint_meta(tmp_path / "final" / "car_1.zip")["car_timesteps"] == 256
    assert not list((tmp_path / "checkpoints" / "partial").iterdir())
    # a finished run stays finished; other settings in the same folder are refused
    assert selfplay(cfg, tmp_path, progress_bar=False)["total_steps"] == 512
    with pytest.raises(ValueError, match="another configuration"):
        selfplay(SelfPlayConfig(**{**TINY, "seed": 1}), tmp_path, progress_bar=False)


@pytest.mark.parametrize(
    "field, value",
    [
        ("cycles", 0),
        ("steps_per_turn", -5),
        ("n_envs", 1.5),
        ("n_cars", 1),
        ("n_cars", 9),
        ("learning_rate", 0.0),
        ("gamma", 1.5),
        ("vec_env", "ray"),
        ("warmup_opponent", "mpc"),
        ("net_arch", (64, 0)),
        ("start", "pole"),
        ("ent_coef", -0.1),
        ("init", "pretrained"),
        ("bc_rounds", 0),
        ("bc_noise", -1.0),
    ],
)
def test_bad_config_values_raise_naming_the_value(field, value):
    with pytest.raises(
        ValueError, match=f"{field}.*{value!r}".replace("(", r"\(").replace(")", r"\)")
    ):
        SelfPlayConfig(**{field: value})


def test_batch_larger_than_a_rollout_is_refused():
    with pytest.raises(ValueError, match="batch_size 4096 exceeds"):
        SelfPlayConfig(batch_size=4096, n_steps=256, n_envs=8)


def test_bad_checkpoints_raise_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        make_agent_spec(f"ppo:checkpoint={tmp_path / 'none.zip'}")
    (tmp_path / "x.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not an alpha-racer PPO checkpoint"):
        PPOAgent(checkpoint=tmp_path / "x.zip")


# ---------------------------------------------------------------------- the shipped agent
def test_shipped_ppo_agent_loads_and_drives():
    meta = read_checkpoint_meta(default_checkpoint())
    assert meta["n_cars"] == 3 and meta["evaluation"]["off_track_frac"] < 0.05
    agent = make_agent_spec("ppo")
    for n_cars in (1, 3, 4):
        env = RacingParallelEnv(n_cars=n_cars, max_cycles=30)
        obs, _ = env.reset(seed=0)
        agent.reset(env.track, "car_0", 0)
        while env.agents:
            acts = {a: np.array([0.3, 0.0], np.float32) for a in env.agents}
            acts["car_0"] = agent.act(obs["car_0"])
            assert np.all(np.isfinite(acts["car_0"])) and np.all(np.abs(acts["car_0"]) <= 1)
            obs, *_ = env.step(acts)
        assert env.core.progress()[0, 0] > 1.0  # it drives off


# ---------------------------------------------------------------------- slow
@pytest.mark.slow
@pytest.mark.parametrize("backend", ["dummy", "subproc"])
def test_selfplay_with_sb3_vec_envs(tmp_path, backend):
    summary = selfplay(SelfPlayConfig(**{**TINY, "vec_env": backend}), tmp_path, progress_bar=False)
    assert summary["done"] and summary["total_steps"] == 256


@pytest.mark.slow
def test_race_ppo_against_two_mpcs(tmp_path):
    pytest.importorskip("daqp")
    out = tmp_path / "race"
    assert (
        main(
            [
                "race",
                "--agents",
                "ppo",
                "mpc",
                "mpc",
                "--steps",
                "100",
                "--no-animation",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    summary = json.loads((out / "result.json").read_text())
    assert summary["agents"] == ["ppo", "mpc", "mpc"] and min(summary["progress_m"]) > 5.0


@pytest.mark.slow
def test_shipped_ppo_agent_meets_the_quality_bar():
    """Alone on the default track for 50 s: >= 80% of the MPC's distance, < 5% off track."""
    pytest.importorskip("daqp")
    cfg = SelfPlayConfig()
    ppo = sp_envs.evaluate_solo(make_agent_spec("ppo"), cfg, races=3)
    mpc = sp_envs.mpc_reference(cfg)
    assert ppo["distance_m"] >= 0.8 * mpc["distance_m"]
    assert ppo["off_track_frac"] < 0.05
