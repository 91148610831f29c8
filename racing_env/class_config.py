"""The race of a vehicle class: its car, its track, its rules at its size, its wake.

The envs take ``vehicle_class`` (``"orca"``, the paper's 1:43 car, the default; or
``"fullsize"``) and build the race from :data:`CLASS_DEFAULTS`:

==========  ==================  ==============================  ======  =========================
class       vehicle             rules, start, ``preview_ds``    wake    default track
==========  ==================  ==============================  ======  =========================
orca        VehicleParams()     the package defaults            0.0     ``"default"`` (38.9 m)
fullsize    FullSizeParams()    scaled to the car's size;       1.0     ``"tumftm:Monza"`` (5.8 km)
                                rejoin at the edge
==========  ==================  ==============================  ======  =========================

(scaled by :func:`racing_env.scaling.scaled_configs`: contact box one car length by one car
width, walls, start regions and the curvature preview in car lengths). A track name is built
at the class's scale (:func:`racing_env.tracks.make_track`); a :class:`Track` or a race config
of another class than the one asked for is a ``ValueError`` naming both.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

from .config import RaceConfig
from .vehicle import VehicleParams
from .vehicles.fullsize import FullSizeParams

if TYPE_CHECKING:
    from .track import Track

CLASS_DEFAULTS: dict[str, dict] = {
    "orca": {"vehicle": VehicleParams, "wake": 0.0, "track": "default"},
    "fullsize": {
        "vehicle": FullSizeParams,
        "wake": 1.0,
        "track": "tumftm:Monza",
        "rules": {"offtrack_rejoin": True, "contact_repeat": False},
    },
}
"""Per vehicle class: its parameter dataclass, the wake strength, the track of its races and
the rules it changes besides their lengths (``rules``; the full-size car rejoins the track at
the edge it crossed, and a pair of cars in touch is slowed once, not every period:
:class:`~racing_env.config.RulesConfig`)."""


def class_of(vehicle: VehicleParams | FullSizeParams) -> str:
    """``"fullsize"`` for a :class:`FullSizeParams`, ``"orca"`` for a :class:`VehicleParams`."""
    if isinstance(vehicle, FullSizeParams):
        return "fullsize"
    if isinstance(vehicle, VehicleParams):
        return "orca"
    raise ValueError(
        f"vehicle must be a VehicleParams or a FullSizeParams, got {type(vehicle).__name__}"
    )


def resolve_class(
    vehicle_class: str | None = None,
    config: RaceConfig | None = None,
    vehicle: VehicleParams | FullSizeParams | None = None,
    track: str | Track | None = None,
) -> str:
    """The vehicle class of a race from what was given, in this order: ``vehicle_class``,
    ``vehicle``, ``config``'s vehicle, a :class:`Track`'s ``vehicle_class``; ``"orca"`` if
    none. Any two that disagree raise ``ValueError`` naming both."""
    if vehicle_class is not None and vehicle_class not in CLASS_DEFAULTS:
        raise ValueError(
            f"unknown vehicle_class {vehicle_class!r}; expected one of {tuple(CLASS_DEFAULTS)}"
        )
    claims = [("vehicle_class", vehicle_class)]
    if vehicle is not None:
        claims.append(("vehicle", class_of(vehicle)))
    if config is not None:
        claims.append(("config.vehicle", config.vehicle_class))
    if track is not None and not isinstance(track, str):
        claims.append((f"track {track.name!r}", track.vehicle_class))
    known = [(who, c) for who, c in claims if c is not None]
    for who, c in known[1:]:
        if c != known[0][1]:
            raise ValueError(
                f"the vehicle classes disagree: {known[0][0]} is {known[0][1]!r} but {who} is "
                f"{c!r}; a race has one class (give a track and a vehicle of the same class)"
            )
    return known[0][1] if known else "orca"


def race_config_for(
    vehicle_class: str | None = None,
    vehicle: VehicleParams | FullSizeParams | None = None,
    wake: float | None = None,
) -> RaceConfig:
    """The default :class:`RaceConfig` of ``vehicle_class`` (default: ``vehicle``'s class, or
    ``"orca"``): :class:`RaceConfig` itself for
    ``"orca"`` (exactly the paper's), else the class's vehicle (``vehicle`` or its defaults)
    with the rules, start and ``preview_ds`` scaled to the car's size and the class's wake
    (``wake`` overrides it)."""
    from .scaling import scaled_configs

    cls = resolve_class(vehicle_class, vehicle=vehicle)
    defaults = CLASS_DEFAULTS[cls]
    car = vehicle if vehicle is not None else defaults["vehicle"]()
    strength = defaults["wake"] if wake is None else wake
    if cls == "orca":
        base = RaceConfig() if vehicle is None else RaceConfig(vehicle=car)
        return base if wake is None else base.with_(wake=strength)
    scaled = scaled_configs(car)
    rules = replace(scaled.rules, **defaults.get("rules", {}))
    return scaled.race_config(RaceConfig(vehicle=car), wake=strength).with_(rules=rules)


def default_track(vehicle_class: str) -> str:
    """The track name a race of ``vehicle_class`` runs on unless told (:data:`CLASS_DEFAULTS`)."""
    return str(CLASS_DEFAULTS[resolve_class(vehicle_class)]["track"])


def class_race(
    vehicle_class: str | None,
    track: str | Track | None,
    config: RaceConfig | None,
    vehicle: VehicleParams | FullSizeParams | None = None,
    wake: float | None = None,
) -> tuple[RaceConfig, str | Track]:
    """``(config, track)`` of an env's arguments: the class resolved by :func:`resolve_class`,
    ``config`` (or the class's :func:`race_config_for`, with ``vehicle``) with ``wake`` if
    given, and ``track`` (or the class's :func:`default_track`). The env's other keywords
    (``n_cars``, ``rules``, ...) are applied by the caller."""
    cls = resolve_class(vehicle_class, config, vehicle, track)
    cfg = config if config is not None else race_config_for(cls, vehicle)
    if wake is not None:
        cfg = cfg.with_(wake=wake)
    return cfg, default_track(cls) if track is None else track
