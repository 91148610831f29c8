"""What the world layer knows of an agent: the duck-typed protocol (``reset(track, agent_id,
seed)`` and ``act(observation)``), how errors name an agent, and an ``act`` call whose errors name
the agent and its car.

Both layers use these: the envs (:mod:`racing_env.gym_env` and the vectorised envs) to drive
their embedded opponents, the agents layer (:mod:`agents.observations`) and the races of
``experiments`` to name an agent in their errors. This module imports nothing of either layer,
so ``agents`` can import it without reaching :mod:`racing_env.gym_env` (which builds opponents
from spec strings through ``agents``).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def is_agent(obj: object) -> bool:
    """An agent instance (a class with ``act`` and ``reset`` is a factory, not an agent)."""
    return (
        not isinstance(obj, type)
        and callable(getattr(obj, "act", None))
        and callable(getattr(obj, "reset", None))
    )


def agent_label(agent: object, spec: str | None = None) -> str:
    """How errors name an agent: its spec string if given, else its ``name`` or class name."""
    if spec:
        return repr(spec)
    return repr(getattr(agent, "name", None) or type(agent).__name__)


def act_named(
    agent: Any, observation: np.ndarray, car: str, spec: str | None = None, batch: bool = False
) -> np.ndarray:
    """``agent.act(observation)`` (with ``batch``, ``agent.act_batch(observations)``); a
    ``ValueError``, ``TypeError`` or ``IndexError`` raised in it (a shape mismatch: "operands
    could not be broadcast together ...") is raised again, of the same type, with the agent, its
    car and the observation size named."""
    try:
        return agent.act_batch(observation) if batch else agent.act(observation)
    except (ValueError, TypeError, IndexError) as exc:
        msg = str(exc)
        if car in msg:
            raise
        size = np.shape(observation)[-1] if np.ndim(observation) else "?"
        try:
            named = type(exc)(
                f"agent {agent_label(agent, spec)} driving {car} (observation of "
                f"{size} values): {msg}"
            )
        except Exception:
            raise exc from None
        # the agent's own error, for callers that name it themselves (an attribute of the
        # instance only: the exception classes do not declare it)
        named.agent_error = exc  # type: ignore[union-attr]
        raise named from exc
