"""What a benchmark is: the cars' roles and start regions, the :class:`BenchConfig`, and the
checks of agent specs that every race suite runs before its first race."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from experiments.infra.checks import check_counts

ROLES = ("ego", "O1", "O2")


REGIONS = ("R1", "R2", "R3")


def roles(n_cars: int = 3) -> tuple[str, ...]:
    """Names of the cars of an N-car benchmark: ``ego``, ``O1`` .. ``O(N-1)``."""
    return ("ego",) + tuple(f"O{k}" for k in range(1, n_cars))


def regions(n_cars: int = 3) -> tuple[str, ...]:
    """Start regions ``R1`` (front-most) .. ``RN``."""
    return tuple(f"R{k}" for k in range(1, n_cars + 1))


@dataclass(frozen=True)
class BenchConfig:
    """One head-to-head benchmark: ``ego`` (an agent spec) against ``n_cars - 1``
    ``opponents`` (one agent spec, used for O1, O2, ...) in ``races`` races of ``steps`` steps
    on ``track``. Race k's start positions and the agents' seeds come from ``(seed, k)``.
    With N != 3 cars, ``races`` must be a multiple of N (the ego starts from every region
    equally often); the paper's 3-car benchmark takes any count, as it always has.
    ``ego_regions`` (region names, e.g. ``("R2", "R3")``) replaces the ego's rotation through
    every region by a cycle through these (any race count; :meth:`order`).
    ``vehicle_class`` (``"orca"``, the paper's 1:43 car, or ``"fullsize"``) is the class the
    races are run in (the track built at its scale, the agents learn it from the track) and
    ``wake`` the wake's strength (None: the class's, 0 for ORCA and 1 full size; stored
    resolved). The paper's class without a wake is left out of :meth:`to_dict`."""

    ego: str = "alpha"
    opponents: str = "mpc"
    races: int = 99
    steps: int = 500
    track: str = "default"
    seed: int = 0
    n_cars: int = 3
    ego_regions: tuple[str, ...] | None = None
    vehicle_class: str = "orca"
    wake: float | None = None

    def __post_init__(self):
        check_counts(self, ("races", "steps"))
        check_class_wake(self)
        if isinstance(self.n_cars, bool) or not (
            isinstance(self.n_cars, int) and 2 <= self.n_cars <= 8
        ):
            raise ValueError(f"BenchConfig.n_cars must be an integer in 2..8, got {self.n_cars!r}")
        if self.ego_regions is not None:
            object.__setattr__(self, "ego_regions", tuple(self.ego_regions))
            bad = [r for r in self.ego_regions if r not in self.regions]
            if not self.ego_regions or bad:
                raise ValueError(
                    f"BenchConfig.ego_regions must be a non-empty sequence of "
                    f"start regions of {', '.join(self.regions)}, got "
                    f"{list(self.ego_regions)}"
                )
        elif self.n_cars != 3 and self.races % self.n_cars:
            raise ValueError(
                f"BenchConfig.races must be a multiple of n_cars = {self.n_cars} "
                f"(every start region equally often), got {self.races}"
            )
        check_spec_fields(self, ("ego", "opponents"))

    @property
    def agents(self) -> list[str]:
        return [self.ego] + [self.opponents] * (self.n_cars - 1)

    @property
    def roles(self) -> tuple[str, ...]:
        return roles(self.n_cars)

    @property
    def regions(self) -> tuple[str, ...]:
        return regions(self.n_cars)

    def to_dict(self) -> dict:
        """The config as stored in manifests and summaries; the 3-car default of ``n_cars``
        is left out, so the paper's benchmarks keep the manifests they always had."""
        d = asdict(self)
        if d["n_cars"] == 3:
            del d["n_cars"]
        if d["ego_regions"] is None:
            del d["ego_regions"]
        else:
            d["ego_regions"] = list(d["ego_regions"])
        return drop_default_class(d)

    def race_seed(self, k: int) -> int:
        return int(np.random.SeedSequence([self.seed, k]).generate_state(1)[0])

    @staticmethod
    def start_order(k: int, n_cars: int = 3) -> list[int]:
        """Start regions (0 = R1) of ego, O1, O2, ... in race k: the ego cycles R1 .. RN and
        the opponents take the other regions front to back (O1 the front-most)."""
        ego = k % n_cars
        return [ego] + [r for r in range(n_cars) if r != ego]

    def order(self, k: int) -> list[int]:
        """Start regions (0 = R1) of ego, O1, O2, ... in race k of this benchmark:
        :meth:`start_order`, or with ``ego_regions`` the ego in ``ego_regions[k mod len]``
        and the opponents in the other regions front to back."""
        if self.ego_regions is None:
            return self.start_order(k, self.n_cars)
        ego = self.regions.index(self.ego_regions[k % len(self.ego_regions)])
        return [ego] + [r for r in range(self.n_cars) if r != ego]


def class_wake(vehicle_class: str, wake) -> float:
    """The wake strength of a race of ``vehicle_class`` (``wake``, or the class's default when
    None: 0 for ``"orca"``, 1 for ``"fullsize"``); a ValueError naming a bad class or wake."""
    from racing_env.class_config import CLASS_DEFAULTS

    if vehicle_class not in CLASS_DEFAULTS:
        raise ValueError(
            f"vehicle_class must be one of {', '.join(CLASS_DEFAULTS)}, got {vehicle_class!r}"
        )
    if wake is None:
        return float(CLASS_DEFAULTS[vehicle_class]["wake"])
    if (
        isinstance(wake, bool)
        or not isinstance(wake, (int, float))
        or not np.isfinite(wake)
        or wake < 0
    ):
        raise ValueError(f"wake must be a finite number >= 0, got {wake!r}")
    return float(wake)


def check_class_wake(config) -> None:
    """Check ``config.vehicle_class`` and resolve ``config.wake`` (None: the class's) in place
    (a frozen dataclass)."""
    object.__setattr__(config, "wake", class_wake(config.vehicle_class, config.wake))


#: The paper's world ``(vehicle_class, wake)``: the 1:43 ORCA class without a wake.
PAPER_WORLD = ("orca", 0.0)


def drop_default_class(d: dict) -> dict:
    """Leave ``vehicle_class`` and ``wake`` out of a config's dict ``d`` (in place) while they
    are the paper's world (the ORCA class without a wake), so that its manifests and stored
    results keep the keys they always had; any other class or wake is recorded (a resume with
    another is then refused)."""
    if (d.get("vehicle_class"), d.get("wake")) == PAPER_WORLD:
        del d["vehicle_class"], d["wake"]
    return d


def check_spec_fields(config: object, names: Sequence[str]) -> None:
    """Raise a ValueError naming the first field of ``config`` among ``names`` that is not
    an agent spec string (a non-empty ``str``)."""
    for name in names:
        if not isinstance(getattr(config, name), str) or not getattr(config, name):
            raise ValueError(
                f"{type(config).__name__}.{name} must be an agent spec string, "
                f"got {getattr(config, name)!r}"
            )


def check_agent_specs(specs, tracks=(), vehicle_class: str = "orca") -> list:
    """Build each agent spec once, so a typo fails before any race starts; an agent with a
    ``check_track(track)`` method (``mpc:theta=best``: the track's entry in the best-theta
    table) checks each of ``tracks`` too, built at ``vehicle_class``'s scale (a typo in a
    track fails here too). Returns the agents built, one per spec of ``specs`` (a repeated
    spec's agent repeated), for :func:`~experiments.infra.artifacts.provenance`."""
    from agents import make_agent_spec
    from racing_env.tracks import make_track

    tracks = [make_track(t, vehicle_class=vehicle_class) for t in dict.fromkeys(tracks)]
    built = {}
    for spec in dict.fromkeys(specs):
        agent = built[spec] = make_agent_spec(spec)
        check = getattr(agent, "check_track", None)
        for track in tracks if check is not None else ():
            try:
                check(track)
            except ValueError as exc:
                raise ValueError(f"agent {spec!r}: {exc}") from None

    return [built[spec] for spec in specs]
