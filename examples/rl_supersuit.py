"""SuperSuit + stable-baselines3 on the PettingZoo env: one PPO policy shared by every car.

SuperSuit turns the ``ParallelEnv`` into a vector env with one slot per car
(``pettingzoo_env_to_vec_env_v1``) and stacks copies of it for SB3
(``concat_vec_envs_v1``): every car of every race is a sample of the same policy
(parameter sharing). Needs ``pip install supersuit`` (the ``rl`` extra) and the ``learn`` extra.

    python examples/rl_supersuit.py [STEPS]
"""

import sys

import supersuit as ss
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

import racing_env


def main(steps: int = 2048) -> PPO:
    env = racing_env.parallel_env(n_cars=3, track="default", max_cycles=500)
    venv = ss.pettingzoo_env_to_vec_env_v1(env)  # 3 slots: car_0, car_1, car_2
    venv = ss.concat_vec_envs_v1(venv, 2, num_cpus=0, base_class="stable_baselines3")  # 2 races
    venv = VecNormalize(VecMonitor(venv), norm_obs=True, norm_reward=True)
    # no seed= here: SB3 would call venv.seed(), which SuperSuit's vector env lacks
    model = PPO(
        "MlpPolicy",
        venv,
        n_steps=256,
        batch_size=256,
        n_epochs=5,
        learning_rate=5e-4,
        device="cpu",
        verbose=0,
    )
    model.learn(total_timesteps=steps)
    print(f"trained {model.num_timesteps} car-steps over {venv.num_envs} cars")
    return model


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2048)
