"""CleanRL-style PPO on the PettingZoo env: one file, top to bottom, torch only.

Every car of the race is a learner sharing one actor-critic (parameter sharing, as CleanRL's
PettingZoo PPO does): a step of the ``ParallelEnv`` gives N samples. Observations are scaled by
a running mean and variance (the raw ones mix metres, radians and metres per second).
Needs torch (the ``learn`` extra).

    python examples/cleanrl_ppo.py --total-steps 20000
"""

import argparse
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn as nn
from torch.distributions import Normal

import racing_env


# ---------------------------------------------------------------------- arguments
@dataclass
class Args:
    total_steps: int = 20_000  # race steps (each gives n_cars samples)
    n_cars: int = 3
    track: str = "default"
    max_cycles: int = 500
    rollout: int = 256  # race steps per update
    epochs: int = 4
    minibatch: int = 256
    lr: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    seed: int = 0


def parse_args(argv=None) -> Args:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    for name, value in vars(Args()).items():
        p.add_argument("--" + name.replace("_", "-"), type=type(value), default=value)
    return Args(**vars(p.parse_args(argv)))


# ---------------------------------------------------------------------- the model
class Agent(nn.Module):
    def __init__(self, n_obs: int, n_act: int):
        super().__init__()

        def mlp(out, std):
            layers = [
                nn.Linear(n_obs, 64),
                nn.Tanh(),
                nn.Linear(64, 64),
                nn.Tanh(),
                nn.Linear(64, out),
            ]
            nn.init.orthogonal_(layers[-1].weight, std)
            return nn.Sequential(*layers)

        self.critic, self.actor_mean = mlp(1, 1.0), mlp(n_act, 0.01)
        self.actor_logstd = nn.Parameter(torch.full((n_act,), -0.5))

    def value(self, x):
        return self.critic(x).squeeze(-1)

    def act(self, x, action=None):
        dist = Normal(self.actor_mean(x), self.actor_logstd.exp())
        if action is None:
            action = dist.sample()
        return action, dist.log_prob(action).sum(-1), dist.entropy().sum(-1), self.value(x)


class RunningNorm:
    def __init__(self, dim):
        self.mean, self.var, self.count = np.zeros(dim), np.ones(dim), 1e-4

    def __call__(self, x, update=True):
        if update:
            m, v, n = x.mean(0), x.var(0), len(x)
            delta, total = m - self.mean, self.count + n
            self.mean = self.mean + delta * n / total
            self.var = (self.var * self.count + v * n + delta**2 * self.count * n / total) / total
            self.count = total
        return np.clip((x - self.mean) / np.sqrt(self.var + 1e-8), -10, 10).astype(np.float32)


def main(argv=None) -> list[float]:
    args = parse_args(argv)
    torch.manual_seed(args.seed)

    # ------------------------------------------------------------------ the env
    env = racing_env.parallel_env(n_cars=args.n_cars, track=args.track, max_cycles=args.max_cycles)
    cars = env.possible_agents
    n_obs, n_act = env.observation_space(cars[0]).shape[0], env.action_space(cars[0]).shape[0]
    obs_dict, _ = env.reset(seed=args.seed)
    norm = RunningNorm(n_obs)
    obs = norm(np.stack([obs_dict[a] for a in cars]))

    agent = Agent(n_obs, n_act)
    optim = torch.optim.Adam(agent.parameters(), lr=args.lr, eps=1e-5)
    T, N = args.rollout, args.n_cars
    buf_obs = torch.zeros(T, N, n_obs)
    buf_act, buf_logp = torch.zeros(T, N, n_act), torch.zeros(T, N)
    buf_rew, buf_done, buf_val = torch.zeros(T, N), torch.zeros(T, N), torch.zeros(T, N)

    # ------------------------------------------------------------------ the loop
    episode_progress, steps, races = [], 0, 0
    while steps < args.total_steps:
        for t in range(T):
            buf_obs[t] = torch.as_tensor(obs)
            with torch.no_grad():
                action, logp, _, value = agent.act(buf_obs[t])
            buf_act[t], buf_logp[t], buf_val[t] = action, logp, value
            clipped = action.clamp(-1, 1).numpy()
            obs_dict, rewards, terms, truncs, infos = env.step(
                {a: clipped[i] for i, a in enumerate(cars)}
            )
            buf_rew[t] = torch.tensor([rewards[a] for a in cars], dtype=torch.float32)
            done = any(terms.values()) or any(truncs.values())
            buf_done[t] = float(done)
            if done:
                episode_progress.append(float(np.mean([infos[a]["progress"] for a in cars])))
                races += 1
                obs_dict, _ = env.reset(seed=args.seed + races)
            obs = norm(np.stack([obs_dict[a] for a in cars]))
            steps += 1

        # GAE over the rollout, per car
        with torch.no_grad():
            next_value = agent.value(torch.as_tensor(obs))
            adv, last = torch.zeros(T, N), torch.zeros(N)
            for t in reversed(range(T)):
                nv = next_value if t == T - 1 else buf_val[t + 1]
                nonterminal = 1.0 - buf_done[t]
                delta = buf_rew[t] + args.gamma * nv * nonterminal - buf_val[t]
                last = delta + args.gamma * args.gae_lambda * nonterminal * last
                adv[t] = last
            returns = adv + buf_val

        # PPO update on T * N samples
        b_obs, b_act, b_logp = (
            buf_obs.reshape(-1, n_obs),
            buf_act.reshape(-1, n_act),
            buf_logp.reshape(-1),
        )
        b_adv, b_ret = adv.reshape(-1), returns.reshape(-1)
        for _ in range(args.epochs):
            for idx in torch.randperm(T * N).split(args.minibatch):
                _, logp, entropy, value = agent.act(b_obs[idx], b_act[idx])
                ratio = (logp - b_logp[idx]).exp()
                a = (b_adv[idx] - b_adv[idx].mean()) / (b_adv[idx].std() + 1e-8)
                pg_loss = torch.max(
                    -a * ratio, -a * ratio.clamp(1 - args.clip, 1 + args.clip)
                ).mean()
                v_loss = 0.5 * ((value - b_ret[idx]) ** 2).mean()
                loss = pg_loss + args.vf_coef * v_loss - args.ent_coef * entropy.mean()
                optim.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), 0.5)
                optim.step()

        # ------------------------------------------------------------------ logging
        recent = np.mean(episode_progress[-5:]) if episode_progress else float("nan")
        print(
            f"steps {steps:7d}  races {races:4d}  mean progress of the last races {recent:7.2f} m  "
            f"loss {loss.item():+.4f}"
        )
    env.close()
    return episode_progress


if __name__ == "__main__":
    main()
