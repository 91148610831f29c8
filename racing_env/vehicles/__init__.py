"""Vehicle classes: a parameter set plus its force law, each written once for numpy/numba/CasADi.

* ``"orca"``: the paper's 1:43 ORCA car (:class:`racing_env.vehicle.VehicleParams`,
  :func:`racing_env.vehicle.frenet_ode`), the default; its races stay the same bit for bit.
* ``"fullsize"``: a full-size single-seater from TUM FTM's published parameter set
  (:class:`racing_env.vehicles.fullsize.FullSizeParams`,
  :func:`racing_env.vehicles.fullsize.frenet_ode_fullsize`).
"""

from __future__ import annotations

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


__all__ = [
    "VEHICLE_CLASSES",
    "FullSizeParams",
    "VehicleParams",
    "frenet_ode_fullsize",
    "vehicle_class",
]
