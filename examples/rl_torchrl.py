"""TorchRL on the PettingZoo env: multi-agent PPO (shared actor, centralised critic).

``PettingZooWrapper`` groups the cars as ``"car"`` (observations ``(3, 28)`` per step); the
rest follows TorchRL's multi-agent PPO tutorial: a ``MultiAgentMLP`` actor with a tanh-normal
head, a ``MultiAgentMLP`` critic that sees every car (``centralised=True``), GAE and
``ClipPPOLoss``. Needs ``pip install torchrl`` (the ``rl`` extra).

    python examples/rl_torchrl.py [ITERATIONS]
"""

import sys

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule

try:
    from torchrl.collectors import Collector  # torchrl >= 0.14
except ImportError:
    from torchrl.collectors import SyncDataCollector as Collector  # older releases
from torchrl.envs import RewardSum, TransformedEnv
from torchrl.envs.libs.pettingzoo import PettingZooWrapper
from torchrl.envs.utils import check_env_specs
from torchrl.modules import MultiAgentMLP, ProbabilisticActor, TanhNormal
from torchrl.objectives import ClipPPOLoss, ValueEstimators

import racing_env

N_CARS, FRAMES = 3, 400


def main(iterations: int = 2) -> list[float]:
    torch.manual_seed(0)
    env = PettingZooWrapper(
        env=racing_env.parallel_env(n_cars=N_CARS, max_cycles=200),
        use_mask=False,
        return_state=False,
        seed=0,
    )
    env = TransformedEnv(
        env, RewardSum(in_keys=[("car", "reward")], out_keys=[("car", "episode_reward")])
    )
    check_env_specs(env)
    n_obs = env.observation_spec["car", "observation"].shape[-1]
    n_act = env.full_action_spec["car", "action"].shape[-1]

    def mlp(n_outputs: int, centralised: bool):
        """One network shared by the cars (two hidden layers of 64, tanh); ``centralised``: it
        sees every car's observation."""
        return MultiAgentMLP(
            n_agent_inputs=n_obs,
            n_agent_outputs=n_outputs,
            n_agents=N_CARS,
            centralised=centralised,
            share_params=True,
            depth=2,
            num_cells=64,
            activation_class=torch.nn.Tanh,
        )

    actor_net = torch.nn.Sequential(mlp(2 * n_act, centralised=False), NormalParamExtractor())
    actor = ProbabilisticActor(
        TensorDictModule(
            actor_net, in_keys=[("car", "observation")], out_keys=[("car", "loc"), ("car", "scale")]
        ),
        spec=env.full_action_spec["car", "action"],
        in_keys=[("car", "loc"), ("car", "scale")],
        out_keys=[("car", "action")],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0},
        return_log_prob=True,
    )
    critic = TensorDictModule(
        mlp(1, centralised=True),
        in_keys=[("car", "observation")],
        out_keys=[("car", "state_value")],
    )

    collector = Collector(env, actor, frames_per_batch=FRAMES, total_frames=FRAMES * iterations)
    loss = ClipPPOLoss(
        actor_network=actor, critic_network=critic, clip_epsilon=0.2, entropy_coeff=1e-3
    )
    loss.set_keys(
        reward=("car", "reward"),
        action=("car", "action"),
        value=("car", "state_value"),
        done=("car", "done"),
        terminated=("car", "terminated"),
    )
    loss.make_value_estimator(ValueEstimators.GAE, gamma=0.99, lmbda=0.95)
    optim = torch.optim.Adam(loss.parameters(), lr=3e-4)

    mean_rewards = []
    for i, batch in enumerate(collector):
        with torch.no_grad():
            loss.value_estimator(
                batch,
                params=loss.critic_network_params,
                target_params=loss.target_critic_network_params,
            )  # noqa: E501
        for _ in range(4):  # epochs over the batch
            terms = loss(batch)
            total = terms["loss_objective"] + terms["loss_critic"] + terms["loss_entropy"]
            optim.zero_grad()
            total.backward()
            torch.nn.utils.clip_grad_norm_(loss.parameters(), 1.0)
            optim.step()
        collector.update_policy_weights_()
        mean_rewards.append(float(batch.get(("next", "car", "reward")).mean()))
        print(
            f"iteration {i + 1}: {batch.numel()} steps, mean reward per car-step {mean_rewards[-1]:+.4f}"
        )
    collector.shutdown()
    return mean_rewards


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
