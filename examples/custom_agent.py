"""Plug in your own agent: register it by name, then race it against the built-in follower."""

import numpy as np

from agents import register_agent
from experiments.evaluation.race import run_race


@register_agent("wiggle")
class Wiggle:
    """Full throttle, steering back to the centre line."""

    def reset(self, track, agent_id, seed=None):
        self.track = track

    def act(self, observation):
        n, mu = observation[1], observation[2]  # own lateral offset [m] and heading [rad]
        return np.array([1.0, np.clip(-4 * n - 2 * mu, -1, 1)], dtype=np.float32)


if __name__ == "__main__":
    result, _ = run_race(["wiggle", "raceline"], track="default", seed=0, max_cycles=300)
    print(result.table())
