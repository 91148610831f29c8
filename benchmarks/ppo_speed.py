"""PPO self-play training throughput (env steps per second) by vectorised-env backend.

    python benchmarks/ppo_speed.py            # a few minutes
    python benchmarks/ppo_speed.py --quick    # about a minute, for a smoke check

Setting: the paper's PPO (8 parallel races, rollouts of 2048 steps per race, batch 1024,
5 epochs) for a learner racing two frozen PPO opponents (the situation of every self-play
turn after the first cycle). Two figures per backend: the env alone (learner actions random,
opponents acting) and whole ``PPO.learn`` (rollouts + policy updates), in env steps per
second of wall time and, for the single-process backends, per second of this process's CPU
time (the figure that holds on a shared, busy machine).

Backends:

* ``dummy+predict`` (the named baseline): SB3 ``DummyVecEnv`` over the registered Gymnasium
  env ``alpha_racer/HeadToHead-v2``, opponents calling SB3 ``policy.predict`` per race;
* ``dummy+numpy``: the same env, opponents as :class:`agents.ppo_agent.FrozenPolicy` (numpy
  actor) per race;
* ``subproc+numpy``: SB3 ``SubprocVecEnv`` (2 worker processes, one per core) of the same;
* ``batched``: :class:`racing_env.vec_env.HeadToHeadVecEnv`, all races in one compiled step,
  each opponent one numpy call for all races (what ``alpha-racer selfplay`` uses).

Measured on the 2-core development machine while other jobs ran (``--quick``), per CPU second:
env alone 649 (dummy+predict), 4,032 (dummy+numpy), 16,246 (batched) steps; ``PPO.learn`` 529,
2,736 and 3,517 steps, so the batched env trains 6.6x faster than the baseline and 1.3x faster
than the same DummyVecEnv with numpy opponents. SubprocVecEnv (2 workers) reached 1,348
``PPO.learn`` steps per wall second on the busy machine, below the single-process backends.
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np
import torch

N_ENVS = 8


class PredictOpponent:
    """A frozen PPO opponent the plain way: VecNormalize statistics + ``policy.predict``."""

    def __init__(self, policy, vecnorm):
        self.policy, self.vecnorm = policy, vecnorm

    def reset(self, track, agent_id, seed=None):
        pass

    def act(self, obs):
        a, _ = self.policy.predict(self.vecnorm.normalize_obs(obs[None]), deterministic=True)
        return a[0]


def make_opponent_policy():
    """A PPO policy + VecNormalize with the right spaces (weights untrained: speed only)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecNormalize

    from racing_env.vec_env import HeadToHeadVecEnv

    venv = VecNormalize(HeadToHeadVecEnv(1))
    model = PPO("MlpPolicy", venv, device="cpu", seed=0)
    venv.obs_rms.var[:] = 4.0
    return model.policy, venv


def make_venv(backend: str, policy, vecnorm):
    import gymnasium as gym
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    from agents.ppo_agent import FrozenPolicy
    from racing_env.registration import ENV_ID
    from racing_env.vec_env import HeadToHeadVecEnv

    if backend == "batched":
        opps = [FrozenPolicy(policy, vecnorm, n_cars=3) for _ in range(2)]
        venv = HeadToHeadVecEnv(N_ENVS, opponents=opps)
    else:
        if backend == "dummy+predict":
            opps = [PredictOpponent(policy, vecnorm) for _ in range(2)]
        else:
            opps = [FrozenPolicy(policy, vecnorm, n_cars=3) for _ in range(2)]
        fns = [(lambda o=copy.deepcopy(opps): gym.make(ENV_ID, opponents=o)) for _ in range(N_ENVS)]
        if backend.startswith("subproc"):
            venv = SubprocVecEnv(fns, start_method="fork")
        else:
            venv = DummyVecEnv(fns)
    venv.seed(0)
    return venv


def bench_env(venv, steps: int) -> tuple[float, float]:
    """(steps per wall second, steps per CPU second of this process)."""
    venv.reset()
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (steps, N_ENVS, 2)).astype(np.float32)
    acts[..., 0] = np.abs(acts[..., 0])
    for a in acts[:20]:
        venv.step(a)
    t0, c0 = time.perf_counter(), time.process_time()
    for a in acts:
        venv.step(a)
    n = steps * N_ENVS
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def bench_learn(venv, rollouts: int) -> float:
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    env = VecNormalize(VecMonitor(venv))
    model = PPO(
        "MlpPolicy",
        env,
        learning_rate=5e-4,
        n_steps=2048,
        batch_size=1024,
        n_epochs=5,
        gamma=0.99,
        device="cpu",
        seed=0,
    )
    model.learn(2048 * N_ENVS)  # warm-up rollout + update
    t0, c0 = time.perf_counter(), time.process_time()
    model.learn(rollouts * 2048 * N_ENVS, reset_num_timesteps=False)
    n = rollouts * 2048 * N_ENVS
    return n / (time.perf_counter() - t0), n / (time.process_time() - c0)


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--backends",
        nargs="+",
        default=["dummy+predict", "dummy+numpy", "subproc+numpy", "batched"],
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    env_steps, rollouts = (300, 1) if args.quick else (1500, 3)
    policy, vecnorm = make_opponent_policy()
    rows = []
    print(
        f"{'backend':<15} {'env steps/s':>12} {'per CPU s':>10}   {'PPO.learn steps/s':>17} {'per CPU s':>10}"
    )
    for backend in args.backends:
        venv = make_venv(backend, policy, vecnorm)
        env_rate = bench_env(venv, env_steps)
        learn_rate = bench_learn(venv, rollouts)
        venv.close()
        rows.append((backend, env_rate, learn_rate))
        cpu_ok = not backend.startswith("subproc")  # workers' CPU time is not this process's
        fmt = lambda r: f"{r:10.0f}" if cpu_ok else f"{'-':>10}"  # noqa: B023
        print(
            f"{backend:<15} {env_rate[0]:12.0f} {fmt(env_rate[1])}   {learn_rate[0]:17.0f} {fmt(learn_rate[1])}",
            flush=True,
        )
    base = {r[0]: r for r in rows}.get("dummy+predict")
    if base:
        print(
            "\nspeed-up over dummy+predict (SB3 DummyVecEnv over the Gymnasium env), by CPU time "
            "(subproc: by wall time):"
        )
        for name, e, l in rows:
            k = 0 if name.startswith("subproc") else 1
            print(f"{name:<15} env x{e[k] / base[1][k]:5.1f}   PPO.learn x{l[k] / base[2][k]:5.1f}")


if __name__ == "__main__":
    main()
