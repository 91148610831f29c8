"""The races a self-play run learns in and is measured on: the learner's vectorised env,
the frozen opponents, and the solo evaluation (the car alone on the track, beside the MPC).
Every race is of the run's vehicle class and wake
(:func:`~experiments.learning.config.race_config`; the raceline followers and the MPC take
the class from the track)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from experiments.learning.config import RACELINE_GRIP, SelfPlayConfig, SelfPlayState, race_config


def make_learning_env(cfg: SelfPlayConfig, opponents: list, seed: int):
    """The learner's vectorised env (before VecMonitor / VecNormalize), seeded; its races are
    :func:`~experiments.learning.config.race_config`'s (the run's class and wake)."""
    import copy

    if cfg.vec_env == "batched":
        from racing_env.vec_env import HeadToHeadVecEnv

        venv = HeadToHeadVecEnv(
            cfg.n_envs, opponents=opponents, track=cfg.track, config=race_config(cfg)
        )
    else:
        import gymnasium as gym
        from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

        import racing_env  # noqa: F401  registers the env
        from racing_env.registration import ENV_ID

        def make():
            opps = [copy.deepcopy(o) for o in opponents]
            return lambda: gym.make(
                ENV_ID,
                max_episode_steps=cfg.max_cycles,
                opponents=opps,
                track=cfg.track,
                config=race_config(cfg),
            )

        fns = [make() for _ in range(cfg.n_envs)]
        venv = (
            DummyVecEnv(fns) if cfg.vec_env == "dummy" else SubprocVecEnv(fns, start_method="fork")
        )
    venv.seed(seed)
    return venv


def frozen_policy(path):
    """The policy of a checkpoint as a batched agent (:class:`agents.ppo_agent.FrozenPolicy`)."""
    from agents.ppo_agent import PPOAgent

    return PPOAgent(checkpoint=path)


def live_policy(model, cfg: SelfPlayConfig):
    """The policy being trained, as a :class:`agents.ppo_agent.FrozenPolicy` with its current
    weights and observation statistics (what a checkpoint saved now would race)."""
    from agents.ppo_agent import FrozenPolicy

    return FrozenPolicy(
        model.policy,
        model.get_vec_normalize_env(),
        n_cars=cfg.n_cars,
        n_preview=race_config(cfg).n_preview,
    )


def make_opponents(
    cfg: SelfPlayConfig, out: Path, state: SelfPlayState, car: int
) -> tuple[list, list[str]]:
    from racing_env.controllers import RacelineFollower

    opps, names = [], []
    for slot, k in enumerate(j for j in range(cfg.n_cars) if j != car):
        if state.trained_turns[k] == 0 and cfg.warmup_opponent == "raceline":
            grip = RACELINE_GRIP[slot % len(RACELINE_GRIP)]
            opps.append(RacelineFollower(grip=grip))
            names.append(f"raceline:grip={grip}")
        else:
            opps.append(frozen_policy(out / state.cars[k]))
            names.append(f"car_{k}@{state.trained_turns[k]}turns")
    return opps, names


def evaluate_solo(agent, cfg: SelfPlayConfig, races: int | None = None) -> dict:
    """The agent alone on the track for ``max_cycles`` steps from ``races`` fixed starts
    (seeds 0..races-1), in the run's vehicle class and wake: mean distance [m] and fraction
    of steps off track."""
    from racing_env import RacingParallelEnv

    races = races or cfg.eval_races
    env = RacingParallelEnv(
        track=cfg.track,
        n_cars=1,
        max_cycles=cfg.max_cycles,
        start=cfg.start,
        vehicle_class=cfg.vehicle_class,
        wake=cfg.wake,
    )
    dist, off = [], []
    for seed in range(races):
        obs, _ = env.reset(seed=seed)
        agent.reset(env.track, "car_0", seed)
        while env.agents:
            obs, *_ = env.step({"car_0": agent.act(obs["car_0"])})
        dist.append(float(env.core.progress()[0, 0]))
        off.append(float(env.core.offtracks[0, 0]) / cfg.max_cycles)
    return {
        "distance_m": float(np.mean(dist)),
        "off_track_frac": float(np.mean(off)),
        "distance_per_race": dist,
    }


def mpc_reference(cfg: SelfPlayConfig) -> dict:
    """The fixed-parameter MPC agent (``mpc``) alone, as :func:`evaluate_solo` measures."""
    from agents.mpc_agent import MPCAgent

    return evaluate_solo(MPCAgent(), cfg)
