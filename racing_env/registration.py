"""Registers the Gymnasium envs ``alpha_racer/HeadToHead-v2`` and ``alpha_racer/FullSize-v0``
(the same game with full-size cars on Monza and the wake; :class:`racing_env.gym_env.FullSizeEnv`)
(idempotent).

``gymnasium.make`` builds :class:`racing_env.gym_env.HeadToHeadEnv` wrapped in ``TimeLimit(500)``,
which truncates at the same step as the env itself (``max_cycles`` = 500 by default), so the
wrapper changes nothing; pass ``max_episode_steps`` to ``make`` with ``max_cycles`` to race
longer. ``gymnasium.make_vec`` builds :class:`racing_env.gym_vector.HeadToHeadVectorEnv` (one
batched core for all envs) unless ``vectorization_mode="sync"`` / ``"async"`` is asked for.

``HeadToHead-v1`` (contact slowed cars but did not keep them apart) and ``HeadToHead-v0``
(contact checked only at the end of each 0.1 s step) are no longer registered: their
behaviour is not kept; see Version History in ``HeadToHeadEnv``.
"""

import gymnasium

ENV_ID = "alpha_racer/HeadToHead-v2"
MAX_EPISODE_STEPS = 500
"""The registered ``spec.max_episode_steps``: :class:`racing_env.RaceConfig`'s ``max_cycles``."""

FULLSIZE_ENV_ID = "alpha_racer/FullSize-v0"
"""Full-size cars on Monza with the wake (:class:`racing_env.gym_env.FullSizeEnv`)."""

if FULLSIZE_ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=FULLSIZE_ENV_ID,
        entry_point="racing_env.gym_env:FullSizeEnv",
        vector_entry_point="racing_env.gym_vector:HeadToHeadVectorEnv",
        max_episode_steps=MAX_EPISODE_STEPS,
        kwargs={"vehicle_class": "fullsize", "track": "tumftm:Monza"},
    )

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="racing_env.gym_env:HeadToHeadEnv",
        vector_entry_point="racing_env.gym_vector:HeadToHeadVectorEnv",
        max_episode_steps=MAX_EPISODE_STEPS,
    )
