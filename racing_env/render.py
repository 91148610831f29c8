"""Rendering of races in the env's two render modes: RGB frames and a window.

* :class:`Renderer` turns a race state into an RGB image ``(height, width, 3)`` uint8. The
  static background (grass, track surface, edge lines, start/finish line at ``s = 0``,
  optional racing line) is drawn once with PIL when the renderer is built; each frame only
  copies it and draws the cars (rotated rectangles, one colour per car index from
  :data:`CAR_COLORS`), optional labels and a HUD.
* :class:`HumanViewer` shows frames in a matplotlib window (``render_mode="human"``); without a
  display it warns once and only keeps the last frame.

The colours and drawing primitives are in :mod:`racing_env.draw`, the writing of animations
(:func:`save_animation`) in :mod:`racing_env.animation`, the trajectory plot
(:func:`plot_trajectories`) in :mod:`racing_env.trajectory_plot`; their public names are
re-exported here, so ``from racing_env.render import save_animation`` keeps working.

Conventions: world coordinates in metres, ``y`` up; pixel coordinates ``(u, v)`` are
(column, row) with the origin at the top-left corner of the image, ``v`` down; a pixel
``(i, j)`` covers ``[i, i + 1) x [j, j + 1)``. A car's state is the Frenet vector
``(s, n, mu, vx, vy, omega)`` (see :mod:`racing_env.vehicle`); a race state has shape (N, 6).
"""

from __future__ import annotations

import math
import numbers
import os
import sys
import warnings
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .animation import ffmpeg_available, save_animation  # noqa: F401 (re-exported)
from .draw import (
    CAR_COLORS,
    CHECKER_COLORS,
    EDGE_COLOR,
    GRASS_COLOR,  # noqa: F401 (re-exported)
    HUD_BOX_COLOR,
    HUD_TEXT_COLOR,
    RACELINE_COLOR,
    TRACK_COLOR,
    _as_race_state,
    _as_xy,
    _draw_patch,
    _fill_convex,
    _load_font,
    car_color,  # noqa: F401 (re-exported)
)
from .track import Track
from .trajectory_plot import plot_trajectories  # noqa: F401 (re-exported)
from .vehicle import VehicleParams
from .vehicles.fullsize import FullSizeParams

if TYPE_CHECKING:
    from types import ModuleType

    from matplotlib.figure import Figure
    from matplotlib.image import AxesImage

_SUPERSAMPLE = 3  # background is drawn at 3x and box-filtered down (anti-aliasing)


# ---------------------------------------------------------------------------- renderer
class Renderer:
    """Draw race states of one track as RGB images.

    Parameters
    ----------
    track : Track
        The track; its edges are fitted into the image with a margin, aspect ratio kept.
    vehicle : VehicleParams, optional
        Car body size ``length`` x ``width`` [m] (default :class:`VehicleParams`).
    raceline_xy : optional
        Racing line as ``(x, y)`` arrays [m] (or an (M, 2) array), drawn as a closed polyline.
    width, height : int
        Image size [px].
    car_scale : float
        Cars are drawn ``car_scale`` times their real size (>= 1 keeps small cars visible on
        big tracks); they are further enlarged, keeping their aspect ratio, to be at least
        ``min_car_length_px`` pixels long.
    margin_px : float
        Free border around the track [px].
    min_car_length_px : float
        Smallest drawn car length [px].
    view_m : float, optional
        A view that follows a car (a circuit of kilometres, where the whole track leaves a car
        a pixel long): the image spans ``view_m`` metres across, centred on the car
        :meth:`frame` follows (default the lead car). None (the default): the whole track.

    Attributes
    ----------
    background : np.ndarray
        The cached static image, (height, width, 3) uint8, read-only; with ``view_m`` the
        whole track at the view's scale, which frames crop.
    scale : float
        Pixels per metre.
    car_length_px, car_width_px : float
        Drawn car size [px].
    """

    track: Track
    vehicle: VehicleParams | FullSizeParams
    width: int
    height: int
    raceline_xy: tuple[np.ndarray, np.ndarray] | None
    scale: float
    car_length_px: float
    car_width_px: float
    background: np.ndarray
    _cx: float
    _cy: float
    _body: np.ndarray
    _nose: np.ndarray
    _nose_colors: list[tuple[int, int, int]]
    _font: ImageFont.ImageFont | ImageFont.FreeTypeFont
    _line_h: int

    def __init__(
        self,
        track: Track,
        vehicle: VehicleParams | FullSizeParams | None = None,
        raceline_xy=None,
        width: int = 640,
        height: int = 480,
        car_scale: float = 1.0,
        *,
        margin_px: float = 12.0,
        min_car_length_px: float = 8.0,
        view_m: float | None = None,
    ) -> None:
        if not isinstance(track, Track):
            raise ValueError(f"track must be a Track, got {type(track).__name__}")
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < 16:
                raise ValueError(f"{name} must be an integer >= 16 pixels, got {v!r}")
        if not (isinstance(car_scale, numbers.Real) and math.isfinite(car_scale) and car_scale > 0):
            raise ValueError(f"car_scale must be a positive finite number, got {car_scale!r}")
        if not (0 <= margin_px < min(width, height) / 2):
            raise ValueError(
                f"margin_px must be in [0, {min(width, height) / 2}), got {margin_px!r}"
            )
        self.track = track
        self.vehicle = vehicle if vehicle is not None else VehicleParams()
        self.width, self.height = int(width), int(height)
        self.raceline_xy = None if raceline_xy is None else _as_xy(raceline_xy)

        # world -> pixel transform fitting both edges
        (xl, yl), (xr, yr) = track.edges()
        xs, ys = np.concatenate([xl, xr]), np.concatenate([yl, yr])
        x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
        span_x, span_y = max(x1 - x0, 1e-9), max(y1 - y0, 1e-9)
        self.view_m: float | None = view_m
        self._canvas: tuple[int, int]
        if view_m is None:
            self.scale = float(
                min((self.width - 2 * margin_px) / span_x, (self.height - 2 * margin_px) / span_y)
            )
            self._canvas = (self.width, self.height)
        else:
            if not (isinstance(view_m, numbers.Real) and math.isfinite(view_m) and view_m > 0):
                raise ValueError(f"view_m must be a positive finite number, got {view_m!r}")
            self.scale = float(self.width / view_m)
            self._canvas = (
                int(math.ceil(span_x * self.scale + 2 * margin_px)),
                int(math.ceil(span_y * self.scale + 2 * margin_px)),
            )
        self._cx, self._cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)

        # drawn car size
        L, W = self.vehicle.length, self.vehicle.width
        k = max(car_scale, min_car_length_px / max(L * self.scale, 1e-12))
        self.car_length_px = float(L * self.scale * k)
        self.car_width_px = float(W * self.scale * k)
        # unit car outline and nose triangle in body coordinates [px] (x forward, y left)
        hl, hw = 0.5 * self.car_length_px, 0.5 * self.car_width_px
        self._body = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
        self._nose = np.array(
            [
                [hl, 0.0],
                [hl - 0.45 * self.car_length_px, 0.7 * hw],
                [hl - 0.45 * self.car_length_px, -0.7 * hw],
            ]
        )
        self._nose_colors = [
            (20, 20, 20) if (0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]) > 150 else (250, 250, 250)
            for c in CAR_COLORS
        ]
        self._font = _load_font()
        self._line_h = int(self._font.getbbox("Ag")[3]) + 2  # text line height [px]

        bg = np.array(self._draw_background())
        bg.setflags(write=False)
        self.background = bg

    # ------------------------------------------------------------------ transform
    def world_to_pixel(
        self, x: float | np.ndarray, y: float | np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) [m] -> pixel (u, v) [px] (column, row; floats, any broadcastable shape)."""
        u = 0.5 * self._canvas[0] + self.scale * (np.asarray(x, dtype=float) - self._cx)
        v = 0.5 * self._canvas[1] - self.scale * (np.asarray(y, dtype=float) - self._cy)
        return u, v

    def _car_polygons(self, u, v, phi):
        """Body (N, 4, 2) and nose (N, 3, 2) polygons [px] of cars centred at (u, v) heading phi."""
        c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
        out = []
        for shape in (self._body, self._nose):
            bx, by = shape[:, 0], shape[:, 1]  # body frame: x forward, y left; v points down
            out.append(
                np.stack([u[:, None] + bx * c - by * s, v[:, None] - (bx * s + by * c)], axis=-1)
            )
        return out[0], out[1]

    def car_pixel_positions(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel centre (u, v) [px] and world heading phi [rad] of each car, each shape (N,)."""
        st = _as_race_state(state)
        x, y, phi = self.track.to_cartesian(st[:, 0], st[:, 1], st[:, 2])
        u, v = self.world_to_pixel(x, y)
        return np.atleast_1d(u), np.atleast_1d(v), np.atleast_1d(phi)

    # ------------------------------------------------------------------ background
    def _draw_background(self) -> Image.Image:
        cw, ch = self._canvas
        f = _SUPERSAMPLE
        while f > 1 and cw * ch * f * f > 40_000_000:  # a followed view of a large circuit
            f -= 1
        img = Image.new("RGB", (cw * f, ch * f), GRASS_COLOR)
        d = ImageDraw.Draw(img)
        tr = self.track

        def px(x, y):  # world -> supersampled pixel coordinates, as (M, 2)
            u, v = self.world_to_pixel(x, y)
            return np.column_stack([np.ravel(u) * f, np.ravel(v) * f])

        (xl, yl), (xr, yr) = tr.edges()
        left, right = px(xl, yl), px(xr, yr)
        m = len(left)
        # track surface: one quad per grid segment (robust for any closed track shape)
        for k in range(m):
            j = (k + 1) % m
            quad = [tuple(left[k]), tuple(left[j]), tuple(right[j]), tuple(right[k])]
            d.polygon(quad, fill=TRACK_COLOR)
        # edge lines
        edge_w = max(1, int(round(1.5 * f)))
        for e in (left, right):
            pts = [tuple(p) for p in np.vstack([e, e[:1]])]
            d.line(pts, fill=EDGE_COLOR, width=edge_w, joint="curve")
        # start / finish line: two rows of checkers across the track at s = 0
        wl, wr = tr.widths(0.0)
        wl, wr = float(wl), float(wr)
        n_sq = max(4, int(round((wl + wr) * self.scale / 4.0)))  # ~4 px squares
        sq = (wl + wr) / n_sq  # [m] square side across the track
        x0, y0 = (float(a) for a in tr.position(0.0))
        psi = float(tr.heading(0.0))
        t = np.array([math.cos(psi), math.sin(psi)])
        nrm = np.array([-t[1], t[0]])
        for row in range(2):
            for col in range(n_sq):
                a0, a1 = (row - 1) * sq, row * sq  # along the track
                b0, b1 = -wr + col * sq, -wr + (col + 1) * sq  # across (left positive)
                corners = [
                    np.array([x0, y0]) + a * t + b * nrm
                    for a, b in ((a0, b0), (a1, b0), (a1, b1), (a0, b1))
                ]
                c = np.array(corners)
                poly = [tuple(p) for p in px(c[:, 0], c[:, 1])]
                d.polygon(poly, fill=CHECKER_COLORS[(row + col) % 2])
        # racing line
        if self.raceline_xy is not None:
            rx, ry = self.raceline_xy
            pts = px(rx, ry)
            pts = [tuple(p) for p in np.vstack([pts, pts[:1]])]
            d.line(pts, fill=RACELINE_COLOR, width=max(1, f), joint="curve")
        return img.reduce(f)  # box filter: anti-aliased, no ringing

    # ------------------------------------------------------------------ frames
    def frame(
        self,
        state: np.ndarray,
        labels: Sequence[str] | None = None,
        hud: Sequence[str] | None = None,
        follow: int | None = None,
    ) -> np.ndarray:
        """Render one race state.

        Parameters
        ----------
        state : array (N, 6) or (6,)
            Frenet states ``(s, n, mu, vx, vy, omega)`` [m, m, rad, m/s, m/s, rad/s] of N cars
            (N may be 0). Car ``i`` is drawn in :func:`car_color` ``(i)``, centred on its
            reference point, oriented along ``phi = psi(s) + mu``, with a nose mark at the
            front. Rows that are not finite are skipped.
        labels : sequence of N str, optional
            Text drawn next to each car.
        hud : sequence of str, optional
            Lines of text drawn in a box at the top-left corner (e.g. step, time, order).
        follow : int, optional
            With ``view_m``: the car the view is centred on (default the lead car, the
            largest ``s``); ignored for the whole-track view.

        Returns
        -------
        np.ndarray, shape (height, width, 3), dtype uint8, a new array.
        """
        st = _as_race_state(state)
        n_cars = len(st)
        if labels is not None:
            labels = list(labels)
            if len(labels) != n_cars:
                raise ValueError(
                    f"labels must have one entry per car ({n_cars}), got {len(labels)}"
                )
        u0 = v0 = 0
        ok = np.all(np.isfinite(st[:, :3]), axis=1) if n_cars else np.zeros(0, bool)
        if self.view_m is None:
            out = self.background.copy()
        else:
            out = np.empty((self.height, self.width, 3), np.uint8)
            out[:] = GRASS_COLOR
            if ok.any():
                k = int(np.argmax(np.where(ok, st[:, 0], -np.inf))) if follow is None else follow
                cu, cv, _ = self.car_pixel_positions(st[k])
                u0 = int(round(float(cu[0]) - 0.5 * self.width))
                v0 = int(round(float(cv[0]) - 0.5 * self.height))
            bh, bw = self.background.shape[:2]
            a0, b0 = max(u0, 0), max(v0, 0)
            a1, b1 = min(u0 + self.width, bw), min(v0 + self.height, bh)
            if a1 > a0 and b1 > b0:
                out[b0 - v0 : b1 - v0, a0 - u0 : a1 - u0] = self.background[b0:b1, a0:a1]
        if n_cars:
            u, v, phi = self.car_pixel_positions(np.where(ok[:, None], st, 0.0))
            u, v = u - u0, v - v0
            body, nose = self._car_polygons(u, v, phi)  # (N, 4, 2), (N, 3, 2) [px]
            for i in np.flatnonzero(ok):
                _fill_convex(
                    out,
                    (
                        (body[i], CAR_COLORS[i % len(CAR_COLORS)]),
                        (nose[i], self._nose_colors[i % len(CAR_COLORS)]),
                    ),
                )
            if labels is not None:
                off = 0.5 * self.car_length_px + 2
                for k in range(n_cars):
                    if ok[k] and labels[k]:
                        self._draw_text(
                            out, u[k] + off, v[k] - off - self._line_h, [str(labels[k])], box=False
                        )
        if hud:
            self._draw_text(out, 6, 5, [str(line) for line in hud], box=True)
        return out

    def _draw_text(self, out: np.ndarray, x: float, y: float, lines: list[str], box: bool) -> None:
        """Draw text lines with the top-left corner at pixel (x, y), optionally on a dark box."""
        widths = [self._font.getbbox(line)[2] for line in lines]
        w, h = max(widths), self._line_h * len(lines)
        pad = 3 if box else 0

        def draw_text(d, ox, oy):
            if box:
                d.rectangle(
                    (x - pad - ox, y - pad - oy, x + w + pad - ox, y + h + pad - oy),
                    fill=HUD_BOX_COLOR,
                )
            for k, line in enumerate(lines):
                d.text(
                    (x - ox, y + k * self._line_h - oy), line, fill=HUD_TEXT_COLOR, font=self._font
                )

        _draw_patch(out, (x - pad, y - pad), (x + w + pad, y + h + pad), draw_text)

    __call__ = frame


# ---------------------------------------------------------------------------- human viewer
_NON_INTERACTIVE = {
    "agg",
    "cairo",
    "pdf",
    "pgf",
    "ps",
    "svg",
    "template",
    "module://matplotlib_inline.backend_inline",
    "inline",
}


def display_available() -> tuple[bool, str]:
    """Whether a window can be opened: ``(ok, reason)``.

    False on Linux/BSD without ``DISPLAY`` or ``WAYLAND_DISPLAY``, or when matplotlib's backend
    is non-interactive (e.g. ``Agg``, ``MPLBACKEND=agg``).
    """
    if sys.platform.startswith(("linux", "freebsd", "openbsd", "netbsd")):
        if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
            return False, "no DISPLAY or WAYLAND_DISPLAY environment variable"
    try:
        import matplotlib

        backend = str(matplotlib.get_backend()).lower()
    except Exception as exc:  # pragma: no cover
        return False, f"matplotlib unavailable ({exc})"
    if backend in _NON_INTERACTIVE:
        return False, f"matplotlib backend {backend!r} is non-interactive"
    return True, f"matplotlib backend {backend!r}"


class HumanViewer:
    """Show frames in a matplotlib window (interactive mode, ``plt.pause``).

    Without a display (see :func:`display_available`) or if the window cannot be opened it
    emits one ``warnings.warn`` (RuntimeWarning) and then only keeps the last frame in
    :attr:`last_frame`; it never raises for that reason.

    Parameters
    ----------
    title : str
        Window title.
    pause : float
        Seconds passed to ``plt.pause`` after each frame (>= 1e-3).
    """

    def __init__(self, title: str = "alpha-racer", pause: float = 1e-3):
        self.title = title
        self.pause = max(float(pause), 1e-3)
        self.last_frame: np.ndarray | None = None
        self._fig: Figure | None = None
        self._im: AxesImage | None = None
        self._plt: ModuleType | None = None  # matplotlib.pyplot, imported on the first frame
        self._warned = False
        ok, reason = display_available()
        self.available = ok
        if not ok:
            self._warn(reason)

    def _warn(self, reason: str) -> None:
        self.available = False
        if not self._warned:
            self._warned = True
            warnings.warn(
                f"human rendering needs a display ({reason}); frames are not shown. "
                f"Use render_mode='rgb_array' and save_animation() instead.",
                RuntimeWarning,
                stacklevel=3,
            )

    def show(self, frame: np.ndarray) -> None:
        """Display ``frame`` ((H, W, 3) uint8), replacing the previous one."""
        frame = np.asarray(frame)
        if frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"frame must have shape (H, W, 3), got {frame.shape}")
        self.last_frame = frame
        if not self.available:
            return
        try:
            if self._plt is None:
                import matplotlib.pyplot as plt

                self._plt = plt
                plt.ion()
            plt = self._plt
            if self._fig is None or not plt.fignum_exists(self._fig.number):
                self._fig, ax = plt.subplots(num=self.title)
                ax.set_axis_off()
                self._fig.subplots_adjust(0, 0, 1, 1)
                self._im = ax.imshow(frame, interpolation="nearest")
                plt.show(block=False)
            else:
                assert self._im is not None  # drawn with the figure
                self._im.set_data(frame)
            plt.pause(self.pause)
        except Exception as exc:  # no usable window after all: degrade, don't crash
            self._warn(f"could not open a window: {exc}")

    def close(self) -> None:
        """Close the window (if any). The viewer can be shown again afterwards."""
        if self._fig is not None and self._plt is not None:
            try:
                self._plt.close(self._fig)
            except Exception:  # pragma: no cover
                pass
        self._fig = None
        self._im = None
