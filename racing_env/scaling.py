"""The race's lengths scaled to the car's size: start regions, contact, walls, preview, line.

The defaults of :class:`~racing_env.config.RulesConfig`, :class:`~racing_env.config.StartConfig`,
:class:`~racing_env.config.RaceConfig` (``preview_ds``), :class:`~racing_env.raceline.RacelineConfig`
and :class:`~racing_env.controllers.RacelineFollower` are tuned to the paper's 1:43 car (ORCA,
0.12 m long, 0.06 m wide; :data:`REFERENCE_SIZE`) and stay so. :func:`scaled_configs` gives
the same settings for a car of another size: each length in metres is multiplied by the ratio
of the car's length (``k_len = length / 0.12``) or of its width (``k_wid = width / 0.06``) to
the ORCA car's, as listed in :data:`SCALED_FIELDS`:

========================  ===================  =====  =====================================
config                    field                scale  why
========================  ===================  =====  =====================================
RulesConfig               contact_ds           len    one car length, along the track
RulesConfig               contact_dn           wid    one car width, across the track
RulesConfig               wall_margin          wid    run-off beyond the edge, sideways
StartConfig               s0                   len    front of the grid, 25 car lengths
                                                      from s = 0; on a TUMFTM circuit about
                                                      the same place at 1/43 and full size
StartConfig               grid_gap             len    rows of the grid
StartConfig               region_length        len    start regions R1, R2, ...
StartConfig               region_gap           len    gaps between them
StartConfig               min_gap              len    spacing of ``random`` starts
RaceConfig                preview_ds           len    curvature preview spacing
RacelineConfig            margin               wid    clearance from the edges
RacelineConfig            point_spacing        len    optimisation stations
RacelineFollower          preview_min          len    shortest steering preview
RacelineFollower          yield_gap            wid    lateral room left to a car
RacelineFollower          yield_behind/ahead   len    window in which it gives way
========================  ===================  =====  =====================================

Not scaled, on purpose: fractions and factors (``lateral_jitter``, ``front_factor``,
``rear_factor``, ``offtrack_factor``, the ``mu_*`` of the racing line), counts
(``n_preview``, ``max_substeps``, ``substep_gain``, ``n_cars``), times (``dt``,
``max_cycles``, ``preview_time``, ``speed_preview``) and speeds (``StartConfig.speed``): they
belong to the dynamics, not to the size. ``RacelineConfig.tol`` (None) already follows the
track's width. The off-track rule itself (the car's centre beyond an edge) has no length.

Two lengths are constants of the compiled step, not settings, and are *not* scaled here: the
1 cm margin of the contact pre-check (``racing_env.simulator``; it covers the difference
between two integrations and between sub-step points, set by the speeds, accelerations and
the ~25-50 ms sub-steps, which are alike in both classes, not by the car's size: see
``_step_one_race``) and ``racing_env.core.S_CLIP`` (1e4 m, the bound of the relative progress
in an observation), which :func:`racing_env.core.s_clip` scales by the length ratio for the
other classes (3.9e5 m at full size: 67 laps of Monza, instead of 1.7).
"""

from __future__ import annotations

import inspect
import math
from dataclasses import dataclass, replace
from typing import Any, Protocol

from .config import RaceConfig, RulesConfig, StartConfig
from .vehicle import VehicleParams
from .vehicles import VEHICLE_CLASSES

REFERENCE_SIZE = (VehicleParams().length, VehicleParams().width)
"""(length, width) [m] of the car the defaults are tuned to: the ORCA 1:43 car, (0.12, 0.06)."""

VEHICLE_SIZES = {name: (cls().length, cls().width) for name, cls in VEHICLE_CLASSES.items()}
"""(length, width) [m] of each vehicle class, from its parameter set
(:data:`racing_env.vehicles.VEHICLE_CLASSES`)."""

SCALED_FIELDS: dict[str, dict[str, str]] = {
    "RulesConfig": {"contact_ds": "length", "contact_dn": "width", "wall_margin": "width"},
    "StartConfig": {
        "s0": "length",
        "grid_gap": "length",
        "region_length": "length",
        "region_gap": "length",
        "min_gap": "length",
    },
    "RaceConfig": {"preview_ds": "length"},
    "RacelineConfig": {"margin": "width", "point_spacing": "length"},
    "RacelineFollower": {
        "preview_min": "length",
        "yield_gap": "width",
        "yield_behind": "length",
        "yield_ahead": "length",
    },
}
"""For each config, its fields in metres and whether they scale with the car's ``"length"``
or ``"width"``; every other field does not scale (see the module docstring)."""


class _Sized(Protocol):
    @property
    def length(self) -> float: ...
    @property
    def width(self) -> float: ...


def vehicle_size(vehicle: str | tuple[float, float] | _Sized) -> tuple[float, float]:
    """(length, width) [m] of ``vehicle``: a class name of :data:`VEHICLE_SIZES`, a
    ``(length, width)`` pair, or an object with ``length`` and ``width`` attributes (a
    :class:`~racing_env.vehicle.VehicleParams`)."""
    if isinstance(vehicle, str):
        if vehicle not in VEHICLE_SIZES:
            raise ValueError(
                f"unknown vehicle class {vehicle!r}; expected one of {tuple(VEHICLE_SIZES)}"
            )
        length, width = VEHICLE_SIZES[vehicle]
    elif isinstance(vehicle, tuple):
        if len(vehicle) != 2:
            raise ValueError(f"vehicle size must be (length, width), got {vehicle!r}")
        length, width = vehicle
    else:
        try:
            length, width = vehicle.length, vehicle.width
        except AttributeError:
            raise ValueError(
                f"vehicle must be a class name, a (length, width) pair or have length and "
                f"width attributes, got {type(vehicle).__name__}"
            ) from None
    for name, v in (("length", length), ("width", width)):
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"vehicle {name} must be a positive number [m], got {v!r}")
    return float(length), float(width)


def size_ratios(vehicle: str | tuple[float, float] | _Sized) -> tuple[float, float]:
    """``(k_len, k_wid)``: the car's length and width over the ORCA car's (1.0, 1.0 for ORCA;
    about (39.2, 33.3) for ``"fullsize"``)."""
    length, width = vehicle_size(vehicle)
    return length / REFERENCE_SIZE[0], width / REFERENCE_SIZE[1]


def _scale_fields(obj: Any, table: dict[str, str], k_len: float, k_wid: float) -> dict:
    k = {"length": k_len, "width": k_wid}
    return {name: getattr(obj, name) * k[kind] for name, kind in table.items()}


def _follower_defaults() -> dict[str, float]:
    from .controllers import RacelineFollower

    params = inspect.signature(RacelineFollower.__init__).parameters
    return {name: params[name].default for name in SCALED_FIELDS["RacelineFollower"]}


@dataclass(frozen=True)
class ScaledConfigs:
    """The settings of :func:`scaled_configs` for one car size."""

    k_len: float
    k_wid: float
    rules: RulesConfig
    start: StartConfig
    preview_ds: float
    raceline: Any  # racing_env.raceline.RacelineConfig (imported lazily)
    follower: dict[str, float]
    """Keyword arguments of :class:`~racing_env.controllers.RacelineFollower`."""

    def race_config(self, base: RaceConfig | None = None, **changes: Any) -> RaceConfig:
        """``base`` (default :class:`RaceConfig`) with these rules, start and ``preview_ds``
        (plus ``changes``, e.g. ``vehicle=...``)."""
        base = base or RaceConfig()
        return base.with_(rules=self.rules, start=self.start, preview_ds=self.preview_ds, **changes)


def scaled_configs(
    vehicle: str | tuple[float, float] | _Sized,
    rules: RulesConfig | None = None,
    start: StartConfig | None = None,
    preview_ds: float | None = None,
    raceline: Any = None,
    follower: dict[str, float] | None = None,
) -> ScaledConfigs:
    """Rules, start, preview spacing, racing-line and follower settings for ``vehicle`` (a
    class name such as ``"fullsize"``, a ``(length, width)`` pair in metres or an object with
    ``length`` and ``width``): each length of :data:`SCALED_FIELDS` of the given settings
    (default: the package defaults, tuned to the ORCA car) multiplied by the car's length or
    width ratio to the ORCA car. For the ORCA car the settings come back exactly as given.
    """
    from .raceline import RacelineConfig

    k_len, k_wid = size_ratios(vehicle)
    rules = rules or RulesConfig()
    start = start or StartConfig()
    raceline = raceline or RacelineConfig()
    base_follower = {**_follower_defaults(), **(follower or {})}
    preview = RaceConfig.preview_ds if preview_ds is None else preview_ds
    return ScaledConfigs(
        k_len=k_len,
        k_wid=k_wid,
        rules=replace(rules, **_scale_fields(rules, SCALED_FIELDS["RulesConfig"], k_len, k_wid)),
        start=replace(start, **_scale_fields(start, SCALED_FIELDS["StartConfig"], k_len, k_wid)),
        preview_ds=preview * k_len,
        raceline=replace(
            raceline, **_scale_fields(raceline, SCALED_FIELDS["RacelineConfig"], k_len, k_wid)
        ),
        follower={
            name: base_follower[name] * (k_len if kind == "length" else k_wid)
            for name, kind in SCALED_FIELDS["RacelineFollower"].items()
        },
    )
