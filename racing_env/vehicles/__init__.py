"""Vehicle classes: a parameter set plus its force law, each written once for numpy/numba/CasADi.

* ``"orca"``: the paper's 1:43 ORCA car (:class:`racing_env.vehicle.VehicleParams`,
  :func:`racing_env.vehicle.frenet_ode`), the default; its races stay the same bit for bit.
* ``"fullsize"``: a full-size single-seater from TUM FTM's published parameter set
  (:class:`racing_env.vehicles.fullsize.FullSizeParams`,
  :func:`racing_env.vehicles.fullsize.frenet_ode_fullsize`).
"""

from __future__ import annotations

from typing import Any

from ..vehicle import VehicleParams
from .fullsize import FullSizeParams, frenet_ode_fullsize

VEHICLE_CLASSES: dict[str, type] = {"orca": VehicleParams, "fullsize": FullSizeParams}
"""Name of a vehicle class -> its parameter dataclass (defaults: the published set)."""


def vehicle_class(name: str) -> type:
    """The parameter dataclass of the vehicle class ``name`` (see :data:`VEHICLE_CLASSES`)."""
    if not isinstance(name, str) or name not in VEHICLE_CLASSES:
        raise ValueError(
            f"unknown vehicle class {name!r}; valid classes: {', '.join(sorted(VEHICLE_CLASSES))}"
        )
    return VEHICLE_CLASSES[name]


def class_of(vehicle: object) -> str:
    """The vehicle class name of a parameter set (``"orca"`` for a :class:`VehicleParams`)."""
    for name, cls in VEHICLE_CLASSES.items():
        if isinstance(vehicle, cls):
            return name
    raise ValueError(
        f"vehicle must be a parameter set of a vehicle class ({', '.join(sorted(VEHICLE_CLASSES))}), "
        f"got {type(vehicle).__name__}"
    )


def track_class(track: object) -> str:
    """The vehicle class a track is sized for: its ``vehicle_class`` (``"orca"`` if it has none)."""
    return str(getattr(track, "vehicle_class", "orca"))


def vehicle_for_track(track: object, vehicle: object = None, who: str = "agent") -> Any:
    """The parameter set an agent ``who`` races with on ``track``: ``vehicle`` if given (a
    ``ValueError`` naming both classes when it is of another class than the track's), else
    the track's class's defaults (``vehicle_class(track_class(track))()``)."""
    cls = track_class(track)
    if vehicle is None:
        return vehicle_class(cls)()
    given = class_of(vehicle)
    if given != cls:
        name = getattr(track, "name", None) or "the track"
        raise ValueError(
            f"{who}: its vehicle ({type(vehicle).__name__}) is of the {given!r} class, but "
            f"track {name!r} is sized for the {cls!r} class; give a {cls!r} vehicle or none "
            f"(the class's defaults)"
        )
    return vehicle


__all__ = [
    "VEHICLE_CLASSES",
    "FullSizeParams",
    "VehicleParams",
    "class_of",
    "frenet_ode_fullsize",
    "track_class",
    "vehicle_class",
    "vehicle_for_track",
]
