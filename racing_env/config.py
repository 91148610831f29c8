"""Typed configuration of a race: rules, start positions, episode and observation settings."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from .vehicle import VehicleParams
from .vehicles.fullsize import FullSizeParams

START_MODES = ("grid", "regions", "random")
#: A pair of cars is "touching" when it is inside the contact box grown by this fraction of its
#: length and width (the bodies-apart rule leaves two cars that met exactly on the box's edge).
TOUCHING = 0.01
MAX_CARS = 8

# layout of the rule vector of the compiled step (RulesConfig.pack)
(
    R_CONTACT_ON,
    R_CONTACT_DS,
    R_CONTACT_DN,
    R_FRONT,
    R_REAR,
    R_OFF_ON,
    R_OFF_FACTOR,
    R_MAX_SUB,
    R_SUB_GAIN,
    R_OFF_REJOIN,
    R_CONTACT_REPEAT,
    R_WAKE,  # from RaceConfig (RaceConfig.pack_rules): the wake's strength, 0 = off
    R_WAKE_LENGTH,  # the cars' length and width [m], the wake's units
    R_WAKE_WIDTH,
) = range(14)


def _is_int(v) -> bool:
    """An integer, but not a bool (``True`` is an ``int`` to Python, not a count to us)."""
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _positive(obj, *names):
    for name in names:
        v = getattr(obj, name)
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise ValueError(f"{type(obj).__name__}.{name} must be a positive number, got {v!r}")


@dataclass(frozen=True)
class RulesConfig:
    """The paper's racing rules (section 2.2), applied after every control period.

    * Contact: two cars closer than ``contact_ds`` along the track *and* ``contact_dn``
      sideways (their bodies overlap, by default) at any moment of a control period are
      slowed there and then: the car in front at that moment to ``front_factor * vx``
      (paper: 1/2), the car behind to ``rear_factor * vx`` (paper: 1/3). Contact is swept
      over the RK4 sub-steps, so no car passes through another; a car is slowed at most once
      per period (by the smallest factor due, off track included). With ``contact_repeat``
      off, a pair that starts a period touching (within :data:`TOUCHING` of the contact box,
      as the bodies-apart rule below leaves two cars that met) is not slowed again while it
      stays in touch: the two slide along each other (the full-size class's rule: two cars
      side by side, one steering into the other, were slowed every period, 0.5 and 1/3 of
      their speed 10 times a second, and crawled side by side at 0.7 m/s for up to 45 s in
      Monza's first chicane, measured; the paper's 1:43 world keeps the rule as it is).
    * Bodies stay apart (env v2): a car may not end a sub-step overlapping, or beyond, a car
      it is not laterally clear of (``|n_i - n_j| < contact_dn``). A bump from behind puts the
      rear car back to ``contact_ds`` behind and limits its ``vx`` to the front car's; a bump
      from the side pushes the two apart sideways. A car passes another only through free
      space (see :func:`racing_env.contact._separate`).
    * Off track: a car beyond an edge (``n > w_left`` or ``n < -w_right``) is slowed to
      ``offtrack_factor * vx`` (paper: 1/2) and re-aligned with the track
      (``mu = 0``; we also zero ``vy`` and ``omega``). With ``offtrack_rejoin`` it is also put
      back onto the track at the edge it crossed, its body just inside it (the centre half a
      car width in), so it rejoins the track (the full-size class's rule:
      re-aligned every period beyond the edge, a full-size car slowed to walking pace cannot
      build the heading to steer back within 0.1 s, and crept along Spa's run-off for 20 to
      100 periods at 0.4 m/s, measured; the paper's 1:43 world keeps the rule as it is).
    * A wall ``wall_margin`` m beyond each edge stops a car sideways.
    """

    contact: bool = True
    contact_ds: float = 0.12  # [m] default: one car length
    contact_dn: float = 0.06  # [m] default: one car width
    front_factor: float = 0.5
    rear_factor: float = 1.0 / 3.0
    offtrack: bool = True
    offtrack_factor: float = 0.5
    offtrack_rejoin: bool = False
    contact_repeat: bool = True
    wall_margin: float = 0.15  # [m]
    max_substeps: int = 100  # cap of RK4 sub-steps per control period
    substep_gain: float = 1.0  # >1 takes more sub-steps than stability needs

    def __post_init__(self):
        _positive(self, "contact_ds", "contact_dn", "wall_margin", "max_substeps", "substep_gain")
        for name in ("front_factor", "rear_factor", "offtrack_factor"):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise ValueError(f"RulesConfig.{name} must be in [0, 1], got {v!r}")

    def pack(self) -> np.ndarray:
        """Vector for the compiled step (layout: ``R_*`` above, re-exported by
        :mod:`racing_env.simulator`)."""
        return np.array(
            [
                float(self.contact),
                self.contact_ds,
                self.contact_dn,
                self.front_factor,
                self.rear_factor,
                float(self.offtrack),
                self.offtrack_factor,
                float(self.max_substeps),
                self.substep_gain,
                float(self.offtrack_rejoin),
                float(self.contact_repeat),
            ]
        )


@dataclass(frozen=True)
class StartConfig:
    """Where cars start.

    * ``grid``: a two-column grid behind ``s0``, car_0 on pole, rows ``grid_gap`` m apart.
    * ``regions``: the paper's start regions R1 (front-most, ending at ``s0``), R2, R3, ...
      each ``region_length`` m long and ``region_gap`` m apart; each car gets one region (a
      random order unless ``order`` is given to reset) and a uniform random position in it,
      with a random lateral offset of at most ``lateral_jitter`` of the usable half width.
    * ``random``: anywhere on the track, at least ``min_gap`` m apart along it: the track is
      cut into ``n_cars`` equal slots at a random rotation, each car (in a random order) takes
      one slot at a random position within ``(slot - min_gap) / 2`` of its centre, with a
      random lateral offset as in ``regions``. ``n_cars * min_gap`` over the track length is
      an error.
    """

    mode: str = "regions"
    s0: float = 3.0  # [m] front of the grid / of R1 (on the default track's main straight)
    grid_gap: float = 0.3
    region_length: float = 0.4
    region_gap: float = 0.6
    lateral_jitter: float = 0.8
    min_gap: float = 0.3
    speed: float = 0.0  # initial vx [m/s]

    def __post_init__(self):
        if self.mode not in START_MODES:
            raise ValueError(f"start mode must be one of {START_MODES}, got {self.mode!r}")
        _positive(self, "grid_gap", "region_length", "min_gap")
        if self.region_gap < 0 or not (0 <= self.lateral_jitter <= 1) or self.speed < 0:
            raise ValueError(
                f"invalid StartConfig: region_gap {self.region_gap} (>= 0), "
                f"lateral_jitter {self.lateral_jitter} (in [0, 1]), "
                f"speed {self.speed} (>= 0)"
            )


@dataclass(frozen=True)
class RaceConfig:
    """Everything that defines a race apart from the track.

    ``max_cycles`` control periods of ``dt`` s (default 500 x 0.1 s = 50 s, the paper's race);
    with ``laps`` set, the race also ends when the first car completes that many laps.
    Observations carry a curvature preview of ``n_preview`` values ``preview_ds`` m apart.

    ``vehicle`` is a :class:`VehicleParams` (the paper's 1:43 ORCA car, the default) or a
    :class:`~racing_env.vehicles.fullsize.FullSizeParams` (the full-size class; its rules,
    start and ``preview_ds`` come from :func:`racing_env.scaling.scaled_configs`, see
    :func:`racing_env.class_config.race_config_for`). ``wake`` is the strength of the wake
    (:mod:`racing_env.wake`; 0 = off, exactly the world without it; 1 = the published
    figures): each car's drag and downforce factors are computed from the cars ahead at the
    start of every control period and held over it. The full-size car takes both; the ORCA
    car has no downforce and takes the drag factor on its drag term ``C4 vx^2``.
    """

    n_cars: int = 3
    dt: float = 0.1
    max_cycles: int = 500
    laps: int | None = None
    vehicle: VehicleParams | FullSizeParams = field(default_factory=VehicleParams)
    rules: RulesConfig = field(default_factory=RulesConfig)
    start: StartConfig = field(default_factory=StartConfig)
    n_preview: int = 10
    preview_ds: float = 0.25
    wake: float = 0.0

    def __post_init__(self):
        if not isinstance(self.vehicle, (VehicleParams, FullSizeParams)):
            raise ValueError(
                f"vehicle must be a VehicleParams or a FullSizeParams, got "
                f"{type(self.vehicle).__name__}"
            )
        w = self.wake
        if isinstance(w, (bool, np.bool_)) or not (
            isinstance(w, (int, float, np.integer, np.floating)) and math.isfinite(w) and w >= 0
        ):
            raise ValueError(f"RaceConfig.wake must be a finite number >= 0, got {w!r}")
        if not (_is_int(self.n_cars) and 1 <= self.n_cars <= MAX_CARS):
            raise ValueError(f"n_cars must be an integer in 1..{MAX_CARS}, got {self.n_cars!r}")
        if not (_is_int(self.max_cycles) and self.max_cycles >= 1):
            raise ValueError(f"max_cycles must be a positive integer, got {self.max_cycles!r}")
        if self.laps is not None and not (_is_int(self.laps) and self.laps >= 1):
            raise ValueError(f"laps must be None or a positive integer, got {self.laps!r}")
        if not (_is_int(self.n_preview) and self.n_preview >= 0):
            raise ValueError(f"n_preview must be a non-negative integer, got {self.n_preview!r}")
        _positive(self, "dt", "preview_ds")

    @property
    def vehicle_class(self) -> str:
        """``"fullsize"`` for a :class:`FullSizeParams` vehicle, else ``"orca"``."""
        return "fullsize" if isinstance(self.vehicle, FullSizeParams) else "orca"

    def pack_rules(self) -> np.ndarray:
        """The compiled step's rule vector: :meth:`RulesConfig.pack`, then ``wake`` and the
        car's length and width (``R_WAKE``, ``R_WAKE_LENGTH``, ``R_WAKE_WIDTH``)."""
        v = self.vehicle
        return np.concatenate([self.rules.pack(), [float(self.wake), v.length, v.width]])

    def with_(self, **changes) -> RaceConfig:
        """A copy with some fields changed (validated)."""
        return replace(self, **changes)

    def to_dict(self) -> dict:
        return asdict(self)
