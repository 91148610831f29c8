"""The racing line as a result: :class:`Raceline` (per-point arrays on the track grid, the
speed library, lookups at centre-line ``s``), its CSV and ``.npz`` forms and its plot."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, overload

import numpy as np

from ..envelope import grip_arg
from ..interp import periodic_interp
from ..track import Track
from .config import CACHE_VERSION
from .speed import lap_time_of

if TYPE_CHECKING:
    import os


CSV_COLUMNS = (
    "s_m",
    "x_m",
    "y_m",
    "psi_rad",
    "kappa_radpm",
    "vx_mps",
    "ax_mps2",
    "n_m",
    "s_track_m",
)
"""Column names (with units) of :meth:`Raceline.to_csv`."""

_ARRAYS = (
    "s",
    "x",
    "y",
    "psi",
    "kappa",
    "vx",
    "ax",
    "n",
    "s_track",
    "n_lo",
    "n_hi",
    "mus",
    "vx_lib",
    "ax_lib",
)
_SCALARS = (
    "length",
    "track_length",
    "mu_nominal",
    "lap_time",
    "iterations",
    "converged",
    "last_change",
    "cost",
    "cost_center",
    "compute_time",
    "length_weight",
)


@dataclass(eq=False)
class Raceline:
    """A racing line with its speed library. Per-point arrays have shape (M,), one entry per
    grid point of the track (``s_track == track.s_grid``), in driving order:

    * ``s`` [m] arc length along the racing line (``s[0] = 0``), ``length`` [m] its lap length;
    * ``x, y`` [m] position, ``psi`` [rad] heading (unwrapped), ``kappa`` [1/m] curvature
      (left turn positive);
    * ``vx`` [m/s] speed and ``ax`` [m/s^2] acceleration of the nominal profile
      (``mu = mu_nominal``); ``ax[k]`` is the constant acceleration from point k to k+1;
    * ``n`` [m] lateral offset from the centre line (left positive), ``s_track`` [m] centre-line
      arc length of each point, ``n_lo, n_hi`` [m] the target bounds of the offsets (edges minus half the car and the margin; the interpolated line may enter the margin by spline overshoot, well under 1 mm);
    * ``mus`` (K,) envelope scales of the library, ``vx_lib, ax_lib`` (K, M) their profiles.

    Scalars: ``track_length`` [m] (centre line), ``lap_time`` [s] of the nominal profile,
    ``iterations`` / ``converged`` / ``last_change`` [m] of the minimum-curvature iteration,
    ``cost`` / ``cost_center`` the integral of kappa^2 along the path [1/m] of line / centre
    line on the optimisation stations, ``compute_time`` [s]. ``from_cache`` tells whether it was loaded.
    """  # noqa: E501

    s: np.ndarray
    x: np.ndarray
    y: np.ndarray
    psi: np.ndarray
    kappa: np.ndarray
    vx: np.ndarray
    ax: np.ndarray
    n: np.ndarray
    s_track: np.ndarray
    n_lo: np.ndarray
    n_hi: np.ndarray
    mus: np.ndarray
    vx_lib: np.ndarray
    ax_lib: np.ndarray
    length: float
    track_length: float
    mu_nominal: float
    lap_time: float
    iterations: int
    converged: bool
    last_change: float
    cost: float
    cost_center: float
    compute_time: float
    length_weight: float = 0.0
    track_name: str = ""
    track_fingerprint: str = ""
    key: str = ""
    from_cache: bool = False
    track: Track | None = field(default=None, repr=False)
    # the cache format version of a line read by from_npz_dict (None: computed here)
    _meta_version: int | None = field(default=None, init=False, repr=False)

    # ------------------------------------------------------------------ checks
    def validate(self) -> None:
        """Raise ``ValueError`` if any array is non-finite or shapes disagree."""
        m = len(self.s)
        for name in _ARRAYS:
            a = getattr(self, name)
            if not np.all(np.isfinite(a)):
                raise ValueError(f"raceline {name} has non-finite values")
            want = (
                (len(self.mus), m)
                if name in ("vx_lib", "ax_lib")
                else (len(self.mus),)
                if name == "mus"
                else (m,)
            )
            if a.shape != want:
                raise ValueError(f"raceline {name} has shape {a.shape}, expected {want}")
        for name in _SCALARS:
            if not math.isfinite(float(getattr(self, name))):
                raise ValueError(f"raceline {name} is not finite: {getattr(self, name)!r}")
        if m < 2 or np.any(np.diff(self.s) <= 0) or self.length <= self.s[-1]:
            raise ValueError("raceline arc length s is not increasing")
        if np.any(self.vx <= 0) or np.any(self.vx_lib <= 0) or np.any(np.diff(self.mus) <= 0):
            raise ValueError("raceline speeds must be positive and mus increasing")

    # ------------------------------------------------------------------ lookups
    @property
    def ds(self) -> np.ndarray:
        """Segment lengths [m] along the racing line, shape (M,): ``ds[k] = s[k+1] - s[k]``."""
        return np.diff(np.append(self.s, self.length))

    def _interp(self, table: np.ndarray, s_track):
        """Periodic linear interpolation of a per-point table at (unwrapped) centre-line s."""
        m = len(self.s_track)
        # grid points hit their entry exactly (snap)
        return periodic_interp(
            table, s_track, self.track_length, per_metre=m / self.track_length, size=m, snap=1e-9
        )

    # (the *_at lookups return a float for a float ``s_track``, an array for an array)
    @overload
    def offset_at(self, s_track: float) -> float: ...
    @overload
    def offset_at(self, s_track: np.ndarray) -> np.ndarray: ...
    def offset_at(self, s_track: float | np.ndarray) -> float | np.ndarray:
        """Racing-line offset ``n`` [m] (left positive) at centre-line arc length ``s_track`` [m]
        (any shape, unwrapped allowed); same shape as ``s_track``."""
        return self._interp(self.n, s_track)

    def _check_grip(self, grip) -> float:
        grip_f = float(grip)
        lo, hi = float(self.mus[0]), float(self.mus[-1])
        if not (math.isfinite(grip_f) and lo - 1e-12 <= grip_f <= hi + 1e-12):
            raise ValueError(
                f"envelope scale grip={grip!r} is outside the speed library range [{lo}, {hi}]"
            )
        return min(max(grip_f, lo), hi)

    def profile(
        self, grip: float | None = None, *, mu: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(vx, ax)`` per point [m/s], [m/s^2] for envelope scale ``grip`` (default
        ``mu_nominal``), linearly interpolated between the library's neighbouring profiles;
        shapes (M,). ``mu``: deprecated name of ``grip``."""
        grip = grip_arg(grip, mu, "Raceline.profile")
        if grip is None:
            return self.vx, self.ax
        grip = self._check_grip(grip)
        hit = np.flatnonzero(np.abs(self.mus - grip) <= 1e-12)
        if hit.size:  # a library entry: exactly its profile
            return self.vx_lib[hit[0]], self.ax_lib[hit[0]]
        j = int(np.clip(np.searchsorted(self.mus, grip, side="right") - 1, 0, len(self.mus) - 2))
        w = (grip - self.mus[j]) / (self.mus[j + 1] - self.mus[j])
        vx = (1.0 - w) * self.vx_lib[j] + w * self.vx_lib[j + 1]
        ax = (1.0 - w) * self.ax_lib[j] + w * self.ax_lib[j + 1]
        return vx, ax

    @overload
    def speed_at(
        self, s_track: float, grip: float | None = None, *, mu: float | None = None
    ) -> float: ...
    @overload
    def speed_at(
        self, s_track: np.ndarray, grip: float | None = None, *, mu: float | None = None
    ) -> np.ndarray: ...
    def speed_at(
        self, s_track: float | np.ndarray, grip: float | None = None, *, mu: float | None = None
    ) -> float | np.ndarray:
        """Reference speed ``vx`` [m/s] at centre-line ``s_track`` [m] (any shape, unwrapped
        allowed) for envelope scale ``grip`` (scalar in ``[mus[0], mus[-1]]``, default
        ``mu_nominal``; ``mu``: its deprecated name). Raises ``ValueError`` for a ``grip``
        outside the library range."""
        return self._interp(self.profile(grip_arg(grip, mu, "Raceline.speed_at"))[0], s_track)

    @overload
    def accel_at(
        self, s_track: float, grip: float | None = None, *, mu: float | None = None
    ) -> float: ...
    @overload
    def accel_at(
        self, s_track: np.ndarray, grip: float | None = None, *, mu: float | None = None
    ) -> np.ndarray: ...
    def accel_at(
        self, s_track: float | np.ndarray, grip: float | None = None, *, mu: float | None = None
    ) -> float | np.ndarray:
        """Reference acceleration ``ax`` [m/s^2] at centre-line ``s_track`` (like :meth:`speed_at`)."""
        return self._interp(self.profile(grip_arg(grip, mu, "Raceline.accel_at"))[1], s_track)

    @overload
    def heading_at(self, s_track: float) -> float: ...
    @overload
    def heading_at(self, s_track: np.ndarray) -> np.ndarray: ...
    def heading_at(self, s_track: float | np.ndarray) -> float | np.ndarray:
        """Racing-line heading ``psi`` [rad], wrapped to (-pi, pi], at centre-line ``s_track`` [m]."""
        c = self._interp(np.cos(self.psi), s_track)
        sn = self._interp(np.sin(self.psi), s_track)
        return np.arctan2(sn, c)

    @overload
    def kappa_at(self, s_track: float) -> float: ...
    @overload
    def kappa_at(self, s_track: np.ndarray) -> np.ndarray: ...
    def kappa_at(self, s_track: float | np.ndarray) -> float | np.ndarray:
        """Racing-line curvature ``kappa`` [1/m] at centre-line ``s_track`` [m]."""
        return self._interp(self.kappa, s_track)

    def s_line_at(self, s_track: float | np.ndarray) -> float | np.ndarray:
        """Arc length along the racing line [m] at centre-line ``s_track`` [m], unwrapped the
        same way (``s_track + k * track_length`` maps to ``... + k * length``)."""
        s_track = np.asarray(s_track, dtype=float)
        lap = np.floor(s_track / self.track_length)
        s_ext = np.append(self.s, self.length)
        st_ext = np.append(self.s_track, self.track_length)
        return lap * self.length + np.interp(s_track - lap * self.track_length, st_ext, s_ext)

    def lap_time_at(self, grip: float | None = None, *, mu: float | None = None) -> float:
        """Lap time [s] of the profile for envelope scale ``grip`` (default ``mu_nominal``;
        ``mu``: its deprecated name)."""
        return lap_time_of(self.profile(grip_arg(grip, mu, "Raceline.lap_time_at"))[0], self.ds)

    # ------------------------------------------------------------------ output
    def to_csv(self, path: str | os.PathLike) -> Path:
        """Write the nominal racing line as CSV (columns :data:`CSV_COLUMNS`, units in the names:
        ``_m`` metres, ``_rad`` radians, ``_radpm`` 1/m, ``_mps`` m/s, ``_mps2`` m/s^2)."""
        path = Path(path)
        data = np.column_stack(
            [self.s, self.x, self.y, self.psi, self.kappa, self.vx, self.ax, self.n, self.s_track]
        )
        if not np.all(np.isfinite(data)):
            raise ValueError("refusing to write a racing line with non-finite values")
        header = (
            f"racing line of track '{self.track_name}' ({self.track_fingerprint}), "
            f"mu = {self.mu_nominal}, length {self.length:.4f} m, lap time {self.lap_time:.4f} s\n"
            + ",".join(CSV_COLUMNS)
        )
        np.savetxt(path, data, delimiter=",", header=header, fmt="%.9g")
        return path

    def plot(
        self,
        path: str | os.PathLike,
        track: Track | None = None,
        grip: float | None = None,
        *,
        mu: float | None = None,
    ) -> Path:
        """Write a PNG of the track edges, centre line and racing line coloured by speed."""
        on = track if track is not None else self.track
        if on is None:
            raise ValueError("Raceline.plot: give the track (none is attached to this line)")
        return plot_raceline(
            on,
            self,
            path,
            grip=grip_arg(grip, mu, "Raceline.plot"),
        )

    def to_npz_dict(self) -> dict:
        """Arrays and metadata for :func:`numpy.savez` (no objects, loadable without pickle)."""
        d = {name: np.asarray(getattr(self, name), dtype=float) for name in _ARRAYS}
        for name in _SCALARS:
            d[name] = np.asarray(float(getattr(self, name)))
        meta = dict(
            track_name=self.track_name,
            track_fingerprint=self.track_fingerprint,
            key=self.key,
            version=CACHE_VERSION,
        )
        d["meta"] = np.asarray(json.dumps(meta))
        return d

    @classmethod
    def from_npz_dict(cls, d: dict) -> Raceline:
        """Inverse of :meth:`to_npz_dict`; raises ``ValueError``/``KeyError`` on bad content."""
        meta = json.loads(str(d["meta"][()]))
        kw: dict[str, Any] = {name: np.array(d[name], dtype=float) for name in _ARRAYS}
        for name in _SCALARS:
            kw[name] = float(d[name][()])
        kw["iterations"] = int(kw["iterations"])
        kw["converged"] = bool(kw["converged"])
        rl = cls(
            **kw,
            track_name=str(meta["track_name"]),
            track_fingerprint=str(meta["track_fingerprint"]),
            key=str(meta["key"]),
        )
        rl._meta_version = meta.get("version")
        rl.validate()
        return rl

    def __repr__(self) -> str:
        return (
            f"Raceline(track={self.track_name!r}, points={len(self.s)}, length={self.length:.3f} m, "
            f"lap_time={self.lap_time:.3f} s at mu={self.mu_nominal}, "
            f"v {self.vx.min():.2f}..{self.vx.max():.2f} m/s, iterations={self.iterations}, "
            f"converged={self.converged})"
        )


def plot_raceline(
    track: Track,
    raceline: Raceline,
    path: str | os.PathLike,
    grip: float | None = None,
    dpi: int = 150,
    *,
    mu: float | None = None,
) -> Path:
    """Write a PNG [path] of the track edges, the centre line and the racing line coloured by
    speed [m/s] (profile for envelope scale ``grip``, default nominal; ``mu``: its deprecated name). Uses matplotlib's Agg canvas directly, so
    it never touches the global backend."""  # noqa: E501
    if track is None:
        raise ValueError("plot_raceline needs the track (raceline.track is not set)")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    path = Path(path)
    grip = grip_arg(grip, mu, "plot_raceline")
    vx = raceline.profile(grip)[0]
    fig = Figure(figsize=(8, 6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    (xl, yl), (xr, yr) = track.edges()
    close = lambda a: np.append(a, a[0])
    ax.plot(close(xl), close(yl), color="0.2", lw=1.0)
    ax.plot(close(xr), close(yr), color="0.2", lw=1.0)
    ax.plot(close(track.x), close(track.y), color="0.6", lw=0.8, ls="--", label="centre line")
    pts = np.column_stack([close(raceline.x), close(raceline.y)])
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(list(segs), cmap="viridis", linewidths=2.0)
    lc.set_array(0.5 * (vx + np.roll(vx, -1)))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed [m/s]")
    ax.plot(raceline.x[0], raceline.y[0], "r>", ms=8, label="start")
    grip_txt = raceline.mu_nominal if grip is None else float(grip)
    ax.set_title(
        f"{raceline.track_name}: racing line, grip = {grip_txt:g}, "
        f"lap {lap_time_of(vx, raceline.ds):.2f} s"
    )
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return path
