"""A closed race track: centre line, widths, arc length, heading, curvature, Frenet frame.

Conventions (used everywhere in the package):

* ``s``  arc length along the centre line [m]. Functions accept *unwrapped* ``s`` (any real
  number; ``s + k * length`` is the same place on lap ``k``).
* ``n``  lateral offset from the centre line [m], **left positive**.
* ``psi`` heading of the centre line [rad]; ``kappa`` its curvature [1/m], positive when the
  track turns left.
* ``w_left(s)``, ``w_right(s)``: distance from the centre line to the left / right edge [m],
  both positive. A car is on the track while ``-w_right(s) <= n <= w_left(s)``.

A :class:`Track` stores its geometry on a uniform arc-length grid (``ds`` about 1/200 of the
lap, at most a few cm) and a periodic cubic spline through it, so that positions, heading and
curvature are consistent with each other.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import overload

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial import cKDTree

from .interp import periodic_interp

MIN_POINTS = 8
"""Fewest centre-line points a track may be built from."""
STRAIGHT_KAPPA_LENGTHS = 0.01
"""``|kappa| * car length`` below which the track is a straight (a radius over 100 car
lengths: 470 m at full size): the pass report's sections and the wake space's hold."""


def _fail(msg: str) -> None:
    raise ValueError(msg)


def _cross2(u, v) -> float:
    """z-component of the cross product of two 2-D vectors."""
    return float(u[0] * v[1] - u[1] * v[0])


def _segments_intersect(p: np.ndarray) -> tuple[int, int] | None:
    """First pair (i, j) of non-adjacent segments of the closed polyline ``p`` (M, 2) that cross."""
    m = len(p)
    a, b = p, np.roll(p, -1, axis=0)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    # bounding-box prefilter via sort on x, then exact orientation test for candidates
    order = np.argsort(lo[:, 0])
    for idx, i in enumerate(order):
        for j in order[idx + 1 :]:
            if lo[j, 0] > hi[i, 0]:
                break
            if abs(i - j) <= 1 or abs(i - j) == m - 1:
                continue
            if lo[j, 1] > hi[i, 1] or hi[j, 1] < lo[i, 1]:
                continue
            d1 = _cross2(b[i] - a[i], a[j] - a[i])
            d2 = _cross2(b[i] - a[i], b[j] - a[i])
            d3 = _cross2(b[j] - a[j], a[i] - a[j])
            d4 = _cross2(b[j] - a[j], b[i] - a[j])
            if d1 * d2 < 0 and d3 * d4 < 0:
                return (int(min(i, j)), int(max(i, j)))
    return None


def validate_centerline(
    x: np.ndarray,
    y: np.ndarray,
    w_right: float | np.ndarray,
    w_left: float | np.ndarray,
    allow_crossing: bool = False,
) -> tuple[np.ndarray, ...]:
    """Check raw centre-line data and return it as float arrays with a repeated end point removed.

    Raises ``ValueError`` naming what is wrong and where (point index and coordinates).
    """
    arrays = []
    for name, a in (("x", x), ("y", y), ("w_right", w_right), ("w_left", w_left)):
        a = np.asarray(a, dtype=float)
        if a.ndim != 1:
            _fail(f"track {name} must be a 1-D array, got shape {a.shape}")
        arrays.append(a)
    x, y, w_right, w_left = arrays
    if not (len(x) == len(y) == len(w_right) == len(w_left)):
        _fail(
            f"track arrays differ in length: x {len(x)}, y {len(y)}, "
            f"w_right {len(w_right)}, w_left {len(w_left)}"
        )
    for name, a in (("x", x), ("y", y), ("w_right", w_right), ("w_left", w_left)):
        bad = np.flatnonzero(~np.isfinite(a))
        if bad.size:
            _fail(f"track {name} is not finite (NaN or inf) at point {bad[0]}: {a[bad[0]]}")
    if len(x) >= 2 and np.hypot(x[-1] - x[0], y[-1] - y[0]) < 1e-9:
        x, y, w_right, w_left = x[:-1], y[:-1], w_right[:-1], w_left[:-1]
    if len(x) < MIN_POINTS:
        _fail(f"track needs at least {MIN_POINTS} distinct centre-line points, got {len(x)}")
    for name, w in (("w_right", w_right), ("w_left", w_left)):
        bad = np.flatnonzero(w <= 0)
        if bad.size:
            _fail(
                f"track {name} must be positive; point {bad[0]} at "
                f"({x[bad[0]]:.3f}, {y[bad[0]]:.3f}) has {name} = {w[bad[0]]}"
            )
    seg = np.hypot(np.diff(x), np.diff(y))
    dup = np.flatnonzero(seg < 1e-9)
    if dup.size:
        _fail(
            f"track has repeated consecutive points at index {dup[0]} "
            f"({x[dup[0]]:.3f}, {y[dup[0]]:.3f})"
        )
    gap = np.hypot(x[-1] - x[0], y[-1] - y[0])
    typical = float(np.median(seg))
    if gap > 5.0 * typical:
        _fail(
            f"track is not closed: the last point ({x[-1]:.3f}, {y[-1]:.3f}) is {gap:.3f} m "
            f"from the first ({x[0]:.3f}, {y[0]:.3f}), over 5x the median point spacing "
            f"{typical:.3f} m"
        )
    hit = None if allow_crossing else _segments_intersect(np.column_stack([x, y]))
    if hit is not None:
        i, j = hit
        _fail(
            f"track centre line intersects itself: segment {i} starting at "
            f"({x[i]:.3f}, {y[i]:.3f}) crosses segment {j} starting at ({x[j]:.3f}, {y[j]:.3f}) "
            f"(for a circuit with a bridge pass allow_crossing=True)"
        )
    return x, y, w_right, w_left


def _narrow_tight(name, s_grid, kappa, w_l, w_r, limit=0.8):
    """Narrow the inner width to ``limit / |kappa|`` where it reaches further; warn."""
    import warnings

    with np.errstate(divide="ignore"):
        cap = limit / np.abs(kappa)
    new_l = np.where(kappa > 0, np.minimum(w_l, cap), w_l)
    new_r = np.where(kappa < 0, np.minimum(w_r, cap), w_r)
    cut = np.maximum(w_l - new_l, w_r - new_r)
    if cut.max() > 0:
        k = int(np.argmax(cut))
        warnings.warn(
            f"track '{name}': inner width narrowed at {int((cut > 0).sum())} grid points "
            f"(most, by {cut[k]:.3f} m, at s = {s_grid[k]:.2f} m) to keep it inside "
            f"{limit:.0%} of the radius of curvature",
            stacklevel=4,
        )
    return new_l, new_r


@dataclass(frozen=True, eq=False)
class Track:
    """A closed track sampled on a uniform arc-length grid.

    Build it with :meth:`Track.from_centerline`, a loader in :mod:`racing_env.tracks`, or
    :func:`racing_env.tracks.make_track`. Arrays all have shape (M,), one entry per grid point
    ``s_grid[k] = k * ds``; the grid does not repeat its first point.
    """

    name: str
    s_grid: np.ndarray
    x: np.ndarray
    y: np.ndarray
    psi: np.ndarray
    kappa: np.ndarray
    w_left: np.ndarray
    w_right: np.ndarray
    length: float
    _sx: CubicSpline = field(repr=False)
    _sy: CubicSpline = field(repr=False)
    _tree: cKDTree = field(repr=False)
    vehicle_class: str = "orca"
    """The vehicle class the track is sized for (``"orca"``, the 1:43 car, or ``"fullsize"``;
    set by :func:`racing_env.tracks.make_track`): a race refuses a car of another class."""

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_centerline(
        cls,
        x: np.ndarray,
        y: np.ndarray,
        w_right: float | np.ndarray,
        w_left: float | np.ndarray,
        name: str = "custom",
        ds: float | None = None,
        allow_crossing: bool = False,
        narrow_tight: bool = False,
    ) -> Track:
        """Build a track from a closed centre line (x, y) [m] with right/left widths [m].

        The points go around the track once (the first point may or may not be repeated at
        the end); the driving direction is the order of the points. ``ds`` is the grid spacing
        [m] (default: lap length / 1000, clipped to [0.005, 2.0] m).
        Raises ``ValueError`` for open, self-intersecting, too short, non-finite or
        non-positive-width input, and for a track whose inner edge lies beyond the centre of
        curvature (the Frenet frame would fold). ``allow_crossing`` accepts a centre line
        that crosses itself (a bridge, as at Suzuka). ``narrow_tight`` instead narrows the inner
        width where it would reach past 80% of the radius of curvature (real hairpins in
        surveyed data), with a warning saying where and by how much.
        """
        x, y, w_right, w_left = validate_centerline(x, y, w_right, w_left, allow_crossing)
        # periodic interpolating spline parametrised by chord length, then resampled by arc length
        pts = np.column_stack([x, y])
        chord = np.hypot(*np.diff(np.vstack([pts, pts[:1]]), axis=0).T)
        u = np.concatenate([[0.0], np.cumsum(chord)])
        closed = np.vstack([pts, pts[:1]])
        spx = CubicSpline(u, closed[:, 0], bc_type="periodic")
        spy = CubicSpline(u, closed[:, 1], bc_type="periodic")
        wr = CubicSpline(u, np.append(w_right, w_right[0]), bc_type="periodic")
        wl = CubicSpline(u, np.append(w_left, w_left[0]), bc_type="periodic")
        fine = np.linspace(0.0, u[-1], 20 * len(x) + 1)
        speed = np.hypot(spx(fine, 1), spy(fine, 1))
        arc = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(fine))])
        length = float(arc[-1])
        if ds is None:
            ds = float(np.clip(length / 1000.0, 0.005, 2.0))
        if not ds > 0:
            _fail(f"grid spacing ds must be positive, got {ds}")
        m = max(int(round(length / ds)), MIN_POINTS)
        s_grid = np.arange(m) * (length / m)
        u_of_s = np.interp(s_grid, arc, fine)
        gx, gy = spx(u_of_s), spy(u_of_s)
        w_r = np.maximum(wr(u_of_s), 1e-6)
        w_l = np.maximum(wl(u_of_s), 1e-6)
        return cls._from_grid(name, s_grid, gx, gy, w_l, w_r, length, narrow_tight)

    @classmethod
    def _from_grid(cls, name, s_grid, gx, gy, w_l, w_r, length, narrow_tight=False) -> Track:
        knots = np.append(s_grid, length)
        sx = CubicSpline(knots, np.append(gx, gx[0]), bc_type="periodic")
        sy = CubicSpline(knots, np.append(gy, gy[0]), bc_type="periodic")
        dx, dy = sx(s_grid, 1), sy(s_grid, 1)
        ddx, ddy = sx(s_grid, 2), sy(s_grid, 2)
        psi = np.unwrap(np.arctan2(dy, dx))
        kappa = (dx * ddy - dy * ddx) / np.maximum(np.hypot(dx, dy), 1e-12) ** 3
        if narrow_tight:
            w_l, w_r = _narrow_tight(name, s_grid, kappa, w_l, w_r)
        track = cls(
            name=name,
            s_grid=s_grid,
            x=gx,
            y=gy,
            psi=psi,
            kappa=kappa,
            w_left=w_l,
            w_right=w_r,
            length=float(length),
            _sx=sx,
            _sy=sy,
            _tree=cKDTree(np.column_stack([gx, gy])),
        )
        track._check_frenet_valid()
        return track

    def _check_frenet_valid(self) -> None:
        inner = np.where(self.kappa > 0, self.w_left, self.w_right)
        fold = inner * np.abs(self.kappa)
        k = int(np.argmax(fold))
        if fold[k] >= 1.0:
            _fail(
                f"track '{self.name}' is too tight at s = {self.s_grid[k]:.3f} m "
                f"(x = {self.x[k]:.3f}, y = {self.y[k]:.3f}): the inner width "
                f"{inner[k]:.3f} m exceeds the radius of curvature {1 / abs(self.kappa[k]):.3f} m"
            )

    # ------------------------------------------------------------------ properties
    @property
    def ds(self) -> float:
        """Grid spacing [m]."""
        return self.length / len(self.s_grid)

    @property
    def width(self) -> np.ndarray:
        """Total track width w_left + w_right [m], shape (M,)."""
        return self.w_left + self.w_right

    def fingerprint(self) -> str:
        """Short hash of the geometry (and of the vehicle class, unless ``"orca"``: the ORCA
        tracks' fingerprints are those of their geometry alone), for cache keys."""
        h = hashlib.sha1()
        for a in (self.x, self.y, self.w_left, self.w_right):
            h.update(np.ascontiguousarray(np.round(a, 9)).tobytes())
        if self.vehicle_class != "orca":
            h.update(f"vehicle_class={self.vehicle_class}".encode())
        return h.hexdigest()[:16]

    def for_class(self, vehicle_class: str) -> Track:
        """This track labelled for ``vehicle_class`` (the same geometry; itself if already)."""
        if vehicle_class == self.vehicle_class:
            return self
        from dataclasses import replace

        return replace(self, vehicle_class=vehicle_class)

    # ------------------------------------------------------------------ lookups
    # (the lookups return a float for a float ``s`` and an array for an array ``s``)
    @overload
    def wrap(self, s: float) -> float: ...
    @overload
    def wrap(self, s: np.ndarray) -> np.ndarray: ...
    def wrap(self, s: float | np.ndarray) -> float | np.ndarray:
        """Map unwrapped arc length to [0, length)."""
        return np.mod(s, self.length)

    @overload
    def interp(self, table: np.ndarray, s: float) -> float: ...
    @overload
    def interp(self, table: np.ndarray, s: np.ndarray) -> np.ndarray: ...
    def interp(self, table: np.ndarray, s: float | np.ndarray) -> float | np.ndarray:
        """Periodic linear interpolation of a grid table (M,) at (unwrapped) ``s`` [m], any
        shape (:func:`racing_env.interp.periodic_interp`)."""
        return periodic_interp(table, s, self.length, self.ds)

    @overload
    def curvature(self, s: float) -> float: ...
    @overload
    def curvature(self, s: np.ndarray) -> np.ndarray: ...
    def curvature(self, s: float | np.ndarray) -> float | np.ndarray:
        """kappa(s) [1/m] from the spline's second derivative, any shape of s."""
        sw = np.mod(np.asarray(s, dtype=float), self.length)
        dx, dy = self._sx(sw, 1), self._sy(sw, 1)
        ddx, ddy = self._sx(sw, 2), self._sy(sw, 2)
        return (dx * ddy - dy * ddx) / np.maximum(np.hypot(dx, dy), 1e-12) ** 3

    @overload
    def heading(self, s: float) -> float: ...
    @overload
    def heading(self, s: np.ndarray) -> np.ndarray: ...
    def heading(self, s: float | np.ndarray) -> float | np.ndarray:
        """psi(s) [rad] in (-pi, pi], any shape of s."""
        sw = np.mod(np.asarray(s, dtype=float), self.length)
        return np.arctan2(self._sy(sw, 1), self._sx(sw, 1))

    @overload
    def widths(self, s: float) -> tuple[float, float]: ...
    @overload
    def widths(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
    def widths(self, s: float | np.ndarray) -> tuple[float | np.ndarray, float | np.ndarray]:
        """(w_left(s), w_right(s)) [m]."""
        return self.interp(self.w_left, s), self.interp(self.w_right, s)

    def position(self, s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centre-line point (x, y) [m] at s (arrays of the shape of s)."""
        sw = np.mod(np.asarray(s, dtype=float), self.length)
        return self._sx(sw), self._sy(sw)

    # ------------------------------------------------------------------ Frenet <-> Cartesian
    # (floats for float arguments, arrays once one of ``s`` and ``n`` is an array)
    @overload
    def to_cartesian(self, s: float, n: float, mu: float | None = None) -> tuple[float, ...]: ...
    @overload
    def to_cartesian(
        self, s: np.ndarray, n: float | np.ndarray, mu: float | np.ndarray | None = None
    ) -> tuple[np.ndarray, ...]: ...
    @overload
    def to_cartesian(
        self, s: float | np.ndarray, n: np.ndarray, mu: float | np.ndarray | None = None
    ) -> tuple[np.ndarray, ...]: ...
    def to_cartesian(
        self, s: float | np.ndarray, n: float | np.ndarray, mu: float | np.ndarray | None = None
    ) -> tuple[float | np.ndarray, ...]:
        """Frenet (s, n[, mu]) -> Cartesian (x, y[, phi]); arrays broadcast together.

        ``mu`` is the heading relative to the centre line; ``phi = psi(s) + mu`` is returned
        wrapped to (-pi, pi] when ``mu`` is given.
        """
        s = np.asarray(s, dtype=float)
        n = np.asarray(n, dtype=float)
        sw = np.mod(s, self.length)
        tx, ty = self._sx(sw, 1), self._sy(sw, 1)
        norm = np.maximum(np.hypot(tx, ty), 1e-12)
        x = self._sx(sw) - n * ty / norm
        y = self._sy(sw) + n * tx / norm
        if mu is None:
            return x, y
        phi = np.arctan2(ty, tx) + np.asarray(mu, dtype=float)
        return x, y, np.arctan2(np.sin(phi), np.cos(phi))

    def to_frenet(
        self,
        x: float | np.ndarray,
        y: float | np.ndarray,
        phi: float | np.ndarray | None = None,
        s_hint: float | np.ndarray | None = None,
        window: float | None = None,
        k: int = 8,
    ) -> tuple[float | np.ndarray, ...]:
        """Cartesian (x, y[, phi]) -> Frenet (s, n[, mu]) by nearest-point projection.

        Robust on hairpins: the ``k`` nearest grid points are each refined by Newton steps on
        the spline and the closest refined foot point wins. With ``s_hint`` (unwrapped, same
        shape as x) and ``window`` [m], only foot points within ``window`` of the hint are
        accepted, and the returned ``s`` is unwrapped to the lap of the hint; without a hint
        ``s`` is in [0, length).
        """
        x = np.asarray(x, dtype=float)
        y = np.asarray(y, dtype=float)
        shape = np.broadcast(x, y).shape
        px, py = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
        kk = min(k, len(self.s_grid))
        _, idx = self._tree.query(np.column_stack([px, py]), k=kk)
        idx = idx.reshape(len(px), kk)
        cand = self.s_grid[idx]  # (P, k)
        qx, qy = px[:, None], py[:, None]
        for _ in range(4):  # Newton on (P - C(s)) . C'(s) = 0
            sw = np.mod(cand, self.length)
            cx, cy = self._sx(sw), self._sy(sw)
            dx, dy = self._sx(sw, 1), self._sy(sw, 1)
            ddx, ddy = self._sx(sw, 2), self._sy(sw, 2)
            ex, ey = qx - cx, qy - cy
            g = ex * dx + ey * dy
            h = dx * dx + dy * dy - (ex * ddx + ey * ddy)
            step = np.where(h > 1e-9, g / np.where(h > 1e-9, h, 1.0), g)
            cand = cand + np.clip(step, -self.ds, self.ds)
        sw = np.mod(cand, self.length)
        dist2 = (qx - self._sx(sw)) ** 2 + (qy - self._sy(sw)) ** 2
        if s_hint is not None:
            hint = np.broadcast_to(np.asarray(s_hint, dtype=float), shape).ravel()[:, None]
            delta = np.mod(sw - hint + 0.5 * self.length, self.length) - 0.5 * self.length
            if window is not None:
                dist2 = np.where(np.abs(delta) <= window, dist2, np.inf)
            sw_un = hint + delta
        best = np.argmin(dist2, axis=1)
        rows = np.arange(len(px))
        s_out = (sw_un if s_hint is not None else sw)[rows, best]
        if not np.all(np.isfinite(dist2[rows, best])):
            bad = int(np.flatnonzero(~np.isfinite(dist2[rows, best]))[0])
            _fail(
                f"no centre-line point within window {window} m of s_hint for point "
                f"({px[bad]:.3f}, {py[bad]:.3f})"
            )
        swb = np.mod(s_out, self.length)
        tx, ty = self._sx(swb, 1), self._sy(swb, 1)
        norm = np.maximum(np.hypot(tx, ty), 1e-12)
        n_out = ((px - self._sx(swb)) * -ty + (py - self._sy(swb)) * tx) / norm
        s_out, n_out = s_out.reshape(shape), n_out.reshape(shape)
        if phi is None:
            return s_out, n_out
        mu = np.asarray(phi, dtype=float) - np.arctan2(ty, tx).reshape(shape)
        return s_out, n_out, np.arctan2(np.sin(mu), np.cos(mu))

    # ------------------------------------------------------------------ edges
    @overload
    def edges(self, s: float) -> tuple[tuple[float, ...], tuple[float, ...]]: ...
    @overload
    def edges(
        self, s: np.ndarray | None = None
    ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]: ...
    def edges(
        self, s: float | np.ndarray | None = None
    ) -> tuple[tuple[float | np.ndarray, ...], tuple[float | np.ndarray, ...]]:
        """Left and right edge polylines: ((xl, yl), (xr, yr)) at s (default: the grid)."""
        s = self.s_grid if s is None else s
        wl, wr = self.widths(s)
        return self.to_cartesian(s, wl), self.to_cartesian(s, -wr)

    def __repr__(self) -> str:
        return (
            f"Track(name={self.name!r}, length={self.length:.3f} m, points={len(self.s_grid)}, "
            f"width {self.width.min():.3f}..{self.width.max():.3f} m)"
        )
