"""Rendering of races: fast RGB frames, a human viewer, animations and trajectory plots.

* :class:`Renderer` turns a race state into an RGB image ``(height, width, 3)`` uint8. The
  static background (grass, track surface, edge lines, start/finish line at ``s = 0``,
  optional racing line) is drawn once with PIL when the renderer is built; each frame only
  copies it and draws the cars (rotated rectangles, one colour per car index from
  :data:`CAR_COLORS`), optional labels and a HUD.
* :class:`HumanViewer` shows frames in a matplotlib window (``render_mode="human"``); without a
  display it warns once and only keeps the last frame.
* :func:`save_animation` writes frames to ``.gif`` (PIL) or ``.mp4`` (ffmpeg), atomically.
* :func:`plot_trajectories` draws the cars' paths over an episode to a PNG (matplotlib Agg).

Conventions: world coordinates in metres, ``y`` up; pixel coordinates ``(u, v)`` are
(column, row) with the origin at the top-left corner of the image, ``v`` down; a pixel
``(i, j)`` covers ``[i, i + 1) x [j, j + 1)``. A car's state is the Frenet vector
``(s, n, mu, vx, vy, omega)`` (see :mod:`racing_env.vehicle`); a race state has shape (N, 6).
"""
from __future__ import annotations

import math
import numbers
import os
import shutil
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path
from collections.abc import Iterable, Sequence

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from .files import atomic_path
from .track import Track
from .vehicle import VehicleParams

# ---------------------------------------------------------------------------- colours
CAR_COLORS: tuple[tuple[int, int, int], ...] = (
    (230, 25, 75),    # 0 red
    (0, 130, 200),    # 1 blue
    (255, 225, 25),   # 2 yellow
    (60, 180, 75),    # 3 green
    (245, 130, 48),   # 4 orange
    (145, 30, 180),   # 5 purple
    (240, 50, 230),   # 6 magenta
    (170, 110, 40),   # 7 brown
)
"""Fixed RGB colour of car ``i`` (cars beyond 8 reuse the palette, ``i % 8``). None of these
colours occurs in the rendered background."""

GRASS_COLOR = (34, 66, 38)
TRACK_COLOR = (82, 82, 88)
EDGE_COLOR = (235, 235, 235)
RACELINE_COLOR = (70, 220, 230)
CHECKER_COLORS = ((245, 245, 245), (15, 15, 15))
HUD_TEXT_COLOR = (245, 245, 245)
HUD_BOX_COLOR = (10, 10, 10)

_SUPERSAMPLE = 3  # background is drawn at 3x and box-filtered down (anti-aliasing)


def car_color(i: int) -> tuple[int, int, int]:
    """RGB colour (0..255) of car index ``i``."""
    return CAR_COLORS[int(i) % len(CAR_COLORS)]


def _load_font():
    """PIL's built-in bitmap font (about 11 px high): ~10x faster to draw than FreeType text."""
    try:
        return ImageFont.load_default_imagefont()  # Pillow >= 10.1
    except AttributeError:  # pragma: no cover - older Pillow: load_default() is the bitmap font
        return ImageFont.load_default()


def _fill_convex(out: np.ndarray, polys_colors) -> None:
    """Fill convex polygons into ``out`` (H, W, 3) in place, in order (later ones on top).

    ``polys_colors`` is a sequence of ``(poly, color)`` with ``poly`` (K, 2) vertices [px, (u, v)]
    and ``color`` RGB. A pixel is filled when its centre lies inside (or on) a polygon; no
    anti-aliasing, so the exact colour is kept. Vectorised over the polygons' joint bounding box,
    which is clipped to the image.
    """
    h, w = out.shape[:2]
    allp = np.concatenate([p for p, _ in polys_colors])
    u0, v0 = max(int(math.floor(allp[:, 0].min())), 0), max(int(math.floor(allp[:, 1].min())), 0)
    u1, v1 = min(int(math.ceil(allp[:, 0].max())) + 1, w), min(int(math.ceil(allp[:, 1].max())) + 1, h)
    if u1 <= u0 or v1 <= v0:
        return  # entirely outside the image
    pu = np.arange(u0, u1) + 0.5                 # pixel centres
    pv = (np.arange(v0, v1) + 0.5)[:, None]
    region = out[v0:v1, u0:u1]
    for poly, color in polys_colors:
        a = poly[:, :, None, None]                # (K, 2, 1, 1)
        e = np.roll(poly, -1, axis=0)[:, :, None, None] - a
        cross = e[:, 0] * (pv - a[:, 1]) - e[:, 1] * (pu - a[:, 0])   # (K, h, w)
        inside = (cross >= 0).all(axis=0) | (cross <= 0).all(axis=0)
        region[inside] = color


def _draw_patch(out: np.ndarray, lo, hi, draw_fn) -> None:
    """Run ``draw_fn(ImageDraw, ox, oy)`` on the pixel box [lo, hi] of ``out`` (H, W, 3) in place.

    Only the (small) box is converted to a PIL image and back, which is much cheaper than
    converting the whole frame; ``draw_fn`` gets the box origin (ox, oy) to offset its
    coordinates by.
    """
    h, w = out.shape[:2]
    u0, v0 = max(int(math.floor(lo[0])) - 1, 0), max(int(math.floor(lo[1])) - 1, 0)
    u1, v1 = min(int(math.ceil(hi[0])) + 2, w), min(int(math.ceil(hi[1])) + 2, h)
    if u1 <= u0 or v1 <= v0:
        return  # entirely outside the image
    patch = Image.fromarray(out[v0:v1, u0:u1])
    draw_fn(ImageDraw.Draw(patch), u0, v0)
    out[v0:v1, u0:u1] = np.asarray(patch)


def _as_xy(raceline_xy) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) arrays [m] from ``(x, y)`` or an (M, 2) array; validates shape and finiteness."""
    a = np.asarray(raceline_xy, dtype=float)
    if a.ndim != 2 or 2 not in a.shape:
        raise ValueError(f"raceline_xy must be (x, y) arrays or an (M, 2) array, got shape {a.shape}")
    if a.shape[0] != 2:
        a = a.T
    if a.shape[1] < 2:
        raise ValueError(f"raceline_xy needs at least 2 points, got {a.shape[1]}")
    if not np.all(np.isfinite(a)):
        raise ValueError("raceline_xy contains NaN or inf")
    return a[0], a[1]


def _as_race_state(state, what: str = "state") -> np.ndarray:
    """A race state as float array (N, 6); a single car's (6,) vector becomes (1, 6)."""
    a = np.asarray(state, dtype=float)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 6:
        raise ValueError(f"{what} must have shape (N, 6) (s, n, mu, vx, vy, omega), got {a.shape}")
    return a


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

    Attributes
    ----------
    background : np.ndarray
        The cached static image, (height, width, 3) uint8, read-only.
    scale : float
        Pixels per metre.
    car_length_px, car_width_px : float
        Drawn car size [px].
    """

    def __init__(self, track: Track, vehicle: VehicleParams | None = None, raceline_xy=None,
                 width: int = 640, height: int = 480, car_scale: float = 1.0, *,
                 margin_px: float = 12.0, min_car_length_px: float = 8.0):
        if not isinstance(track, Track):
            raise ValueError(f"track must be a Track, got {type(track).__name__}")
        for name, v in (("width", width), ("height", height)):
            if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < 16:
                raise ValueError(f"{name} must be an integer >= 16 pixels, got {v!r}")
        if not (isinstance(car_scale, numbers.Real) and math.isfinite(car_scale) and car_scale > 0):
            raise ValueError(f"car_scale must be a positive finite number, got {car_scale!r}")
        if not (0 <= margin_px < min(width, height) / 2):
            raise ValueError(f"margin_px must be in [0, {min(width, height) / 2}), got {margin_px!r}")
        self.track = track
        self.vehicle = vehicle if vehicle is not None else VehicleParams()
        self.width, self.height = int(width), int(height)
        self.raceline_xy = None if raceline_xy is None else _as_xy(raceline_xy)

        # world -> pixel transform fitting both edges
        (xl, yl), (xr, yr) = track.edges()
        xs, ys = np.concatenate([xl, xr]), np.concatenate([yl, yr])
        x0, x1, y0, y1 = xs.min(), xs.max(), ys.min(), ys.max()
        span_x, span_y = max(x1 - x0, 1e-9), max(y1 - y0, 1e-9)
        self.scale = float(min((self.width - 2 * margin_px) / span_x,
                               (self.height - 2 * margin_px) / span_y))
        self._cx, self._cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)

        # drawn car size
        L, W = self.vehicle.length, self.vehicle.width
        k = max(car_scale, min_car_length_px / max(L * self.scale, 1e-12))
        self.car_length_px = float(L * self.scale * k)
        self.car_width_px = float(W * self.scale * k)
        # unit car outline and nose triangle in body coordinates [px] (x forward, y left)
        hl, hw = 0.5 * self.car_length_px, 0.5 * self.car_width_px
        self._body = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
        self._nose = np.array([[hl, 0.0], [hl - 0.45 * self.car_length_px, 0.7 * hw],
                               [hl - 0.45 * self.car_length_px, -0.7 * hw]])
        self._nose_colors = [(20, 20, 20) if (0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]) > 150
                             else (250, 250, 250) for c in CAR_COLORS]
        self._font = _load_font()
        self._line_h = int(self._font.getbbox("Ag")[3]) + 2  # text line height [px]

        bg = np.array(self._draw_background())
        bg.setflags(write=False)
        self.background = bg

    # ------------------------------------------------------------------ transform
    def world_to_pixel(self, x: float | np.ndarray, y: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) [m] -> pixel (u, v) [px] (column, row; floats, any broadcastable shape)."""
        u = 0.5 * self.width + self.scale * (np.asarray(x, dtype=float) - self._cx)
        v = 0.5 * self.height - self.scale * (np.asarray(y, dtype=float) - self._cy)
        return u, v

    def _car_polygons(self, u, v, phi):
        """Body (N, 4, 2) and nose (N, 3, 2) polygons [px] of cars centred at (u, v) heading phi."""
        c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
        out = []
        for shape in (self._body, self._nose):
            bx, by = shape[:, 0], shape[:, 1]  # body frame: x forward, y left; v points down
            out.append(np.stack([u[:, None] + bx * c - by * s,
                                 v[:, None] - (bx * s + by * c)], axis=-1))
        return out[0], out[1]

    def car_pixel_positions(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel centre (u, v) [px] and world heading phi [rad] of each car, each shape (N,)."""
        st = _as_race_state(state)
        x, y, phi = self.track.to_cartesian(st[:, 0], st[:, 1], st[:, 2])
        u, v = self.world_to_pixel(x, y)
        return np.atleast_1d(u), np.atleast_1d(v), np.atleast_1d(phi)

    # ------------------------------------------------------------------ background
    def _draw_background(self) -> Image.Image:
        f = _SUPERSAMPLE
        img = Image.new("RGB", (self.width * f, self.height * f), GRASS_COLOR)
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
                a0, a1 = (row - 1) * sq, row * sq            # along the track
                b0, b1 = -wr + col * sq, -wr + (col + 1) * sq  # across (left positive)
                corners = [np.array([x0, y0]) + a * t + b * nrm
                           for a, b in ((a0, b0), (a1, b0), (a1, b1), (a0, b1))]
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
    def frame(self, state: np.ndarray, labels: Sequence[str] | None = None,
              hud: Sequence[str] | None = None) -> np.ndarray:
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

        Returns
        -------
        np.ndarray, shape (height, width, 3), dtype uint8, a new array.
        """
        st = _as_race_state(state)
        n_cars = len(st)
        if labels is not None:
            labels = list(labels)
            if len(labels) != n_cars:
                raise ValueError(f"labels must have one entry per car ({n_cars}), got {len(labels)}")
        out = self.background.copy()
        if n_cars:
            ok = np.all(np.isfinite(st[:, :3]), axis=1)
            u, v, phi = self.car_pixel_positions(np.where(ok[:, None], st, 0.0))
            body, nose = self._car_polygons(u, v, phi)  # (N, 4, 2), (N, 3, 2) [px]
            for i in np.flatnonzero(ok):
                _fill_convex(out, ((body[i], CAR_COLORS[i % len(CAR_COLORS)]),
                                   (nose[i], self._nose_colors[i % len(CAR_COLORS)])))
            if labels is not None:
                off = 0.5 * self.car_length_px + 2
                for i in range(n_cars):
                    if ok[i] and labels[i]:
                        self._draw_text(out, u[i] + off, v[i] - off - self._line_h,
                                        [str(labels[i])], box=False)
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
                d.rectangle((x - pad - ox, y - pad - oy, x + w + pad - ox, y + h + pad - oy),
                            fill=HUD_BOX_COLOR)
            for k, line in enumerate(lines):
                d.text((x - ox, y + k * self._line_h - oy), line, fill=HUD_TEXT_COLOR, font=self._font)

        _draw_patch(out, (x - pad, y - pad), (x + w + pad, y + h + pad), draw_text)

    __call__ = frame


# ---------------------------------------------------------------------------- human viewer
_NON_INTERACTIVE = {"agg", "cairo", "pdf", "pgf", "ps", "svg", "template",
                    "module://matplotlib_inline.backend_inline", "inline"}


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
        self._fig = None
        self._im = None
        self._plt = None
        self._warned = False
        ok, reason = display_available()
        self.available = ok
        if not ok:
            self._warn(reason)

    def _warn(self, reason: str) -> None:
        self.available = False
        if not self._warned:
            self._warned = True
            warnings.warn(f"human rendering needs a display ({reason}); frames are not shown. "
                          f"Use render_mode='rgb_array' and save_animation() instead.",
                          RuntimeWarning, stacklevel=3)

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


# ---------------------------------------------------------------------------- animations
def _check_frames(frames) -> list[np.ndarray]:
    if isinstance(frames, np.ndarray):
        if frames.ndim != 4:
            raise ValueError(f"frames array must have shape (T, H, W, 3), got {frames.shape}")
        frames = list(frames)
    elif isinstance(frames, Iterable) and not isinstance(frames, (str, bytes)):
        frames = list(frames)
    else:
        raise ValueError(f"frames must be a sequence of (H, W, 3) uint8 arrays, got {type(frames).__name__}")
    if not frames:
        raise ValueError("frames is empty: nothing to save")
    shape0 = None
    for i, f in enumerate(frames):
        if not isinstance(f, np.ndarray):
            raise ValueError(f"frame {i} is a {type(f).__name__}, expected a numpy array")
        if f.dtype != np.uint8:
            raise ValueError(f"frame {i} has dtype {f.dtype}, expected uint8")
        if f.ndim != 3 or f.shape[2] != 3 or f.shape[0] < 1 or f.shape[1] < 1:
            raise ValueError(f"frame {i} has shape {f.shape}, expected (H, W, 3)")
        if shape0 is None:
            shape0 = f.shape
        elif f.shape != shape0:
            raise ValueError(f"frame {i} has shape {f.shape}, but frame 0 has {shape0}")
    return frames


def _check_fps(fps) -> float:
    if isinstance(fps, bool) or not isinstance(fps, numbers.Real) or not math.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be a positive finite number, got {fps!r}")
    return float(fps)


def ffmpeg_available() -> bool:
    """Whether :func:`save_animation` can write ``.mp4`` here (an ffmpeg on ``PATH`` or from
    imageio-ffmpeg); check it before a long run whose animation needs it."""
    return _find_ffmpeg() is not None


def _find_ffmpeg() -> str | None:
    exe = shutil.which("ffmpeg")
    if exe:
        return exe
    try:  # imageio's bundled ffmpeg, if installed
        import imageio_ffmpeg
        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:
        return None


def _write_gif(frames: list[np.ndarray], tmp: str, fps: float) -> None:
    # one global palette from up to 8 evenly spaced frames: consistent colours, no flicker
    idx = np.unique(np.linspace(0, len(frames) - 1, min(8, len(frames))).round().astype(int))
    sample = Image.fromarray(np.concatenate([frames[i] for i in idx], axis=0))
    pal = sample.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    images = [Image.fromarray(f).quantize(palette=pal, dither=Image.Dither.NONE) for f in frames]
    duration = max(int(round(1000.0 / fps)), 10)  # ms; GIF stores centiseconds
    images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                   duration=duration, loop=0, optimize=False, disposal=1)


def _write_mp4(frames: list[np.ndarray], tmp: str, fps: float, ffmpeg: str) -> None:
    h, w = frames[0].shape[:2]
    base = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
            "-s", f"{w}x{h}", "-r", f"{fps:g}", "-i", "-", "-an",
            "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"]
    codecs = (["-c:v", "libx264", "-pix_fmt", "yuv420p", "-movflags", "+faststart"],
              ["-c:v", "mpeg4", "-q:v", "3", "-pix_fmt", "yuv420p"])
    errors = []
    for codec in codecs:
        with tempfile.TemporaryFile() as err:
            proc = subprocess.Popen(base + codec + ["-f", "mp4", tmp], stdin=subprocess.PIPE,
                                    stdout=subprocess.DEVNULL, stderr=err)
            try:
                for f in frames:
                    proc.stdin.write(np.ascontiguousarray(f).tobytes())
                proc.stdin.close()
            except (BrokenPipeError, OSError):
                pass
            rc = proc.wait()
            if rc == 0:
                return
            err.seek(0)
            errors.append(f"{codec[1]}: exit {rc}: {err.read().decode(errors='replace').strip()[-500:]}")
    raise RuntimeError("ffmpeg failed to write the mp4: " + " | ".join(errors))


def save_animation(frames: Sequence[np.ndarray], path: str | os.PathLike, fps: float = 10) -> Path:
    """Write frames to an animated ``.gif`` or ``.mp4`` file; returns the path.

    Parameters
    ----------
    frames : sequence of np.ndarray
        T >= 1 frames, each (H, W, 3) uint8, all the same shape (or one (T, H, W, 3) array).
    path : str or PathLike
        Output file; the suffix picks the format (``.gif`` or ``.mp4``, any case). The parent
        folder is created if needed. The file is written to a temporary file in the same
        folder and moved into place with ``os.replace``, so it is either complete or absent.
    fps : float
        Frames per second (> 0). GIF stores frame durations in 1/100 s, so the GIF duration is
        ``round(1000 / fps)`` ms rounded to 10 ms (at least 10 ms); consecutive identical frames
        are merged by PIL into one longer frame.

    Raises
    ------
    ValueError
        Empty frames, wrong dtype/shape, unknown suffix, fps <= 0.
    RuntimeError
        ``.mp4`` requested but no ffmpeg executable was found (or ffmpeg failed).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"unknown animation suffix {path.suffix!r} in {str(path)!r}; use .gif or .mp4")
    fps = _check_fps(fps)
    frames = _check_frames(frames)
    ffmpeg = None
    if suffix == ".mp4":
        ffmpeg = _find_ffmpeg()
        if ffmpeg is None:
            raise RuntimeError(f"cannot write {str(path)!r}: ffmpeg is missing (not on PATH and "
                               f"imageio-ffmpeg not installed); install ffmpeg or save as .gif")
    with atomic_path(path, suffix) as tmp:
        if suffix == ".gif":
            _write_gif(frames, str(tmp), fps)
        else:
            _write_mp4(frames, str(tmp), fps, ffmpeg)
    return path


# ---------------------------------------------------------------------------- trajectory plot
def plot_trajectories(track: Track, states: np.ndarray, path: str | os.PathLike,
                      raceline_xy: tuple[np.ndarray, np.ndarray] | np.ndarray | None = None,
                      labels: Sequence[str] | None = None, title: str | None = None,
                      dpi: int = 150) -> Path:
    """Plot each car's path over an episode on the track to a PNG (matplotlib Agg, no pyplot).

    Parameters
    ----------
    track : Track
    states : array (T, N, 6) (or (T, 6) for one car)
        Frenet states ``(s, n, mu, vx, vy, omega)`` over T steps; non-finite rows break the line.
    path : str or PathLike
        Output PNG file (written atomically; parent folder created if needed).
    raceline_xy : optional
        Racing line as ``(x, y)`` arrays [m] or (M, 2), drawn dashed.
    labels : sequence of N str, optional
        Legend entries (default ``car 0``, ``car 1``, ...).
    title : str, optional
    dpi : int

    Returns
    -------
    Path
        The path written. Car ``i`` has the colour :func:`car_color` ``(i)``, as in
        :class:`Renderer`; a circle marks its first and a cross its last position.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"plot_trajectories writes PNG; got suffix {path.suffix!r} in {str(path)!r}")
    st = np.asarray(states, dtype=float)
    if st.ndim == 2:
        st = st[:, None, :]
    if st.ndim != 3 or st.shape[2] != 6 or st.shape[0] < 1:
        raise ValueError(f"states must have shape (T, N, 6), got {np.shape(states)}")
    n_cars = st.shape[1]
    if labels is None:
        labels = [f"car {i}" for i in range(n_cars)]
    labels = list(labels)
    if len(labels) != n_cars:
        raise ValueError(f"labels must have one entry per car ({n_cars}), got {len(labels)}")

    (xl, yl), (xr, yr) = track.edges()
    aspect = np.ptp(np.r_[yl, yr]) / max(np.ptp(np.r_[xl, xr]), 1e-9)
    fig = Figure(figsize=(9.0, float(np.clip(8.0 * aspect + 1.2, 3.0, 9.0))))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(111)
    for ex, ey in ((xl, yl), (xr, yr)):
        ax.plot(np.append(ex, ex[0]), np.append(ey, ey[0]), color="0.2", lw=1.0)
    (sl_x, sl_y), (sr_x, sr_y) = track.edges(np.array([0.0]))
    ax.plot([sl_x[0], sr_x[0]], [sl_y[0], sr_y[0]], color="k", lw=2.0, label="start/finish")
    if raceline_xy is not None:
        rx, ry = _as_xy(raceline_xy)
        ax.plot(np.append(rx, rx[0]), np.append(ry, ry[0]), "--", color="0.55", lw=1.0,
                label="racing line")
    for i in range(n_cars):
        x, y = track.to_cartesian(st[:, i, 0], st[:, i, 1])
        col = np.array(car_color(i)) / 255.0
        ax.plot(x, y, color=col, lw=1.3, label=str(labels[i]))
        good = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
        if good.size:
            ax.plot(x[good[0]], y[good[0]], "o", color=col, ms=5)
            ax.plot(x[good[-1]], y[good[-1]], "x", color=col, ms=6, mew=2)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{track.name}: {n_cars} car(s), {st.shape[0]} steps")
    ax.legend(loc="best", fontsize=8, framealpha=0.8)
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return path
