"""RLlib multi-agent PPO on the PettingZoo env: every car its own policy, or one shared.

RLlib wraps a PettingZoo ``ParallelEnv`` with ``ParallelPettingZooEnv``; ``policy_mapping_fn``
maps each car to a policy (here one policy per car: independent learners; map every car to
one id for parameter sharing). RLlib pins its own Gymnasium version: install it in an
environment of its own (``pip install "ray[rllib]"`` next to this package).

    python examples/rl_rllib.py [ITERATIONS]
"""

import sys

import ray
from ray.rllib.algorithms.ppo import PPOConfig
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.tune.registry import register_env

import racing_env

N_CARS = 3


def make_env(config: dict):
    return ParallelPettingZooEnv(
        racing_env.parallel_env(
            n_cars=N_CARS,
            track=config.get("track", "default"),
            max_cycles=config.get("max_cycles", 200),
        )
    )


def main(iterations: int = 1) -> dict:
    register_env("alpha_racer", make_env)
    agents = [f"car_{i}" for i in range(N_CARS)]
    config = (
        PPOConfig()
        .environment("alpha_racer", env_config={"track": "default", "max_cycles": 200})
        .multi_agent(
            policies=set(agents), policy_mapping_fn=lambda agent_id, episode, **kw: agent_id
        )
        .env_runners(num_env_runners=0, rollout_fragment_length=200)
        .training(train_batch_size_per_learner=400, minibatch_size=200, num_epochs=2, lr=5e-4)
        .debugging(seed=0)
    )
    ray.init(num_cpus=1, include_dashboard=False, ignore_reinit_error=True, log_to_driver=False)
    try:
        algo = config.build_algo()
        for i in range(iterations):
            result = algo.train()
            returns = result["env_runners"].get("agent_episode_returns_mean", {})
            print(
                f"iteration {i + 1}: env steps {result['env_runners']['num_env_steps_sampled_lifetime']}, "
                f"returns per car {returns}"
            )
        algo.stop()
        return result
    finally:
        ray.shutdown()


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 1)
