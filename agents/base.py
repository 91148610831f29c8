"""The agent interface every driver implements, and the registry that builds agents by name."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

    from racing_env.track import Track


@runtime_checkable
class Agent(Protocol):
    """A driver of one car.

    ``reset(track, agent_id, seed)`` is called at the start of every race with the
    :class:`racing_env.Track`, the car's id (``"car_0"`` ...) and a seed for any randomness.
    ``act(observation)`` maps the car's env observation (see
    :class:`racing_env.RacingParallelEnv`: own Frenet state, every other car relative to it,
    curvature preview) to an action in the env's action space: a float32 array
    ``[throttle, steering]`` in [-1, 1].

    Optionally, an agent declares ``field_sizes``, the numbers of cars it can race among (a
    container of ints such as ``range(2, 9)``; default: any). Races check it before the start
    and name the agent and its car when the field does not fit (see
    :mod:`agents.observations`, which also has :func:`agents.adapt_observation` to read any
    field in a fixed layout).
    """

    def reset(self, track: Track | str, agent_id: str, seed: int | None = None) -> None: ...

    def act(self, observation: np.ndarray) -> np.ndarray: ...


def median_p99(values: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """(median, 99th percentile) of ``values`` (e.g. decision times for an agent's ``stats``);
    NaN for no values."""
    a = np.asarray(values, dtype=float)
    if not a.size:
        return float("nan"), float("nan")
    return float(np.median(a)), float(np.percentile(a, 99))


_REGISTRY: dict[str, Callable[..., Agent]] = {}

#: Entry-point group of agent plugins: an installed distribution that declares
#: ``[project.entry-points."alpha_racer.agents"] mine = "my_agent:Mine"`` makes ``mine`` an
#: agent name (the entry point names a factory: a class or function returning an Agent).
ENTRY_POINT_GROUP = "alpha_racer.agents"


def register_agent(name: str, factory: Callable[..., Agent] | None = None) -> Any:
    """Register ``factory`` (a class or function returning an Agent) under ``name``.

    Usable as a decorator: ``@register_agent("mine") class Mine: ...``. An installed package
    can register agents without being imported first through the :data:`ENTRY_POINT_GROUP`
    entry points, loaded when their name is first asked for.
    """

    def _do(f):
        if not name or not isinstance(name, str):
            raise ValueError(f"agent name must be a non-empty string, got {name!r}")
        _REGISTRY[name] = f
        return f

    return _do(factory) if factory is not None else _do


def _entry_points() -> dict:
    """The installed :data:`ENTRY_POINT_GROUP` entry points by name (metadata only, nothing
    imported)."""
    from importlib.metadata import entry_points

    return {ep.name: ep for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _load_entry_point(name: str) -> bool:
    """Register the plugin agent ``name`` from its entry point; False if there is none."""
    ep = _entry_points().get(name)
    if ep is None:
        return False
    try:
        factory = ep.load()
    except Exception as exc:  # a broken plugin: one line naming it, not its traceback
        raise ValueError(
            f"agent plugin {name!r} (entry point {ep.value!r} in group "
            f"{ENTRY_POINT_GROUP!r}) failed to load: {type(exc).__name__}: {exc}"
        ) from None
    if not callable(factory):
        raise ValueError(
            f"agent plugin {name!r} (entry point {ep.value!r}) is "
            f"{type(factory).__name__}, not a class or function returning an agent"
        )
    register_agent(name, factory)
    return True


def agent_names() -> list[str]:
    """Every agent name: the registered ones and the installed plugins' (not yet loaded)."""
    return sorted(set(_REGISTRY) | set(_entry_points()))


def get_factory(name: str) -> Callable[..., Agent]:
    """The factory registered under ``name``, loading a plugin's entry point on first use;
    ``ValueError`` naming the registered agents if there is none."""
    if name not in _REGISTRY and not _load_entry_point(name):
        raise ValueError(f"unknown agent {name!r}; registered agents: {', '.join(agent_names())}")
    return _REGISTRY[name]


def make_agent(name: str, **kwargs: Any) -> Agent:
    """Build a registered agent by name (``kwargs`` go to its factory)."""
    agent = get_factory(name)(**kwargs)
    if not isinstance(agent, Agent):
        raise TypeError(
            f"agent factory {name!r} returned {type(agent).__name__}, which lacks "
            f"reset(track, agent_id, seed) / act(observation)"
        )
    return agent


@dataclass(frozen=True)
class AgentParameter:
    """One keyword of an agent's factory: its name, default (:data:`REQUIRED` if none),
    bounds ``(low, high)`` where the factory declares them (``None`` otherwise) and a note
    (the factory's ``param_notes``, e.g. the values a string keyword takes; ``""`` if none)."""

    name: str
    default: Any
    bounds: tuple[float, float] | None = None
    note: str = ""


REQUIRED = inspect.Parameter.empty


def agent_parameters(name: str) -> tuple[list[AgentParameter], bool]:
    """The keywords the agent ``name`` accepts, from its factory's signature, and whether it
    accepts other keywords too (a ``**kwargs`` that could not be resolved).

    A ``**kwargs`` of a class's ``__init__`` is followed to the base classes' ``__init__``
    (``alpha`` takes the ``mpc`` keywords), or to the callable in the factory's
    ``spec_keywords_from`` attribute (``ibr`` takes :class:`agents.ibr.IBRConfig` fields).
    Bounds come from the factory's ``param_bounds`` attribute (``{name: (low, high)}``; the
    MPC's theta bounds :data:`agents.reference.THETA_LOW` / ``THETA_HIGH``). A keyword whose
    signature default is ``None`` shows the factory's ``param_defaults`` value instead, if it
    declares one (the MPC's theta keywords default to ``None`` so that explicit values can be
    told apart, and to :data:`agents.mpc_agent.DEFAULT_THETA` in effect); notes come from
    ``param_notes`` (``{name: text}``).
    """
    factory = get_factory(name)
    bounds = dict(getattr(factory, "param_bounds", {}) or {})
    shown = dict(getattr(factory, "param_defaults", {}) or {})
    notes = dict(getattr(factory, "param_notes", {}) or {})

    def param(p) -> AgentParameter:
        default = shown.get(p.name, p.default) if p.default is None else p.default
        return AgentParameter(p.name, default, bounds.get(p.name), notes.get(p.name, ""))

    params: dict[str, AgentParameter] = {}
    sources = [factory]
    if inspect.isclass(factory):
        sources += [
            vars(base)["__init__"]
            for base in factory.__mro__[1:]
            if "__init__" in vars(base) and base is not object
        ]
    extra = getattr(factory, "spec_keywords_from", None)
    open_kwargs = False
    for fn in sources:
        try:
            sig = inspect.signature(fn)
        except (TypeError, ValueError):
            open_kwargs = True
            break
        open_kwargs = False
        for p in sig.parameters.values():
            if (fn is not factory and p.name == "self") or p.kind in (
                p.VAR_POSITIONAL,
                p.POSITIONAL_ONLY,
            ):
                continue
            if p.kind == p.VAR_KEYWORD:
                open_kwargs = True
                continue
            params.setdefault(p.name, param(p))
        if not open_kwargs:
            break
    if open_kwargs and extra is not None:
        for p in inspect.signature(extra).parameters.values():
            if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD):
                params.setdefault(p.name, param(p))
        open_kwargs = False
    return list(params.values()), open_kwargs


def parse_value(text: str) -> int | float | bool | str:
    """An agent spec's value as written (``"5"``, ``"0.3"``, ``"true"``, ``"general"``) parsed
    as int, float, bool or else kept as str."""
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def spec_params(spec: str) -> tuple[str, dict[str, str]]:
    """``(name, {key: value text})`` of an agent spec ``name:key=value,...``, in the spec's
    order, spaces around keys and values stripped (the values as written, not parsed)."""
    name, _, params = spec.partition(":")
    items = (item.partition("=") for item in params.split(",") if item)
    return name, {k.strip(): v.strip() for k, _, v in items}


def spec_with(spec: str, drop: tuple[str, ...] = (), **params) -> str:
    """``spec`` with the keys ``drop`` and ``params`` taken out and ``params`` appended, in
    their order (``spec_with("mpc:q=5,s1=0.3", s1=0)`` is ``"mpc:q=5,s1=0"``)."""
    name, kept = spec_params(spec)
    items = [f"{k}={v}" for k, v in kept.items() if k not in drop and k not in params]
    items += [f"{k}={v}" for k, v in params.items()]
    return f"{name}:{','.join(items)}" if items else name


def make_agent_spec(spec: str) -> Agent:
    """Build an agent from a spec ``name`` or ``name:key=value,key=value`` (command line form),
    e.g. ``"raceline:grip=0.75,line_fraction=0.8"``; values are parsed as int, float, bool or str.

    Every error is a ``ValueError`` naming the spec: an unknown name (with the registered
    names), an unknown key (with the agent's keys), a missing file (a model or checkpoint).
    """
    name, _, params = spec.partition(":")
    kwargs = {}
    for item in filter(None, params.split(",")):
        key, eq, value = item.partition("=")
        if not eq or not key:
            raise ValueError(f"bad agent parameter {item!r} in {spec!r}; expected key=value")
        kwargs[key.strip()] = parse_value(value.strip())
    known, open_kwargs = agent_parameters(name)
    unknown = sorted(set(kwargs) - {p.name for p in known})
    if unknown and not open_kwargs:
        raise ValueError(
            f"agent {spec!r}: unknown parameter(s) {', '.join(unknown)}; "
            f"{name!r} takes {', '.join(p.name for p in known) or 'no parameters'}"
        )
    try:
        return make_agent(name, **kwargs)
    except (TypeError, ValueError, FileNotFoundError) as exc:
        msg = str(exc)
        raise ValueError(msg if spec in msg else f"agent {spec!r}: {msg}") from None


def import_agent_modules(modules: Iterable[str]) -> None:
    """Import each of ``modules`` (module names, or paths of ``.py`` files) so that the agents
    they register become available to specs; the current directory is searched as by
    ``python -m``. ``ValueError`` in one line naming a module that fails to import."""
    import importlib
    import importlib.util
    import os
    import sys
    from pathlib import Path

    if "" not in sys.path and os.getcwd() not in sys.path:
        sys.path.insert(0, os.getcwd())
    for module in modules:
        try:
            if module.endswith(".py"):
                path = Path(module)
                if not path.is_file():
                    raise FileNotFoundError(f"no file {module}")
                spec = importlib.util.spec_from_file_location(path.stem, path)
                if spec is None or spec.loader is None:
                    raise ImportError(f"cannot load {module} as a module")
                mod = importlib.util.module_from_spec(spec)
                sys.modules[path.stem] = mod
                spec.loader.exec_module(mod)
            else:
                importlib.import_module(module)
        except Exception as exc:
            raise ValueError(
                f"cannot import {module!r}: {type(exc).__name__}: {exc} "
                f"(expected an importable module name or a .py file)"
            ) from None
