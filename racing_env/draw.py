"""Colours and drawing primitives shared by the race frames (:mod:`racing_env.render`) and
the trajectory plot (:mod:`racing_env.trajectory_plot`): the palette, convex polygons filled
into an RGB array, PIL drawing on a small patch of one, the text font, and the checks that turn
a racing line or a race state into arrays.

Pixel coordinates ``(u, v)`` are (column, row) with the origin at the top-left corner of the
image, ``v`` down; a pixel ``(i, j)`` covers ``[i, i + 1) x [j, j + 1)``.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image, ImageDraw, ImageFont

# ---------------------------------------------------------------------------- colours
CAR_COLORS: tuple[tuple[int, int, int], ...] = (
    (230, 25, 75),  # 0 red
    (0, 130, 200),  # 1 blue
    (255, 225, 25),  # 2 yellow
    (60, 180, 75),  # 3 green
    (245, 130, 48),  # 4 orange
    (145, 30, 180),  # 5 purple
    (240, 50, 230),  # 6 magenta
    (170, 110, 40),  # 7 brown
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


def car_color(i: int) -> tuple[int, int, int]:
    """RGB colour (0..255) of car index ``i``."""
    return CAR_COLORS[int(i) % len(CAR_COLORS)]


# ---------------------------------------------------------------------------- primitives
def _load_font() -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
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
    u1, v1 = (
        min(int(math.ceil(allp[:, 0].max())) + 1, w),
        min(int(math.ceil(allp[:, 1].max())) + 1, h),
    )
    if u1 <= u0 or v1 <= v0:
        return  # entirely outside the image
    pu = np.arange(u0, u1) + 0.5  # pixel centres
    pv = (np.arange(v0, v1) + 0.5)[:, None]
    region = out[v0:v1, u0:u1]
    for poly, color in polys_colors:
        a = poly[:, :, None, None]  # (K, 2, 1, 1)
        e = np.roll(poly, -1, axis=0)[:, :, None, None] - a
        cross = e[:, 0] * (pv - a[:, 1]) - e[:, 1] * (pu - a[:, 0])  # (K, h, w)
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
        raise ValueError(
            f"raceline_xy must be (x, y) arrays or an (M, 2) array, got shape {a.shape}"
        )
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
