"""Simple agents: the raceline follower, and random / constant drivers for tests and benchmarks."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from racing_env.controllers import RacelineFollower

from .base import register_agent

if TYPE_CHECKING:
    from racing_env.track import Track

register_agent("raceline", RacelineFollower)


@register_agent("random")
class RandomAgent:
    """Uniformly random actions in [-1, 1]^2 (seeded by reset): the env's normalised action
    space, the same in every vehicle class (the env maps it onto the class's throttle and
    steering bounds)."""

    def __init__(self):
        self.rng = np.random.default_rng()

    def reset(self, track: Track | str, agent_id: str, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, 2).astype(np.float32)


@register_agent("constant")
class ConstantAgent:
    """The same action every step (default: half throttle, straight), in the env's normalised
    action space: the same in every vehicle class."""

    param_bounds = {"throttle": (-1.0, 1.0), "steering": (-1.0, 1.0)}

    def __init__(self, throttle: float = 0.5, steering: float = 0.0):
        if not (-1 <= throttle <= 1 and -1 <= steering <= 1):
            raise ValueError(
                f"throttle and steering must be in [-1, 1], got {throttle}, {steering}"
            )
        self.action = np.array([throttle, steering], dtype=np.float32)

    def reset(self, track: Track | str, agent_id: str, seed: int | None = None) -> None:
        pass

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self.action.copy()
