"""Registers the Gymnasium env ``alpha_racer/HeadToHead-v0`` (idempotent)."""
import gymnasium

ENV_ID = "alpha_racer/HeadToHead-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="racing_env.gym_env:HeadToHeadEnv",
                       max_episode_steps=None)
