"""The env observation's layout, read back into Frenet states: ``6 N + n_preview`` values, the
observing car's state ``(s, n, mu, vx, vy, omega)`` first, then every other car's state minus
it, then the curvature preview (:class:`racing_env.config.RaceConfig` ``n_preview``)."""

from __future__ import annotations

import numpy as np


def joint_state_from_observation(obs: np.ndarray, n_cars: int) -> tuple[np.ndarray, np.ndarray]:
    """(ego (6,), others (N-1, 6)) Frenet states from an env observation.

    The ego's ``s`` is its wrapped arc length; the others' are ego ``s`` plus their unwrapped
    progress difference, so every longitudinal difference stays on unwrapped progress.
    """
    ego = np.asarray(obs[:6], dtype=float)
    rel = np.asarray(obs[6 : 6 * n_cars], dtype=float).reshape(n_cars - 1, 6)
    others = rel + ego[None, :]
    others[:, 2] = np.angle(np.exp(1j * others[:, 2]))
    return ego, others


def cars_in_observation(length: int, n_preview: int) -> int:
    """The number of cars N of an observation of ``length`` values with a curvature preview of
    ``n_preview``; ``ValueError`` when the length does not fit ``6 N + n_preview``, N >= 1."""
    n_cars, rest = divmod(length - n_preview, 6)
    if rest or n_cars < 1:
        raise ValueError(
            f"observation of length {length} does not fit 6 N + n_preview "
            f"with n_preview = {n_preview}"
        )
    return n_cars


def split_observation(observation: np.ndarray, n_preview: int) -> tuple[np.ndarray, np.ndarray]:
    """(ego (6,), others (N-1, 6)) from an env observation whose curvature preview has
    ``n_preview`` entries; ``ValueError`` when the length does not fit ``6 N + n_preview``."""
    obs = np.asarray(observation, dtype=float)
    return joint_state_from_observation(obs, cars_in_observation(len(obs), n_preview))
