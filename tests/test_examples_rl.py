"""The learning path and the "Use with other RL libraries" examples, run with tiny budgets.

Each test skips, with the reason, where its library does not import (the ``rl`` extra holds
SuperSuit and TorchRL; RLlib pins its own Gymnasium version and is installed apart).
"""

import importlib
import runpy
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def _need(*modules):
    for name in modules:
        try:
            importlib.import_module(name)
        except Exception as exc:  # ImportError, or a library broken by a version pin
            pytest.skip(
                f"{name} is not importable here ({type(exc).__name__}: {exc}); "
                f"see docs/rl-libraries.md for how to install it"
            )


def _example(name):
    return runpy.run_path(str(ROOT / "examples" / name), run_name="example")


def test_learn_ppo_trains_evaluates_saves_and_races(tmp_path):
    _need("torch", "stable_baselines3")
    out = tmp_path / "run"
    report = _example("learn_ppo.py")["main"](
        [
            "--steps",
            "1024",
            "--envs",
            "2",
            "--n-steps",
            "128",
            "--eval-races",
            "2",
            "--race-steps",
            "20",
            "--off-track-penalty",
            "0.05",
            "--out",
            str(out),
        ]
    )
    assert (out / "curve.csv").read_text().startswith("steps,return,distance_m,off_track_share")
    assert 0.0 <= report["evaluation"]["off_track_share"] <= 1.0
    assert sorted(report["race_order"]) == [0, 1, 2]
    # the checkpoint is what `ppo:checkpoint=` races
    from agents import make_agent_spec

    agent = make_agent_spec(f"ppo:checkpoint={out / 'model.zip'}")
    assert agent.n_cars == 3


def test_supersuit_shared_policy():
    _need("supersuit", "stable_baselines3")
    model = _example("rl_supersuit.py")["main"](512)
    assert model.num_timesteps >= 512


def test_torchrl_multi_agent_ppo():
    _need("torchrl", "tensordict")
    rewards = _example("rl_torchrl.py")["main"](1)
    assert len(rewards) == 1


def test_rllib_multi_agent_ppo():
    _need("ray.rllib", "ray.rllib.algorithms.ppo")
    result = _example("rl_rllib.py")["main"](1)
    assert result["env_runners"]["num_env_steps_sampled_lifetime"] > 0


def test_cleanrl_style_ppo():
    _need("torch")
    progress = _example("cleanrl_ppo.py")["main"](
        ["--total-steps", "256", "--rollout", "128", "--max-cycles", "100", "--epochs", "1"]
    )
    assert len(progress) == 2
