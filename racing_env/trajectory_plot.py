"""The trajectory plot: :func:`plot_trajectories` draws the cars' paths over an episode on
the track to a PNG (matplotlib Agg), in the cars' colours of the race frames."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .draw import _as_xy, car_color
from .files import atomic_path
from .track import Track


def plot_trajectories(
    track: Track,
    states: np.ndarray,
    path: str | os.PathLike,
    raceline_xy: tuple[np.ndarray, np.ndarray] | np.ndarray | None = None,
    labels: Sequence[str] | None = None,
    title: str | None = None,
    dpi: int = 150,
) -> Path:
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
        :class:`~racing_env.render.Renderer`; a circle marks its first and a cross its last
        position.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(
            f"plot_trajectories writes PNG; got suffix {path.suffix!r} in {str(path)!r}"
        )
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
        ax.plot(
            np.append(rx, rx[0]),
            np.append(ry, ry[0]),
            "--",
            color="0.55",
            lw=1.0,
            label="racing line",
        )
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
