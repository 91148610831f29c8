"""Train stable-baselines3 PPO on ``alpha_racer/HeadToHead-v2``, evaluate it, race it.

The learning path of the docs (``docs/learning.md``), as one script that reads top to bottom:

1. arguments;
2. the training env: ``racing_env.vec_env.HeadToHeadVecEnv`` (B races in one compiled step,
   the learner ``car_0`` against embedded opponents), ``VecMonitor`` (episode returns for
   SB3's ``ep_rew_mean``) and ``VecNormalize`` (observations and rewards scaled to unit
   variance: the raw observations mix metres, radians and metres per second, and their
   ``Box`` bounds are far too loose to normalise by); ``--off-track-penalty`` subtracts a
   reward on every step off track (the env itself keeps the paper's rule, which only slows
   the car);
3. the model and the loop, logging every finished episode: steps, return, distance driven
   and the share of steps off track (``curve.csv``);
4. the evaluation: deterministic actions on fresh races, the ``VecNormalize`` statistics
   frozen;
5. the checkpoint (``agents.ppo_agent.save_checkpoint``: model, normalisation and the race
   layout in one zip) and one race with ``ppo:checkpoint=...`` against two raceline followers.

Needs the ``learn`` extra (torch, stable-baselines3). A tiny run (about a minute):

    python examples/learn_ppo.py --steps 4096 --envs 4 --out results/learning/tiny

Then race the checkpoint from the command line:

    alpha-racer race --agents ppo:checkpoint=results/learning/tiny/model.zip raceline raceline
"""

from __future__ import annotations

import argparse
import csv
import json
import time
from pathlib import Path

import numpy as np


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=50_000, help="PPO env steps in all (default 50000)")
    p.add_argument("--envs", type=int, default=8, help="parallel races (default 8)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--opponents",
        nargs="*",
        default=None,
        help="opponent agent specs (default: two raceline followers, mu 0.75 and 0.8)",
    )
    p.add_argument(
        "--n-steps", type=int, default=256, help="PPO rollout length per env (default 256)"
    )
    p.add_argument("--eval-races", type=int, default=4, help="evaluation races (default 4)")
    p.add_argument(
        "--race-steps", type=int, default=500, help="steps of the final race (default 500 = 50 s)"
    )
    p.add_argument(
        "--off-track-penalty",
        type=float,
        default=0.0,
        help="metres of reward taken per step off track, in training only (default 0: the "
        "paper's rule, under which riding beyond the edge costs only speed)",
    )
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--out", type=Path, default=Path("results/learning/run"))
    return p.parse_args(argv)


def main(argv=None) -> dict:
    args = parse_args(argv)
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecEnvWrapper, VecMonitor, VecNormalize

    from agents.ppo_agent import save_checkpoint
    from experiments.evaluation.race import run_race
    from racing_env.vec_env import HeadToHeadVecEnv

    torch.set_num_threads(args.threads)
    args.out.mkdir(parents=True, exist_ok=True)

    # ------------------------------------------------------------------ the training env
    raw = HeadToHeadVecEnv(n_envs=args.envs, opponents=args.opponents)
    raw.seed(args.seed)
    venv = VecMonitor(raw)  # ep_rew_mean: the env's own reward

    class OffTrackPenalty(VecEnvWrapper):
        """Reward minus ``penalty`` [m] on every step a car ends off track (training only)."""

        def __init__(self, venv, penalty: float):
            super().__init__(venv)
            self.penalty = penalty

        def reset(self):
            return self.venv.reset()

        def step_wait(self):
            obs, rewards, dones, infos = self.venv.step_wait()
            rewards = rewards - self.penalty * np.array(
                [bool(i["off_track"]) for i in infos], np.float32
            )
            return obs, rewards, dones, infos

    if args.off_track_penalty:
        venv = OffTrackPenalty(venv, args.off_track_penalty)
    venv = VecNormalize(venv, norm_obs=True, norm_reward=True, gamma=0.99)

    # ------------------------------------------------------------------ logging: the curve
    class Curve(BaseCallback):
        """One row per finished episode: steps so far, return, metres driven, off-track share."""

        def _on_training_start(self) -> None:
            self.off = np.zeros(args.envs)
            self.length = np.zeros(args.envs)
            self.rows = []

        def _on_step(self) -> bool:
            for b, info in enumerate(self.locals["infos"]):
                self.off[b] += bool(info["off_track"])
                self.length[b] += 1
                if "episode" in info:  # VecMonitor: the episode ended
                    final = info  # at an episode end: the ended race
                    self.rows.append(
                        {
                            "steps": self.num_timesteps,
                            "return": info["episode"]["r"],
                            "distance_m": float(final["progress"]),
                            "off_track_share": self.off[b] / self.length[b],
                        }
                    )
                    self.off[b] = self.length[b] = 0
            return True

    curve = Curve()

    # ------------------------------------------------------------------ the model and the loop
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=args.n_steps,
        batch_size=min(256, args.n_steps * args.envs),
        n_epochs=5,
        learning_rate=5e-4,
        gamma=0.99,
        seed=args.seed,
        device="cpu",
        verbose=0,
    )
    t0 = time.time()
    model.learn(total_timesteps=args.steps, callback=curve)
    train_s = time.time() - t0
    with open(args.out / "curve.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, ["steps", "return", "distance_m", "off_track_share"])
        writer.writeheader()
        writer.writerows(curve.rows)

    # ------------------------------------------------------------------ evaluation
    eval_env = VecNormalize(
        VecMonitor(HeadToHeadVecEnv(n_envs=args.eval_races, opponents=args.opponents)),
        training=False,
        norm_reward=False,
    )
    eval_env.obs_rms = venv.obs_rms  # the training statistics, frozen
    eval_env.seed(10_000 + args.seed)
    obs = eval_env.reset()
    done = np.zeros(args.eval_races, bool)
    distance = np.zeros(args.eval_races)
    off = np.zeros(args.eval_races)
    length = np.zeros(args.eval_races)
    while not done.all():
        action, _ = model.predict(obs, deterministic=True)
        obs, _, dones, infos = eval_env.step(action)
        for b, info in enumerate(infos):
            if done[b]:
                continue
            final = info  # at an episode end: the ended race
            off[b] += bool(info["off_track"])
            length[b] += 1
            distance[b] = final["progress"]
            done[b] |= bool(dones[b])
    evaluation = {
        "distance_m": float(distance.mean()),
        "off_track_share": float(off.sum() / length.sum()),
    }

    # ------------------------------------------------------------------ checkpoint and race
    n_cars = 1 + len(raw.opponents)  # observations: 6 N + n_preview
    n_preview = venv.observation_space.shape[0] - 6 * n_cars
    path = save_checkpoint(
        model,
        venv,
        args.out / "model.zip",
        {
            "n_cars": n_cars,
            "n_preview": n_preview,
            "source": "examples/learn_ppo.py",
            "steps": args.steps,
            "seed": args.seed,
        },
    )
    result, _ = run_race(
        [f"ppo:checkpoint={path}", "raceline", "raceline"],
        seed=args.seed,
        max_cycles=args.race_steps,
        progress_bar=False,
    )
    print(result.table())
    report = {
        "steps": args.steps,
        "envs": args.envs,
        "seed": args.seed,
        "train_s": round(train_s, 1),
        "off_track_penalty": args.off_track_penalty,
        "evaluation": evaluation,
        "race_order": [int(i) for i in result.order],
        "race_progress_m": [round(float(p), 2) for p in result.progress],
        "checkpoint": str(path),
    }
    (args.out / "report.json").write_text(json.dumps(report, indent=2))
    print(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
