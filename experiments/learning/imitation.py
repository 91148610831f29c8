"""Behaviour cloning (DAgger) of the raceline follower into a PPO actor: the ``init="bc"``
start of a self-play run (:mod:`experiments.learning.selfplay`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from experiments.learning.config import SelfPlayConfig

if TYPE_CHECKING:
    from racing_env import RaceConfig


def behaviour_cloning(
    model, cfg: SelfPlayConfig, seed: int, race_config: RaceConfig, opponent_mus: Sequence[float]
) -> dict:
    """``init="bc"``: pretrain the PPO actor to imitate the raceline follower (DAgger).

    ``model`` an SB3 ``PPO`` with a ``VecNormalize`` env, ``cfg`` the run's
    :class:`~experiments.learning.config.SelfPlayConfig` (``n_envs``, ``n_cars``, ``track``,
    ``batch_size`` and the ``bc_*`` fields), ``race_config`` the learning env's
    :class:`~racing_env.RaceConfig`, ``opponent_mus`` the envelope scales of the
    raceline-follower opponents by slot (cycled).

    Round 0 collects ``bc_steps`` learner steps in the learning env (raceline-follower
    opponents) with the learner driven by a raceline follower (friction 0.85) whose actions
    are perturbed by Gaussian noise of std ``bc_noise``; rounds 1 .. ``bc_rounds - 1`` let the
    cloned policy drive (same noise) so the data holds the states it gets itself into. Every
    step is labelled with the follower's action for that state. ``bc_alone`` of the
    ``n_envs`` races (:func:`alone_envs`; none for the ORCA class, half at full size) have the
    learner alone on the track, its observations in the layout of ``n_cars`` cars with the
    others as the phantoms half a lap behind that a race alone shows the policy
    (:func:`agents.observations.adapt_observation`, as in the solo evaluation): on a
    full-scale circuit no race with the others comes near those progress differences. After
    each round the model's ``VecNormalize`` observation statistics are updated and the actor
    (policy MLP + action head) is fitted to all data so far by mean squared error for
    ``bc_epochs`` epochs (Adam, lr 1e-3, batch ``batch_size``). The critic stays as
    initialised; the action log-std is set to ``bc_log_std``. Returns the number of samples
    and the final fit error.
    """
    import torch

    from agents.ppo_agent import FrozenPolicy
    from racing_env.controllers import RacelineFollower
    from racing_env.vec_env import HeadToHeadVecEnv

    rng = np.random.default_rng(seed)
    opps = [
        RacelineFollower(grip=opponent_mus[k % len(opponent_mus)]) for k in range(cfg.n_cars - 1)
    ]
    n_alone = alone_envs(cfg)
    n_main = cfg.n_envs - n_alone
    envs = []  # (env, its observations in the learner's layout)
    if n_main:
        env = HeadToHeadVecEnv(n_main, opponents=opps, track=cfg.track, config=race_config)
        env.seed(int(rng.integers(2**31)))
        envs.append((env, None))
    if n_alone:
        solo = HeadToHeadVecEnv(
            n_alone, opponents=[], track=cfg.track, config=race_config.with_(n_cars=1)
        )
        solo.seed(int(rng.integers(2**31)))
        envs.append((solo, _alone_view(cfg.n_cars, race_config.n_preview, solo.track.length)))
    track = envs[0][0].track
    expert = RacelineFollower(grip=0.85)
    expert.reset(track, "car_0")
    vecnorm = model.get_vec_normalize_env()
    policy = model.policy
    params = list(policy.mlp_extractor.policy_net.parameters()) + list(
        policy.action_net.parameters()
    )
    opt = torch.optim.Adam(params, lr=1e-3)
    gen = torch.Generator().manual_seed(seed)

    def actor(xb):
        return policy.action_net(
            policy.mlp_extractor.forward_actor(
                policy.extract_features(xb, policy.pi_features_extractor)
            )
        )

    xs, ys = [], []
    obs = _reset(envs)
    for rnd in range(cfg.bc_rounds):
        driver = (
            None
            if rnd == 0
            else FrozenPolicy(policy, vecnorm, n_cars=cfg.n_cars, n_preview=race_config.n_preview)
        )
        for _ in range(math.ceil(cfg.bc_steps / cfg.n_envs)):
            target = np.array([expert.act(o) for o in obs], dtype=np.float32)
            xs.append(obs)
            ys.append(target)
            act = target if driver is None else driver.act_batch(obs)
            act = np.clip(act + rng.normal(0.0, cfg.bc_noise, act.shape), -1.0, 1.0)
            obs = _step(envs, act.astype(np.float32))
        x, y = np.concatenate(xs), np.concatenate(ys)
        vecnorm.obs_rms.update(np.concatenate(xs[-math.ceil(cfg.bc_steps / cfg.n_envs) :]))
        xn = torch.as_tensor(vecnorm.normalize_obs(x), dtype=torch.float32)
        yt = torch.as_tensor(y)
        policy.set_training_mode(True)
        for _ in range(cfg.bc_epochs):
            perm = torch.randperm(len(xn), generator=gen)
            for i in range(0, len(xn), cfg.batch_size):
                idx = perm[i : i + cfg.batch_size]
                loss = torch.mean((actor(xn[idx]) - yt[idx]) ** 2)
                opt.zero_grad()
                loss.backward()
                opt.step()
        policy.set_training_mode(False)
    with torch.no_grad():
        final = float(torch.mean((torch.clamp(actor(xn), -1, 1) - yt) ** 2))
        policy.log_std.fill_(cfg.bc_log_std)
    return {"samples": int(len(xn)), "rounds": cfg.bc_rounds, "mse": final}


def alone_envs(cfg: SelfPlayConfig) -> int:
    """How many of the ``n_envs`` behaviour-cloning races the learner drives alone:
    ``bc_alone`` of them, rounded (0 for the ORCA class by default)."""
    return min(cfg.n_envs, int(round((cfg.bc_alone or 0.0) * cfg.n_envs)))


def _alone_view(n_cars: int, n_preview: int, track_length: float):
    """The observations of a race alone in the layout of ``n_cars`` cars, as the policy sees
    them racing alone (:func:`agents.observations.adapt_observation`: the missing cars are
    phantoms half a lap behind)."""
    from agents.observations import adapt_observation

    return lambda obs: adapt_observation(obs, n_cars, n_preview, track_length)


def _reset(envs) -> np.ndarray:
    return np.concatenate(
        [env.reset() if view is None else view(env.reset()) for env, view in envs]
    )


def _step(envs, act: np.ndarray) -> np.ndarray:
    out, i = [], 0
    for env, view in envs:
        obs, _, _, _ = env.step(act[i : i + env.num_envs])
        out.append(obs if view is None else view(obs))
        i += env.num_envs
    return np.concatenate(out)
