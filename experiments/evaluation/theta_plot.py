"""What a strategic agent chose during a race: its theta over time beside the gaps to the
other cars (``thetas.png`` of ``alpha-racer race``).

A fixed-theta car drives one theta the whole race; the alpha agent maximises its potential at
every step and so may attack with one theta and block with another. The plot shows, for every
car whose theta changed during the race, one panel per parameter of its policy space against
time, under a panel of its progress gap ``s_j - s_i`` [m] to every other car (positive: car j
ahead), with the race's passes (:mod:`experiments.evaluation.metrics`) as vertical lines.
"""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np

from racing_env.draw import car_color
from racing_env.files import atomic_path

#: the unit of each theta parameter, for the axis labels
UNITS = {
    "q": "",
    "zeta": "",
    "s1": " [m]",
    "s2": " [1/m^2]",
    "s3": " [s/m]",
    "b": "",
    "h": " [L]",
    "p": " [L]",
    "c": "",
}


def varying_cars(thetas) -> list[int]:
    """Indices of the cars whose theta (``(T, D)`` array, or None) changed during the race."""
    return [i for i, t in enumerate(thetas) if t is not None and len(t) and np.ptp(t, axis=0).any()]


def plot_thetas(result, path: str | os.PathLike, dpi: int = 120) -> Path:
    """Plot the thetas of ``result`` (a :class:`experiments.evaluation.race.RaceResult`) to a PNG: one
    column per car whose theta changed, rows: the gap to every other car, then each
    parameter. ``ValueError`` if no car's theta changed (nothing to show) or ``path`` is not
    a ``.png``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ValueError(f"plot_thetas writes PNG; got suffix {path.suffix!r} in {str(path)!r}")
    cars = varying_cars(result.thetas)
    if not cars:
        raise ValueError("no car's theta changed during the race: nothing to plot")
    st = np.asarray(result.states, dtype=float)
    t_state = np.arange(len(st)) * result.dt
    events = [e for e in result.metrics["pass_events"] if e["kind"] in ("pass", "contact")]
    rows = 1 + max(result.thetas[i].shape[1] for i in cars)
    fig = Figure(figsize=(5.5 * len(cars), 1.5 * rows + 0.8))
    FigureCanvasAgg(fig)
    for col, i in enumerate(cars):
        th, names = result.thetas[i], result.theta_names[i]
        t_act = np.arange(len(th)) * result.dt  # the decision at step k acts over [k dt, (k+1) dt)
        axes = [fig.add_subplot(rows, len(cars), r * len(cars) + col + 1) for r in range(rows)]
        gap = axes[0]
        for j in range(st.shape[1]):
            if j != i:
                gap.plot(
                    t_state,
                    st[:, j, 0] - st[:, i, 0],
                    color=np.array(car_color(j)) / 255.0,
                    lw=1.0,
                    label=f"car_{j}",
                )
        gap.axhline(0.0, color="0.5", lw=0.6)
        gap.set_ylabel("s_j - s_i [m]", fontsize=8)
        gap.set_title(textwrap.fill(f"car_{i} ({result.agents[i]})", 60), fontsize=9)
        gap.legend(loc="best", fontsize=7, framealpha=0.8)
        for r, name in enumerate(names, 1):
            ax = axes[r]
            ax.step(t_act, th[:, r - 1], where="post", color=np.array(car_color(i)) / 255.0, lw=0.9)
            ax.set_ylabel(name + UNITS.get(name, ""), fontsize=8)
        for ax in axes:
            ax.tick_params(labelsize=7)
            for e in events:
                if i in (e["passer"], e["passed"]):
                    ax.axvline(
                        e["time_s"],
                        color="k" if e["passer"] == i else "r",
                        ls="--" if e["kind"] == "pass" else ":",
                        lw=0.8,
                    )
        axes[-1].set_xlabel("time [s] (dashed: a pass by this car, red: a pass of it)", fontsize=8)
    fig.tight_layout()
    with atomic_path(path, ".png") as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return path
