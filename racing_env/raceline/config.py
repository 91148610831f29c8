"""What a racing line is computed from, and the key that names it: :class:`RacelineConfig`,
and :func:`cache_key` over the track, the vehicle, the config and the code (:data:`SOURCES`)."""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from ..cache import sources_hash
from ..track import Track
from ..vehicle import VehicleParams
from ..vehicles.fullsize import FullSizeParams

AnyVehicle = VehicleParams | FullSizeParams
"""The vehicle parameters a racing line is computed for: the ORCA car's or the full-size
class's (whose envelope is :mod:`racing_env.vehicles.fullsize_envelope`)."""

CACHE_VERSION = 4
"""Bumped when the saved file's layout changes (invalidates old cache files). An edit of the
code that computes a line needs no bump: the cache key hashes :data:`SOURCES`."""


class RacelineConvergenceWarning(RuntimeWarning):
    """The minimum-curvature iteration stopped at ``max_iter`` before meeting ``tol``."""


TOL_PER_WIDTH = 2e-4
"""Default stopping tolerance of the minimum-curvature iteration, per metre of track width."""

OBJECTIVES = ("curvature", "lap_time")
"""Racing-line objectives of :class:`RacelineConfig` (``objective``)."""

LENGTH_WEIGHTS = (0.0, 0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0)
"""Grid of ``length_weight`` values that ``objective="lap_time"`` tries before refining the
best one (:func:`lap_time_weight_search`)."""


@dataclass(frozen=True)
class RacelineConfig:
    """Settings of the racing line (all hashed into the cache key).

    * ``margin`` [m]: clearance kept from each track edge beyond half the car's width
      (the paper uses 0; a little room absorbs tracking errors of the controllers).
    * ``mu_min``, ``mu_max`` [-], ``n_mu``: the speed library covers ``n_mu`` evenly spaced
      scales of the car's g-g-v envelope in ``[mu_min, mu_max]`` (plus ``mu_nominal``).
    * ``mu_nominal`` [-]: the profile returned when no ``mu`` is given. Default 1: the car's
      own envelope (alone, the MPC at zeta = 1 laps within about 2% of its estimate with no
      off-track step; ``benchmarks/solo_laps.py``).
    * ``point_spacing`` [m]: target spacing of the optimisation stations (the result is
      interpolated back to the track grid).
    * ``tol`` [m]: stop re-linearising once no offset moves by more than this; ``None`` (the
      default) scales it with the track: ``TOL_PER_WIDTH`` (2e-4) of its mean width, 1e-4 m on
      the 0.5 m wide built-in tracks, about 2.5 mm on a full-scale 12 m circuit.
    * ``max_iter``: most re-linearisations.
    * ``smoothing`` [-]: weight of a tiny regulariser ``sum (dn/ds)^2 / L^2`` that makes the
      QP strictly convex where curvature does not pin the line (long straights).
    * ``linearization``: ``"frozen"`` (default; the paper's / TUM's scheme: first derivatives
      fixed at the current iterate) or ``"exact"`` (full Jacobian, Gauss-Newton with a line
      search on the true cost). The frozen scheme ignores that moving outwards lengthens the
      path, so its fixed point is biased towards the inside of corners: it is *not* the exact
      minimiser of ``sum kappa^2`` (on a plain circle it hugs the inner edge, whose curvature is
      higher than the centre line's), but the bias shortens the lap, and its lap times are as
      good or better on most tracks we tried (the figures are in CHANGELOG.md).
      ``"exact"`` gives the true (local) minimum-curvature line.
    * ``objective``: ``"curvature"`` (default; the paper's minimum-curvature line) or
      ``"lap_time"``: the line that adds ``length_weight`` times the path length term (below)
      to the curvature cost, with the weight searched per track for the shortest lap
      estimate at ``mu_nominal`` (:func:`lap_time_weight_search`). A shorter path pays where
      the motor, not the tyres, limits the speed: above about 2.2 m/s this car cannot hold its
      lateral limit, so on tracks of long fast corners the minimum-curvature line is not the
      fastest. Never slower (in estimate) than the minimum-curvature line, which is the
      weight 0 of the search.
    * ``length_weight`` [-]: with ``objective="curvature"``, a fixed weight ``w`` of the
      shortest-path term ``(w / W^2) sum_k |p_{k+1} - p_k|^2 / h`` (``W`` the track's mean
      width, ``h`` the station spacing; ``sum |dp|^2 / h`` is the path length for even
      stations, and ``1 / W^2`` makes ``w`` the same on a 1:43 track and a full-scale one);
      0 (default) is the pure minimum-curvature line. Ignored by ``"lap_time"``, which
      searches it.
    """

    margin: float = 0.01
    mu_min: float = 0.5
    mu_max: float = 1.0
    n_mu: int = 11
    mu_nominal: float = 1.0
    point_spacing: float = 0.05
    tol: float | None = None
    max_iter: int = 100
    smoothing: float = 1e-6
    linearization: str = "frozen"
    objective: str = "curvature"
    length_weight: float = 0.0

    def __post_init__(self):
        if self.linearization not in ("frozen", "exact"):
            raise ValueError(
                f"RacelineConfig.linearization must be 'frozen' or 'exact', "
                f"got {self.linearization!r}"
            )
        if self.objective not in OBJECTIVES:
            raise ValueError(
                f"RacelineConfig.objective must be one of {OBJECTIVES}, got {self.objective!r}"
            )
        for f in fields(self):
            if f.name in ("linearization", "objective") or (f.name == "tol" and self.tol is None):
                continue
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"RacelineConfig.{f.name} must be a finite number, got {v!r}")
        for name in ("n_mu", "max_iter"):
            v = getattr(self, name)
            if int(v) != v or v < (2 if name == "n_mu" else 1):
                raise ValueError(
                    f"RacelineConfig.{name} must be an integer >= "
                    f"{2 if name == 'n_mu' else 1}, got {v!r}"
                )
        for name in ("mu_min", "mu_max", "mu_nominal", "point_spacing", "tol"):
            if getattr(self, name) is not None and getattr(self, name) <= 0:
                raise ValueError(
                    f"RacelineConfig.{name} must be positive, got {getattr(self, name)!r}"
                )
        for name in ("margin", "smoothing", "length_weight"):
            if getattr(self, name) < 0:
                raise ValueError(f"RacelineConfig.{name} must be >= 0, got {getattr(self, name)!r}")
        if not self.mu_min < self.mu_max:
            raise ValueError(
                f"RacelineConfig needs mu_min < mu_max, got mu_min={self.mu_min!r}, "
                f"mu_max={self.mu_max!r}"
            )
        if not self.mu_min <= self.mu_nominal <= self.mu_max:
            raise ValueError(
                f"RacelineConfig.mu_nominal={self.mu_nominal!r} is outside "
                f"[mu_min, mu_max] = [{self.mu_min}, {self.mu_max}]"
            )

    def tol_for(self, track: Track) -> float:
        """The stopping tolerance [m] on ``track``: ``tol``, or ``TOL_PER_WIDTH`` times the
        track's mean width when ``tol`` is None."""
        if self.tol is not None:
            return float(self.tol)
        return TOL_PER_WIDTH * float(np.mean(track.width))

    @property
    def mus(self) -> np.ndarray:
        """Friction values of the speed library, sorted, shape (K,) with K in {n_mu, n_mu + 1}."""
        grid = np.linspace(self.mu_min, self.mu_max, int(self.n_mu))
        if np.min(np.abs(grid - self.mu_nominal)) > 1e-12:
            grid = np.sort(np.append(grid, self.mu_nominal))
        return grid


#: the modules whose code computes a racing line (this package, the envelope, the vehicle model
#: and the track geometry): an edit of any of them is a new cache key, so no stale line is loaded
SOURCES = (
    *sorted(Path(__file__).parent.glob("*.py")),
    *(Path(__file__).parents[1] / m for m in ("envelope.py", "vehicle.py", "track.py")),
)
_SOURCES_HASH = sources_hash(SOURCES)

#: the full-size class's own code (force law and envelope): part of its lines' keys only
FULLSIZE_SOURCES = tuple(
    Path(__file__).parents[1] / "vehicles" / m for m in ("fullsize.py", "fullsize_envelope.py")
)
_FULLSIZE_SOURCES_HASH = sources_hash(FULLSIZE_SOURCES)


def cache_key(track: Track, vehicle: AnyVehicle, config: RacelineConfig) -> str:
    """Hash [hex, 24 chars] of the track geometry, the vehicle parameters, the config and the
    code that computes the line (:data:`SOURCES`). A full-size car's key also names its class
    and hashes :data:`FULLSIZE_SOURCES`; an ORCA car's key is made of the same fields as before
    the class existed, so its cached lines stay valid."""
    if not isinstance(vehicle, (VehicleParams, FullSizeParams)):
        raise ValueError(
            f"vehicle must be a VehicleParams or a FullSizeParams, got {type(vehicle).__name__}"
        )
    fields_ = {
        "version": CACHE_VERSION,
        "sources": _SOURCES_HASH,
        "track": track.fingerprint(),
        "vehicle": vehicle.to_dict(),
        "config": asdict(config),
    }
    if isinstance(vehicle, FullSizeParams):
        fields_["vehicle_class"] = "fullsize"
        fields_["class_sources"] = _FULLSIZE_SOURCES_HASH
    blob = json.dumps(fields_, sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()[:24]
