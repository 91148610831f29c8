"""The agent interface every driver implements, and the registry that builds agents by name."""
from __future__ import annotations

from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Agent(Protocol):
    """A driver of one car.

    ``reset(track, agent_id, seed)`` is called at the start of every race with the
    :class:`racing_env.Track`, the car's id (``"car_0"`` ...) and a seed for any randomness.
    ``act(observation)`` maps the car's env observation (see
    :class:`racing_env.RacingParallelEnv`: own Frenet state, every other car relative to it,
    curvature preview) to an action in the env's action space: a float32 array
    ``[throttle, steering]`` in [-1, 1].
    """

    def reset(self, track, agent_id: str, seed: int | None = None) -> None: ...

    def act(self, observation: np.ndarray) -> np.ndarray: ...


def median_p99(values) -> tuple[float, float]:
    """(median, 99th percentile) of ``values`` (e.g. decision times for an agent's ``stats``);
    NaN for no values."""
    a = np.asarray(values, dtype=float)
    if not a.size:
        return float("nan"), float("nan")
    return float(np.median(a)), float(np.percentile(a, 99))


_REGISTRY: dict[str, Callable[..., Agent]] = {}


def register_agent(name: str, factory: Callable[..., Agent] | None = None):
    """Register ``factory`` (a class or function returning an Agent) under ``name``.

    Usable as a decorator: ``@register_agent("mine") class Mine: ...``.
    """
    def _do(f):
        if not name or not isinstance(name, str):
            raise ValueError(f"agent name must be a non-empty string, got {name!r}")
        _REGISTRY[name] = f
        return f
    return _do(factory) if factory is not None else _do


def agent_names() -> list[str]:
    return sorted(_REGISTRY)


def make_agent(name: str, **kwargs: Any) -> Agent:
    """Build a registered agent by name (``kwargs`` go to its factory)."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown agent {name!r}; registered agents: {', '.join(agent_names())}")
    agent = _REGISTRY[name](**kwargs)
    if not isinstance(agent, Agent):
        raise TypeError(f"agent factory {name!r} returned {type(agent).__name__}, which lacks "
                        f"reset(track, agent_id, seed) / act(observation)")
    return agent


def _parse_value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def make_agent_spec(spec: str) -> Agent:
    """Build an agent from a spec ``name`` or ``name:key=value,key=value`` (command line form),
    e.g. ``"raceline:mu=0.75,line_fraction=0.8"``; values are parsed as int, float, bool or str."""
    name, _, params = spec.partition(":")
    kwargs = {}
    for item in filter(None, params.split(",")):
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise ValueError(f"bad agent parameter {item!r} in {spec!r}; expected key=value")
        kwargs[key.strip()] = _parse_value(value.strip())
    try:
        return make_agent(name, **kwargs)
    except TypeError as exc:
        raise ValueError(f"agent {spec!r}: {exc}") from None
