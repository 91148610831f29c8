"""The policy parameters theta and their spaces: the paper's ``(q, zeta, s1, s2, s3)``, the
extended space's ``b`` and the wake space's ``(h, p, c)``, with their bounds, units and
validation (:class:`Theta`, :class:`PolicySpace`). :mod:`agents.reference` builds the MPC
reference from a theta and re-exports these names."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = [
    "THETA_NAMES",
    "THETA_LOW",
    "THETA_HIGH",
    "THETA_UNITS",
    "THETA_BOUNDS_DOC",
    "Theta",
    "EXTENDED_NAMES",
    "EXTENDED_LOW",
    "EXTENDED_HIGH",
    "WAKE_NAMES",
    "WAKE_ONLY",
    "WAKE_LOW",
    "WAKE_HIGH",
    "PolicySpace",
    "SPACES",
    "policy_space",
    "space_of",
    "space_of_dim",
    "theta_length_scales",
    "MOVES",
    "check_moves",
    "move_items",
    "moved_thetas",
]

# ====================================================================== theta
THETA_NAMES = ("q", "zeta", "s1", "s2", "s3")
"""Names of the policy parameters, in array order."""

THETA_UNITS = ("-", "-", "m", "1/m^2", "s/m")
"""Units of the policy parameters, in array order."""

THETA_LOW = np.array([5.0, 0.8, 0.0, 0.5, 0.0])
THETA_HIGH = np.array([500.0, 1.05, 0.3, 20.0, 5.0])
THETA_LOW.setflags(write=False)
THETA_HIGH.setflags(write=False)
THETA_BOUNDS_DOC = """Bounds of theta (``THETA_LOW``, ``THETA_HIGH``) and why.

* ``q`` in [5, 500] [-]: ``Q = q I`` weighs squared position errors [m^2] against ``R = I`` on
  squared input-rate steps (throttle in [-1, 1], steering [rad], typical steps 0.01..0.1).
  A 5 cm error costs ``q * 2.5e-3``: at ``q = 5`` that equals a 0.1 input step (loose, smooth
  tracking), at ``q = 500`` a full-scale step (tight tracking that starts to oscillate, as the
  paper describes). Outside this range the MPC either ignores the reference or is badly
  conditioned.
* ``zeta`` in [0.8, 1.05] [-]: scale of the race-line speeds. The race line's nominal profile
  is the car's own g-g-v envelope (:mod:`racing_env.envelope`, ``mu = 1``), so ``zeta = 1``
  asks for the limit; measured alone for 50 s (MPC, q = 20) it drives with no off-track step
  and laps within 3% of the profile's estimate on ``default``, ``oval`` and procedural tracks.
  1.05 asks for 5% more than the car can hold: the MPC saturates there and still stays on
  the track (the top of the box is just beyond the limit, not a crash). Above it (1.08,
  1.12, 1.16, measured alone with the bound lifted on the four tracks of
  ``alpha-racer policy-map``) it laps no faster and covers 0.1-1.4 m less in 50 s, still on the
  track. 0.8 is a cautious 20% below the limit; slower policies only lose.
* ``s1`` in [0, 0.3] [m]: lateral clearance wanted from a neighbour when overtaking. 0 turns
  overtaking off; 0.3 m is more than half the 0.5 m wide built-in tracks (cars are 0.06 m
  wide), enough to ask for a full change of side.
* ``s2`` in [0.5, 20] [1/m^2]: the shifts decay like ``exp(-s2 ds^2)`` with the longitudinal
  gap ``ds``; the 1/e distance ``1/sqrt(s2)`` runs from 1.41 m (about the length of half a
  horizon at racing speed, K dt v = 1.5 s * 2..4 m/s) down to 0.22 m (two car lengths).
* ``s3`` in [0, 5] [s/m]: blocking moves the reference a fraction ``1 - exp(-s3 dv)`` of the
  lateral gap toward a faster car, ``dv`` [m/s] its speed advantage. 0 turns blocking off;
  with 5 a 0.1 m/s faster car draws 39 % of the gap, a 0.5 m/s faster one 92 %.
"""


def _check_theta_value(name: str, value: float, lo: float, hi: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"theta parameter {name} must be a number, got {value!r}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"theta parameter {name} = {v!r} is outside its bounds [{lo:g}, {hi:g}]")
    return v


@dataclass(frozen=True)
class Theta:
    """One car's policy parameters (see :data:`THETA_BOUNDS_DOC` for units and bounds).

    ``q`` [-] tracking weight, ``zeta`` [-] race-line speed scale, ``s1`` [m] overtaking
    clearance, ``s2`` [1/m^2] longitudinal decay, ``s3`` [s/m] blocking strength. Construction
    validates the bounds (``ValueError`` naming parameter, value and bounds).
    """

    q: float
    zeta: float
    s1: float
    s2: float
    s3: float
    b: float = 0.0
    h: float = 0.0
    p: float = 0.0
    c: float = 0.0

    __doc__ += "\n" + THETA_BOUNDS_DOC

    def __post_init__(self):
        for i, name in enumerate(WAKE_NAMES):
            v = _check_theta_value(name, getattr(self, name), WAKE_LOW[i], WAKE_HIGH[i])
            object.__setattr__(self, name, v)

    def as_array(self, space: str = "paper") -> np.ndarray:
        """The parameters of policy space ``space`` as a float array: ``[q, zeta, s1, s2, s3]``
        (shape (5,), ``"paper"``, the default), ``[q, zeta, s1, s2, s3, b]`` (shape (6,),
        ``"extended"``) or those and ``[h, p, c]`` (shape (9,), ``"wake"``). A theta with
        ``b > 0`` is not in the paper's space, one with ``h``, ``p`` or ``c`` not 0 in neither
        of the two (``ValueError``)."""
        dim = policy_space(space).dim
        if dim < len(WAKE_NAMES) and any(getattr(self, n) for n in WAKE_ONLY):
            raise ValueError(
                f"theta with h = {self.h!r}, p = {self.p!r}, c = {self.c!r} is outside the "
                f"{policy_space(space).name!r} space (its wake parameters are all 0)"
            )
        if dim == len(WAKE_NAMES):
            return np.array([getattr(self, n) for n in WAKE_NAMES], dtype=float)
        if dim == 5:
            if self.b != 0.0:
                raise ValueError(
                    f"theta with b = {self.b!r} is outside the paper's space "
                    f"(its race line is the minimum-curvature line, b = 0)"
                )
            return np.array([self.q, self.zeta, self.s1, self.s2, self.s3], dtype=float)
        return np.array([self.q, self.zeta, self.s1, self.s2, self.s3, self.b], dtype=float)

    @classmethod
    def from_array(cls, a: Sequence[float] | np.ndarray) -> Theta:
        """Theta from an array-like in :data:`THETA_NAMES` order (length 5, the paper's space),
        in the extended space's order (length 6, ``b`` last) or the wake space's (length 9);
        ``ValueError`` on a wrong shape or a value outside its bounds (naming parameter, value
        and bounds)."""
        if isinstance(a, Theta):
            return a
        arr = np.asarray(a, dtype=float)
        if arr.shape not in ((5,), (6,), (9,)):
            raise ValueError(
                f"theta must have shape (5,) {THETA_NAMES}, (6,) {EXTENDED_NAMES} or (9,) "
                f"{WAKE_NAMES}, got shape {arr.shape}"
            )
        return cls(*(float(x) for x in arr))

    @classmethod
    def sample(cls, rng: np.random.Generator | int | None = None) -> Theta:
        """Uniform sample within ``[THETA_LOW, THETA_HIGH]`` (``rng`` a Generator or a seed)."""
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        a = rng.uniform(THETA_LOW, THETA_HIGH)
        return cls.from_array(np.clip(a, THETA_LOW, THETA_HIGH))


# ====================================================================== policy spaces
EXTENDED_NAMES = THETA_NAMES + ("b",)
"""Names of the extended space's parameters: the paper's five, then ``b``."""
EXTENDED_LOW = np.append(THETA_LOW, 0.0)
EXTENDED_HIGH = np.append(THETA_HIGH, 1.0)
EXTENDED_LOW.setflags(write=False)
EXTENDED_HIGH.setflags(write=False)
WAKE_ONLY = ("h", "p", "c")
"""The wake space's own parameters (all 0 outside it)."""
WAKE_NAMES = EXTENDED_NAMES + WAKE_ONLY
"""Names of the wake space's parameters: the extended space's six, then ``h, p, c``."""
WAKE_LOW = np.append(EXTENDED_LOW, [0.0, 0.0, 0.0])
WAKE_HIGH = np.append(EXTENDED_HIGH, [10.0, 60.0, 1.0])
WAKE_LOW.setflags(write=False)
WAKE_HIGH.setflags(write=False)
WAKE_BOUNDS_DOC = """Bounds of the wake space's parameters (in car lengths, so that a theta names
the same behaviour in every class) and why.

* ``h`` in [0, 10] car lengths: hold the tow. While a car ahead is at most ``h`` lengths ahead
  (centre to centre) and under 1.5 widths aside, on a straight, and the next braking point is
  more than ``p`` lengths away, the reference's lateral target is that car's offset (the
  slipstream) and the overtake shift waits. 0 never holds (the extended space's
  behaviour); at 10 lengths (9 nose to tail) the wake's drag loss is 13% and its downforce
  loss 18% (:func:`racing_env.wake.wake_factors`, directly behind).
* ``p`` in [0, 60] car lengths: pull out. Within ``p`` lengths before the next braking point the
  hold lets go and the overtake shift (``s1``, ``s2``) applies; 60 lengths is 282 m at full
  size, 3.5 s at 80 m/s.
* ``c`` in [0, 1]: cover. Within ``p`` lengths before the next braking point, with a car behind
  under 15 lengths and 1.5 widths aside (in the ego's tow), the reference moves the fraction
  ``c`` of the way from its line to the inside of the coming corner (the car's body on the
  track). 0 never covers.
"""


@dataclass(frozen=True)
class PolicySpace:
    """A box of policy parameters: ``names`` (in array order), bounds ``low``/``high``
    (shape (dim,)) and ``units``.

    * ``"paper"``: the paper's ``(q, zeta, s1, s2, s3)``; the reference follows the
      minimum-curvature race line.
    * ``"extended"``: the paper's five and ``b`` in [0, 1] [-], the weight of the track's
      lap-time race line blended into the reference's path and speed (0: the paper's
      minimum-curvature line; 1: the lap-time line). The lap-time line is shorter where the
      car is motor-limited (above about 2.2 m/s), so a car on it drives another path than a
      car on the curvature line and gains there: that offset is where passes start
      (docs: "Policy spaces").
    * ``"wake"``: the extended space's six and ``(h, p, c)``: hold the tow, where to pull
      out before a braking point, and cover the inside (:data:`WAKE_BOUNDS_DOC`;
      :func:`agents.reference.reference_trajectory`, step 6). With ``h = c = 0`` a wake
      theta drives as the same extended theta.
    """

    name: str
    names: tuple
    low: np.ndarray
    high: np.ndarray
    units: tuple

    @property
    def dim(self) -> int:
        """Number of parameters."""
        return len(self.names)

    def theta(self, a: Sequence[float] | np.ndarray) -> Theta:
        """The :class:`Theta` of an array-like of shape (dim,) (``ValueError`` otherwise)."""
        arr = np.asarray(a, dtype=float)
        if arr.shape != (self.dim,):
            raise ValueError(
                f"a theta of the {self.name!r} space has shape ({self.dim},) "
                f"{self.names}, got shape {arr.shape}"
            )
        return Theta.from_array(arr)

    def array(self, theta: Theta) -> np.ndarray:
        """``theta``'s parameters in this space's order, shape (dim,)."""
        return theta.as_array(self.name)

    def sample(self, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """A uniform sample of the box, shape (dim,) (``rng`` a Generator or a seed)."""
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        return np.clip(rng.uniform(self.low, self.high), self.low, self.high)


SPACES = {
    "paper": PolicySpace("paper", THETA_NAMES, THETA_LOW, THETA_HIGH, THETA_UNITS),
    "extended": PolicySpace(
        "extended", EXTENDED_NAMES, EXTENDED_LOW, EXTENDED_HIGH, THETA_UNITS + ("-",)
    ),
    "wake": PolicySpace(
        "wake", WAKE_NAMES, WAKE_LOW, WAKE_HIGH, THETA_UNITS + ("-", "L", "L", "-")
    ),
}
"""The policy spaces by name."""


def space_of_dim(dim: int | None) -> PolicySpace | None:
    """The policy space of ``dim`` parameters (5 the paper's, 6 the extended one, 9 the wake
    space), ``None`` for another number."""
    for space in SPACES.values():
        if space.dim == dim:
            return space
    return None


def space_of(theta: Sequence[float] | np.ndarray) -> PolicySpace:
    """The policy space whose parameters an array-like ``theta`` holds (by its length: 5 the
    paper's, 6 the extended one, 9 the wake space); ``ValueError`` for another length."""
    n = len(theta)
    space = space_of_dim(n)
    if space is not None:
        return space
    raise ValueError(f"a theta has {sorted(s.dim for s in SPACES.values())} parameters, got {n}")


def policy_space(name: str | PolicySpace) -> PolicySpace:
    """The :class:`PolicySpace` called ``name`` (a PolicySpace is returned as is);
    ``ValueError`` naming the choices otherwise."""
    if isinstance(name, PolicySpace):
        return name
    try:
        return SPACES[name]
    except (KeyError, TypeError):
        raise ValueError(f"policy space must be one of {sorted(SPACES)}, got {name!r}") from None


# ====================================================================== vehicle classes
def theta_length_scales(vehicle: object | None) -> tuple[float, float, float]:
    """Factors ``(k_s1, k_s2, k_s3)`` that turn theta's lengths, given for the ORCA car (the
    box above), into ``vehicle``'s class: ``s1`` [m] times ``k_wid`` (clearance in car
    widths), ``s2`` [1/m^2] times ``1 / k_len^2`` (decay distance in car lengths), ``s3`` [s/m]
    times the ORCA car's top speed over ``vehicle``'s (blocking fraction per the same share
    of the top speed). ``(1, 1, 1)`` for the ORCA car or ``None``. The theta box itself is
    the same in every class, so a theta, a policy map or a potential names the same
    behaviour. (:func:`agents.mpc.config.class_scale` lists every length the class scales.)"""
    from racing_env.vehicle import VehicleParams

    if vehicle is None or isinstance(vehicle, VehicleParams):
        return 1.0, 1.0, 1.0
    return _class_factors(vehicle)


@functools.lru_cache(maxsize=16)
def _class_factors(vehicle: object) -> tuple[float, float, float]:
    """:func:`theta_length_scales` of a vehicle of another class than the ORCA car's (a
    frozen dataclass: computed once per vehicle, not once per decision)."""
    from racing_env.scaling import size_ratios
    from racing_env.vehicle import VehicleParams

    k_len, k_wid = size_ratios(vehicle)  # type: ignore[arg-type]
    top = vehicle.top_speed  # type: ignore[attr-defined]
    top = top() if callable(top) else top
    return k_wid, 1.0 / (k_len * k_len), VehicleParams().top_speed / float(top)


# ====================================================================== one-parameter moves
#: One-parameter moves of a theta, in the order :func:`moved_thetas` adds them (each a face or
#: a step of the box): no overtaking shift, tight tracking, 5% under the limit, blocking, a
#: sharper shift decay, the paper's line alone, a small shift, loose tracking. The rollout
#: oracle's candidates (:mod:`experiments.evaluation.oracle`) and the anchored alpha's
#: (:class:`agents.alpha_agent.AlphaAgent`, ``moves``) are a theta and its first few moves.
MOVES = ("s1=0", "q=500", "zeta=0.95", "s3=5", "s2=2", "b=0", "s1=0.1", "q=50")


def check_moves(moves: object) -> int:
    """``moves`` if it is a number of :data:`MOVES` (0..len(MOVES)), else a ValueError."""
    if isinstance(moves, bool) or not (isinstance(moves, int) and 0 <= moves <= len(MOVES)):
        raise ValueError(f"moves must be an integer in 0..{len(MOVES)}, got {moves!r}")
    return moves


def move_items(moves: int) -> list[tuple[str, str]]:
    """``(parameter, value)`` of each of the first ``moves`` of :data:`MOVES`, the value as
    written (``("s1", "0")``); a ValueError for ``moves`` outside 0..len(MOVES)."""
    return [(m.partition("=")[0], m.partition("=")[2]) for m in MOVES[: check_moves(moves)]]


def moved_thetas(theta: Theta, moves: int) -> list[Theta]:
    """``theta`` and ``theta`` with one parameter moved, for the first ``moves`` of
    :data:`MOVES` (nested: the list of ``moves = m`` is the start of that of ``m + 1``)."""
    return [theta] + [replace(theta, **{k: float(v)}) for k, v in move_items(moves)]
