"""Track sources: the built-in circuits, a seeded procedural generator, and the TUMFTM CSV loader.

* ``make_track("default")`` is our own circuit (about 33 m of 0.5 m wide track, sized for the
  1:43 cars of :mod:`racing_env.vehicle`): a long straight, a hairpin, a chicane, fast
  sweepers and a few medium corners.
* ``make_track("oval")`` a simple oval, handy for tests.
* ``make_track("random:SEED")`` / :func:`random_track` a random closed track from a seed.
* ``load_tumftm_csv(path, scale=...)`` reads the TUMFTM racetrack-database format
  (``# x_m,y_m,w_tr_right_m,w_tr_left_m``); ``make_track("tumftm:NAME")`` a circuit of the
  database, found by :func:`tumftm_file`.

Tracks are sized for a vehicle class (:data:`VEHICLE_CLASSES`): ``"orca"``, the paper's 1:43
car (the default, unchanged), or ``"fullsize"``, a full-size car (4.7 m x 2.0 m).
``make_track(spec, vehicle_class="fullsize")`` gives the real circuits at full scale
(:func:`track_scale`: 1/43 for ``"orca"``, 1 for ``"fullsize"``) and procedural tracks of
realistic size (:data:`RANDOM_TRACKS`: 4.5 km long and 12 m wide instead of 30 m and 0.5 m).
The built-in ``default`` and ``oval`` exist for the ``"orca"`` class only.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .track import Track
from .vehicles import VEHICLE_CLASSES as _VEHICLE_CLASSES

DEFAULT_HALF_WIDTH = 0.25
"""Half width [m] of the built-in tracks: 0.5 m fits three 0.06 m wide cars abreast with room."""

# The default circuit as (kind, length or angle, radius) pieces, driven counter-clockwise.
# Angles in degrees (left positive); the two "close" straights get the lengths that close the loop.
_DEFAULT_LAYOUT = (
    ("straight", "close", None),  # main straight (start/finish at s = 0)
    ("arc", 180.0, 0.8),  # hairpin
    ("straight", 2.0, None),
    ("arc", -60.0, 2.5),  # fast right sweeper
    ("straight", "close", None),
    ("arc", 60.0, 2.5),  # fast left sweeper
    ("straight", 1.0, None),
    ("arc", -40.0, 0.8),  # chicane
    ("arc", 80.0, 0.8),
    ("arc", -40.0, 0.8),
    ("straight", 1.5, None),
    ("arc", 90.0, 1.2),  # medium left
    ("straight", 1.0, None),
    ("arc", -90.0, 1.0),  # tight right
    ("arc", 150.0, 1.1),  # long left onto the straight
    ("straight", 1.0, None),
    ("arc", 30.0, 2.0),
)


def _layout_geometry(layout, close_lengths=None, ds=0.01):
    """Integrate a piece list into (x, y). Returns points and the closure displacement."""
    heading, pos, pts = 0.0, np.zeros(2), []
    k_close = 0
    for kind, a, r in layout:
        if kind == "straight":
            length = close_lengths[k_close] if a == "close" else a
            k_close += a == "close"
            kap = 0.0
        else:
            length = abs(np.deg2rad(a)) * r
            kap = np.sign(a) / r
        m = max(int(np.ceil(length / ds)), 1)
        h = length / m
        for _ in range(m):
            pts.append(pos.copy())
            # exact arc step
            if kap == 0.0:
                pos = pos + h * np.array([np.cos(heading), np.sin(heading)])
            else:
                new = heading + kap * h
                pos = (
                    pos
                    + np.array([np.sin(new) - np.sin(heading), np.cos(heading) - np.cos(new)]) / kap
                )
                heading = new
    return np.array(pts), pos


def _solve_closure(layout):
    """Lengths of the 'close' straights (two of them) that bring the loop back to its start."""
    base_len = np.zeros(2)
    _, end0 = _layout_geometry(layout, base_len)
    cols = []
    for k in range(2):
        e = np.zeros(2)
        e[k] = 1.0
        _, end = _layout_geometry(layout, e)
        cols.append(end - end0)
    lengths = np.linalg.solve(np.column_stack(cols), -end0)
    if np.any(lengths <= 0):
        raise ValueError(f"track layout cannot be closed with positive straights: {lengths}")
    return lengths


def default_track(half_width: float = DEFAULT_HALF_WIDTH) -> Track:
    """The built-in default circuit (counter-clockwise, constant width 2 * half_width)."""
    lengths = _solve_closure(_DEFAULT_LAYOUT)
    pts, _ = _layout_geometry(_DEFAULT_LAYOUT, lengths, ds=0.05)
    pts = _smooth_closed(pts, window=9)
    w = np.full(len(pts), half_width)
    return Track.from_centerline(pts[:, 0], pts[:, 1], w, w, name="default")


def oval_track(
    straight: float = 6.0, radius: float = 1.5, half_width: float = DEFAULT_HALF_WIDTH
) -> Track:
    """A stadium oval: two straights of ``straight`` m joined by half circles of ``radius`` m."""
    layout = (
        ("straight", straight, None),
        ("arc", 180.0, radius),
        ("straight", straight, None),
        ("arc", 180.0, radius),
    )
    pts, _ = _layout_geometry(layout, ds=0.05)
    pts = _smooth_closed(pts, window=5)
    w = np.full(len(pts), half_width)
    return Track.from_centerline(pts[:, 0], pts[:, 1], w, w, name="oval")


def _smooth_closed(pts: np.ndarray, window: int) -> np.ndarray:
    """Circular moving average: softens curvature jumps between pieces (clothoid-like)."""
    kernel = np.ones(window) / window
    pad = window // 2
    out = np.empty_like(pts)
    for d in range(2):
        ext = np.concatenate([pts[-pad:, d], pts[:, d], pts[:pad, d]])
        out[:, d] = np.convolve(ext, kernel, mode="valid")
    return out


def random_track(
    seed: int,
    length: float = 30.0,
    half_width: float = DEFAULT_HALF_WIDTH,
    n_control: int | None = None,
    max_tries: int = 50,
    control_range: tuple[int, int] = (8, 14),
) -> Track:
    """A random closed track from ``seed``: a star-shaped loop of random radii, smoothed.

    The loop is scaled to ``length`` m (approximately) and redrawn until the inner edge stays
    clear of every centre of curvature (tightest radius > 1.5 * half_width). Same seed, same
    track. The loop has ``n_control`` control points, or a random number in
    ``[control_range[0], control_range[1])``: more points, more and tighter corners for the
    length (:data:`RANDOM_TRACKS` holds each vehicle class's settings).
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"random track seed must be a non-negative integer, got {seed!r}")
    if length <= 0 or half_width <= 0:
        raise ValueError(
            f"random_track needs positive length and half_width, got {length}, {half_width}"
        )
    if not (len(control_range) == 2 and 3 <= control_range[0] < control_range[1]):
        raise ValueError(
            f"random_track control_range must be (low, high) with 3 <= low < high, "
            f"got {control_range!r}"
        )
    rng = np.random.default_rng(seed)
    for _ in range(max_tries):
        k = n_control or int(rng.integers(control_range[0], control_range[1]))
        angles = np.sort(rng.uniform(0, 2 * np.pi, k))
        angles += np.linspace(0, 2 * np.pi, k, endpoint=False) - angles  # keep ordered,
        angles += rng.uniform(-0.3, 0.3, k) * (2 * np.pi / k)  # jittered spacing
        radii = rng.uniform(0.55, 1.0, k)
        # periodic spline through control points, densely sampled
        from scipy.interpolate import CubicSpline

        t = np.append(angles, angles[0] + 2 * np.pi)
        r = np.append(radii, radii[0])
        spr = CubicSpline(t, r, bc_type="periodic")
        th = np.linspace(angles[0], angles[0] + 2 * np.pi, 400, endpoint=False)
        rr = spr(th)
        if np.any(rr <= 0.1):
            continue
        pts = np.column_stack([rr * np.cos(th), rr * np.sin(th)])
        perim = np.sum(np.hypot(*np.diff(np.vstack([pts, pts[:1]]), axis=0).T))
        pts *= length / perim
        w = np.full(len(pts), half_width)
        try:
            track = Track.from_centerline(pts[:, 0], pts[:, 1], w, w, name=f"random:{seed}")
        except ValueError:
            continue
        if np.max(np.abs(track.kappa)) * half_width * 1.5 < 1.0:
            return track
    raise ValueError(
        f"random_track(seed={seed}) found no valid track in {max_tries} tries; "
        f"try a larger length ({length}) or smaller half_width ({half_width})"
    )


VEHICLE_CLASSES = tuple(_VEHICLE_CLASSES)
"""Vehicle classes the tracks are sized for (the names of :data:`racing_env.vehicles.VEHICLE_CLASSES`):
``"orca"``, the paper's 1:43 car (0.12 m x 0.06 m, the default), and ``"fullsize"``, a
full-size car (4.7 m x 2.0 m)."""

TUMFTM_SCALES = {"orca": 1 / 43, "fullsize": 1.0}
"""Scale of the TUMFTM circuits (surveyed at full size) for each vehicle class."""


@dataclass(frozen=True)
class RandomTrackConfig:
    """Size of the procedural tracks ``random:SEED`` of a vehicle class (see
    :func:`random_track`): lap ``length`` [m], constant ``half_width`` [m] and the range of the
    number of control points ``control_range`` (low inclusive, high exclusive)."""

    length: float
    half_width: float
    control_range: tuple[int, int]


RANDOM_TRACKS = {
    "orca": RandomTrackConfig(length=30.0, half_width=DEFAULT_HALF_WIDTH, control_range=(8, 14)),
    "fullsize": RandomTrackConfig(length=4500.0, half_width=6.0, control_range=(14, 20)),
}
"""Procedural tracks per vehicle class. ``"orca"``: the paper's 30 m x 0.5 m (250 car lengths,
8 car widths). ``"fullsize"``: 4.5 km x 12 m (about 960 car lengths, 6 car widths, like the
F1 circuits of the TUMFTM database: 4.3-7 km, 9-14 m wide), with 14-19 control points so that
the tightest corners have radii of 12-70 m (median about 26 m over seeds 0-29) rather than the
100-250 m that the ORCA layout scaled to 4.5 km would give."""


def _check_class(vehicle_class: str) -> str:
    if vehicle_class not in VEHICLE_CLASSES:
        raise ValueError(
            f"unknown vehicle class {vehicle_class!r}; expected one of {VEHICLE_CLASSES}"
        )
    return vehicle_class


def track_scale(vehicle_class: str = "orca") -> float:
    """Scale of the real (TUMFTM) circuits for ``vehicle_class``: 1/43 for ``"orca"`` (the
    paper's 1:43 car), 1.0 for ``"fullsize"``."""
    return TUMFTM_SCALES[_check_class(vehicle_class)]


def load_tumftm_csv(
    path: str | os.PathLike,
    scale: float = 1.0,
    name: str | None = None,
    allow_crossing: bool = False,
    narrow_tight: bool = True,
) -> Track:
    """Load a TUMFTM racetrack-database CSV (``# x_m,y_m,w_tr_right_m,w_tr_left_m``).

    ``scale`` multiplies every length (positions and widths), so a full-size circuit can host
    the small default cars, e.g. ``scale=1/43``. Surveyed hairpins often put the inner edge
    at the centre of curvature, which the Frenet frame cannot represent: ``narrow_tight``
    (default) narrows the inner width there, with a warning (see
    :meth:`Track.from_centerline`). ``allow_crossing`` accepts a circuit with a bridge.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"track file not found: {path}")
    if not scale > 0:
        raise ValueError(f"scale must be positive, got {scale}")
    try:
        data = np.loadtxt(path, delimiter=",", comments="#", ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{path}: not a TUMFTM track CSV ({exc})") from None
    if data.shape[1] != 4:
        raise ValueError(
            f"{path}: expected 4 columns x_m,y_m,w_tr_right_m,w_tr_left_m, got {data.shape[1]}"
        )
    data = data * scale
    return Track.from_centerline(
        data[:, 0],
        data[:, 1],
        data[:, 2],
        data[:, 3],
        name=name or path.stem,
        allow_crossing=allow_crossing,
        narrow_tight=narrow_tight,
    )


def _database_dirs() -> list[Path]:
    """Candidate folders of the whole TUMFTM database, in lookup order (existing or not)."""
    env = os.environ.get("ALPHA_RACER_TUMFTM")
    cands = [Path(env)] if env else []
    here = Path(__file__).resolve()
    cands += [p / "shared" / "tracks" / "tumftm" for p in here.parents[:4]]
    try:
        from .circuits.download import default_dest

        cands.append(default_dest())
    except OSError:  # no writable cache folder at all: no downloads either
        pass
    return cands


def tumftm_dir() -> Path | None:
    """The first folder of the whole TUMFTM database that exists (see :func:`tumftm_dirs`,
    the shipped circuits excluded), or None."""
    for c in _database_dirs():
        if c.is_dir():
            return c
    return None


def tumftm_dirs() -> list[Path]:
    """The existing folders that ``tumftm:NAME`` is looked up in, in this order:

    1. ``$ALPHA_RACER_TUMFTM``, if set (a folder of TUMFTM CSVs of your choice);
    2. ``shared/tracks/tumftm`` beside a repository checkout (the project's copy of the
       database: the tests and the published results use it);
    3. ``<cache folder>/tumftm``, where :func:`racing_env.circuits.download.download_racetrack_database`
       stores the database (``alpha-racer circuits download``);
    4. the circuits shipped with the package, ``racing_env/circuits/`` (Monza, Spa,
       Silverstone, Catalunya, Spielberg).

    2, 3 and 4 hold byte-identical files (checked by the download's SHA-256 table and the
    tests), so a circuit is the same track wherever it is found. A name missing from one
    folder is looked up in the next.
    """
    from .circuits import shipped_dir

    found = []
    for c in [*_database_dirs(), shipped_dir()]:
        if c.is_dir() and c not in found:
            found.append(c)
    return found


def _shipped() -> tuple[str, ...]:
    from .circuits import SHIPPED

    return SHIPPED


def tumftm_file(name: str) -> Path | None:
    """``NAME.csv`` in the first of :func:`tumftm_dirs` that holds it, or None."""
    if not name or "/" in name or "\\" in name or name.startswith("."):
        return None
    for d in tumftm_dirs():
        if (d / f"{name}.csv").is_file():
            return d / f"{name}.csv"
    return None


CROSSING_CIRCUITS = {"Suzuka"}
"""TUMFTM circuits whose centre line crosses itself on a bridge (contact uses Frenet
distance, so cars on the bridge and under it do not touch)."""

BUILTIN: dict[str, Callable[[], Track]] = {"default": default_track, "oval": oval_track}


def track_names() -> list[str]:
    """Names accepted by :func:`make_track` (plus ``random:SEED`` and TUMFTM names/paths)."""
    names = sorted(BUILTIN)
    circuits = {p.stem for d in tumftm_dirs() for p in d.glob("*.csv")}
    names += [f"tumftm:{name}" for name in sorted(circuits)]
    return names


_CACHE: dict[tuple, Track] = {}


def make_track(
    spec: str | Track, scale: float | None = None, vehicle_class: str | None = None
) -> Track:
    """Build a track from a name: ``default``, ``oval``, ``random:SEED``, ``tumftm:NAME``
    (a circuit of the TUMFTM database, found by :func:`tumftm_file`) or a path to a TUMFTM CSV
    file. A :class:`Track` is returned unchanged. Results are memoised per process.
    The track's ``vehicle_class`` is the class it was built for (the fingerprint of a
    full-size track differs from the same geometry's for ORCA).

    ``vehicle_class`` (default ``"orca"``, the paper's 1:43 car; or ``"fullsize"``) sizes the
    track for that class: ``tumftm:NAME`` at :func:`track_scale` (1/43 or full size) unless
    ``scale`` is given, ``random:SEED`` with the class's :data:`RANDOM_TRACKS` settings. The
    built-in ``default`` and ``oval`` are ORCA tracks only; a CSV path is read at ``scale``
    (default 1, its own metres) for any class.
    """
    if isinstance(spec, Track):
        return spec
    if not isinstance(spec, str):
        raise ValueError(f"track must be a name or a Track, got {type(spec).__name__}")
    cls = _check_class("orca" if vehicle_class is None else vehicle_class)
    key = (spec, scale) if cls == "orca" else (spec, scale, cls)
    if key in _CACHE:
        return _CACHE[key]
    if spec in BUILTIN:
        if cls != "orca":
            raise ValueError(
                f"the built-in track {spec!r} is sized for the 'orca' class (1:43 cars); "
                f"for {cls!r} use 'random:SEED' or 'tumftm:NAME'"
            )
        track = BUILTIN[spec]()
    elif spec.startswith("random:"):
        try:
            seed = int(spec.split(":", 1)[1])
        except ValueError:
            seed = -1
        if seed < 0:
            raise ValueError(
                f"random track seed must be a non-negative integer, e.g. 'random:3', got {spec!r}"
            )
        rc = RANDOM_TRACKS[cls]
        track = random_track(
            seed, length=rc.length, half_width=rc.half_width, control_range=rc.control_range
        )
    elif spec.startswith("tumftm:"):
        name = spec.split(":", 1)[1]
        path = tumftm_file(name)
        if path is None:
            folders = ", ".join(str(d) for d in tumftm_dirs()) or "none"
            raise ValueError(
                f"TUMFTM track {name!r} not found (folders: {folders}); the package ships "
                f"tumftm:{', tumftm:'.join(_shipped())}: for the others run "
                f"'alpha-racer circuits download' or set ALPHA_RACER_TUMFTM to the "
                f"racetrack-database tracks folder"
            )
        track = load_tumftm_csv(
            path, scale=scale or track_scale(cls), allow_crossing=name in CROSSING_CIRCUITS
        )
    elif spec.endswith(".csv"):
        track = load_tumftm_csv(spec, scale=scale or 1.0)
    else:
        raise ValueError(
            f"unknown track {spec!r}; expected one of {sorted(BUILTIN)}, "
            f"'random:SEED', 'tumftm:NAME' or a .csv path"
        )
    track = track.for_class(cls)
    _CACHE[key] = track
    return track
