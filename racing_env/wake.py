"""The wake: drag and downforce of a car behind another, a rule of the world for any class.

Behind another car, the follower meets slower, turbulent air: its drag falls (the tow) and so
does its downforce (dirty air). :func:`wake_factors` gives the two multipliers of the
follower's drag and downforce, ``(drag_factor, downforce_factor)`` in (0, 1], from

* the gap ``g`` in car lengths of the leader, nose to tail: ``g = ds / L - 1`` with ``ds`` the
  centre-to-centre distance along the track (``g = 0`` touching, ``g = -1`` alongside);
* the lateral offset ``y`` in car widths of the leader (centre to centre);
* a ``strength`` (1 = the published figures below, 0 = off: exactly 1.0).

The curves, one per effect, share one shape of the wake (both forces scale with the dynamic
pressure the follower meets, as TORCS models it) and differ in their amplitude::

    loss_e(g, y) = A_e * shape(g) * exp(-y^2 / (2 sigma(g)^2))         e = drag, downforce
    shape(g)     = (1 + g / G0)^(-Q) * (1 - (g / R)^2)^2    for 0 <= g < R   (0 beyond R)
                 = shape(0) * (1 + g)                          for -1 < g < 0 (overlapping)
    sigma(g)     = SIGMA0 + SPREAD * g                                  [widths]
    factor_e     = (1 - loss_e)^strength

The loss falls with ``|y|`` at every gap, and with the gap for a follower within about half a
width of the leader's line (``|y| <= 0.55``); a follower further aside meets the widening wake
only further back (TORCS' cone, below). ``strength`` acts as an exponent so that every factor
stays in (0, 1] for any strength (for small losses it scales the loss linearly).

Sources and fits (run :func:`print_fit` for the table):

* **Downforce**, FIA (N. Tombazis, FIA Head of Single-Seater Technical Matters, presentation
  of the 2022 Formula 1 regulations, 2021): a 2017-21 car following another loses about 50% of
  its downforce at 1 car length, 32% at 3 and 21% at 7. ``A_DOWNFORCE, G0, Q`` reproduce these
  three points exactly (to 1e-12; :func:`fit_curve`), with ``R = 60`` lengths, where the wake
  ends smoothly (280 m for a full-size car, 3.5 s at 80 m/s). The 2022 cars lose 14, 6 and 2%:
  ``DOWNFORCE_2022 = (A, G0, Q)`` fits those (same ``R``), for a world with 2022-style cars.
* **Drag**, J. J. Cerutti, G. Cafiero, G. Iuso, "Aerodynamic drag reduction by means of
  platooning configurations of light commercial vehicles: a flow field analysis",
  International Journal of Heat and Fluid Flow 90, 108823, 2021 (wind tunnel, van models): at
  a gap (nose to tail) of half a vehicle length the rear van's drag falls by 43% (the front
  van's by 30%; the push on the leader is not modelled). ``A_DRAG`` puts the drag curve
  through that point; its decay with the gap is the downforce curve's (the same wake). The
  pair's average at 3 lengths, 20% there, is matched by our rear car's 22%.
  Check, not fitted: at the 1 s DRS window (about 16 lengths at 80 m/s) the drag falls by
  8.6%, +3.0% top speed at constant power, i.e. 10 km/h at 330 km/h: the size the FIA gives for
  DRS (10-12 km/h), and at constant power top speed goes as drag^(-1/3) (a 20% cut: +7.7%).
* **Form and lateral extent**, TORCS / Speed Dreams (``src/modules/simu/simuv2/aero.cpp``,
  ``SimAeroUpdate``): a car within 10 degrees of straight behind another (and heading within
  8 degrees of it) has its body drag multiplied by ``k^2``, ``k = 1 - exp(-2 d / (C_d v))``
  with ``d`` the distance, ``C_d`` the leader's drag coefficient (0.645 C_x A plus wings, in
  kg/m) and ``v`` its speed: drag follows the dynamic pressure, the square of the air speed
  the follower meets. Its tow is a game's: at 80 m/s and ``C_d = 0.75`` kg/m it cuts 93% of
  the drag at 1 length and 49% at 7 (see :func:`torcs_drag_factor`), far more than the
  published figures, so we take only its form (both effects scale with the dynamic pressure:
  one shape) and its 10-degree cone: the wake's width grows by tan(10 deg) per unit of
  distance, ``SPREAD = tan(10 deg) * 4.7 / 2.0`` widths per length for the full-size car's
  aspect, from ``SIGMA0 = 0.5`` width (the leader's own half-width) at its tail.

A car ahead is found along the track (``s`` unwrapped, the gap taken modulo the track
length, so a car ahead across the start/finish line, or a lap down, is seen); the strongest
wake of any car ahead within ``R`` lengths applies. The wake is frozen over a control period
(computed at its start) by the batched :func:`wake_factors_cars`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from numpy.typing import ArrayLike

WAKE_RANGE = 60.0  # R [leader lengths]: the wake ends (smoothly) there
A_DOWNFORCE = 0.8818800581326804  # downforce loss at g = 0 (FIA 2017-21 fit)
G0 = 0.5139634286206997  # [lengths]
Q = 0.5247379422141508  # decay exponent
A_DRAG = 0.6142904085647163  # drag loss at g = 0 (43% at g = 0.5, Cerutti et al.)
DOWNFORCE_2022 = (0.25249530148635885, 3.1845365290154044, 2.157517052730952)  # (A, G0, Q)
SIGMA0 = 0.5  # [widths] lateral standard deviation of the wake at the leader's tail
SPREAD = math.tan(math.radians(10.0)) * 4.7 / 2.0  # [widths per length] TORCS' 10-degree cone

FIA_2017_21 = ((1.0, 0.50), (3.0, 0.32), (7.0, 0.21))  # (gap [lengths], downforce loss)
FIA_2022 = ((1.0, 0.14), (3.0, 0.06), (7.0, 0.02))
CERUTTI_2021 = ((0.5, 0.43),)  # (gap [lengths], drag loss of the rear vehicle)


@njit(cache=True)
def wake_shape(gap, g0, q):
    """The wake's decay with the gap ``gap`` [leader lengths, nose to tail]; 1 at ``gap = 0``
    for ``g0, q`` of the curve, 0 at and beyond ``WAKE_RANGE`` and at ``gap <= -1``."""
    if gap <= -1.0 or gap >= WAKE_RANGE:
        return 0.0
    if gap < 0.0:
        return 1.0 + gap
    t = 1.0 - (gap / WAKE_RANGE) ** 2
    return (1.0 + gap / g0) ** (-q) * t * t


@njit(cache=True)
def lateral_weight(gap, lateral):
    """Share of the wake at lateral offset ``lateral`` [leader widths] at gap ``gap``."""
    sigma = SIGMA0 + SPREAD * max(gap, 0.0)
    return math.exp(-0.5 * (lateral / sigma) ** 2)


@njit(cache=True)
def wake_factors(gap_lengths, lateral_widths, strength):
    """``(drag_factor, downforce_factor)`` of a follower ``gap_lengths`` leader lengths behind
    (nose to tail) and ``lateral_widths`` leader widths aside; ``strength`` >= 0 (0: exactly
    ``(1.0, 1.0)``; 1: the published figures)."""
    if not (math.isfinite(strength) and strength >= 0.0):
        raise ValueError("wake strength must be a finite number >= 0")
    w = wake_shape(gap_lengths, G0, Q) * lateral_weight(gap_lengths, lateral_widths)
    return (1.0 - A_DRAG * w) ** strength, (1.0 - A_DOWNFORCE * w) ** strength


@njit(cache=True)
def wake_of_car(i, s, n, length, width, track_length, strength):
    """Wake factors of car ``i`` among cars at unwrapped ``s`` (N,) and offsets ``n`` (N,)
    with leader lengths / widths ``length``, ``width`` (N,): the strongest wake of any car
    ahead (gap modulo ``track_length``) within ``WAKE_RANGE`` of its lengths."""
    drag, down = 1.0, 1.0
    for j in range(s.shape[0]):
        if j == i:
            continue
        ds = (s[j] - s[i]) % track_length
        gap = ds / length[j] - 1.0
        if gap >= WAKE_RANGE:
            continue
        fd, fz = wake_factors(gap, abs(n[j] - n[i]) / width[j], strength)
        drag = min(drag, fd)
        down = min(down, fz)
    return drag, down


def _check_strength(strength) -> float:
    if isinstance(strength, bool) or not (
        isinstance(strength, (int, float, np.integer, np.floating))
        and math.isfinite(strength)
        and strength >= 0
    ):
        raise ValueError(f"wake strength must be a finite number >= 0, got {strength!r}")
    return float(strength)


def wake_factors_cars(
    s: ArrayLike,
    n: ArrayLike,
    length: float | ArrayLike,
    width: float | ArrayLike,
    track_length: float,
    strength: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Batched wake of N cars: ``(drag_factor, downforce_factor)``, arrays (N,).

    ``s`` unwrapped arc lengths [m] (N,), ``n`` lateral offsets [m] (N,), ``length`` and
    ``width`` [m] scalars or (N,) per car, ``track_length`` [m]. Each car takes the strongest
    wake among the cars ahead of it (gap modulo the track length) within ``WAKE_RANGE``
    lengths. Same values as :func:`wake_of_car` (numpy, vectorised over pairs).
    """
    strength = _check_strength(strength)
    s = np.asarray(s, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    if s.ndim != 1 or n.shape != s.shape:
        raise ValueError(f"s and n must be equal 1-d arrays, got shapes {s.shape}, {n.shape}")
    if not (math.isfinite(track_length) and track_length > 0):
        raise ValueError(f"track_length must be a positive number, got {track_length!r}")
    N = s.shape[0]
    length = np.broadcast_to(np.asarray(length, dtype=np.float64), (N,))
    width = np.broadcast_to(np.asarray(width, dtype=np.float64), (N,))
    if not (np.all(length > 0) and np.all(width > 0)):
        raise ValueError("car length and width must be positive")
    ds = np.mod(s[None, :] - s[:, None], track_length)  # [i, j]: car j ahead of car i by ds
    gap = ds / length[None, :] - 1.0
    lat = np.abs(n[None, :] - n[:, None]) / width[None, :]
    inside = (gap < WAKE_RANGE) & (gap > -1.0) & ~np.eye(N, dtype=bool)
    g = np.where(inside, gap, 0.0)
    t = 1.0 - (g / WAKE_RANGE) ** 2
    shape = np.where(g < 0.0, 1.0 + g, (1.0 + np.maximum(g, 0.0) / G0) ** (-Q) * t * t)
    sigma = SIGMA0 + SPREAD * np.maximum(g, 0.0)
    w = np.where(inside, shape * np.exp(-0.5 * (lat / sigma) ** 2), 0.0)
    drag = np.power(1.0 - A_DRAG * w, strength).min(axis=1, initial=1.0)
    down = np.power(1.0 - A_DOWNFORCE * w, strength).min(axis=1, initial=1.0)
    return drag, down


def torcs_drag_factor(distance: float, c_d: float, speed: float) -> float:
    """TORCS' drag factor ``k^2``, ``k = 1 - exp(-2 d / (C_d v))`` (for comparison only):
    ``distance`` centre to centre [m], ``c_d`` the leader's drag coefficient [kg/m], ``speed``
    the leader's [m/s]."""
    k = 1.0 - math.exp(-2.0 * distance / (c_d * speed))
    return k * k


def fit_curve(points: Sequence[tuple[float, float]]) -> tuple[float, float, float]:
    """Fit ``(A, G0, Q)`` of ``A * wake_shape(g)`` through three ``(gap, loss)`` points
    (exactly, by least squares on the logs). Reproduces the module's constants."""
    from scipy.optimize import least_squares

    gs = np.array([p[0] for p in points], dtype=float)
    ls = np.array([p[1] for p in points], dtype=float)

    def res(x):
        a, g0, q = x[0], math.exp(x[1]), x[2]
        return np.log([a * wake_shape(g, g0, q) for g in gs]) - np.log(ls)

    r = least_squares(res, [ls[0] * 2.0, 0.0, 1.0], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return float(r.x[0]), float(math.exp(r.x[1])), float(r.x[2])


def fit_rows() -> list[tuple[str, float, float, float]]:
    """(source, gap [lengths], published loss, fitted loss) of every published point."""
    rows = []
    for g, loss in FIA_2017_21:
        rows.append(("FIA 2017-21 downforce", g, loss, 1.0 - wake_factors(g, 0.0, 1.0)[1]))
    a, g0, q = DOWNFORCE_2022
    for g, loss in FIA_2022:
        rows.append(("FIA 2022 downforce (DOWNFORCE_2022)", g, loss, a * wake_shape(g, g0, q)))
    for g, loss in CERUTTI_2021:
        rows.append(("Cerutti 2021 drag (rear van)", g, loss, 1.0 - wake_factors(g, 0.0, 1.0)[0]))
    return rows


def print_fit() -> None:
    """Print the fitted curves against the published points, and the tow at a few gaps."""
    print("| source | gap [lengths] | published loss | fitted loss |")
    print("|---|---|---|---|")
    for src, g, pub, fit in fit_rows():
        print(f"| {src} | {g:g} | {pub:.0%} | {fit:.2%} |")
    print()
    print("| gap [lengths] | drag factor | downforce factor | TORCS k^2 (80 m/s, 0.75 kg/m) |")
    print("|---|---|---|---|")
    for g in (0.5, 1.0, 3.0, 7.0, 16.0, 30.0, 60.0):
        fd, fz = wake_factors(g, 0.0, 1.0)
        torcs = torcs_drag_factor((g + 1.0) * 4.7, 0.75, 80.0)
        print(f"| {g:g} | {fd:.3f} | {fz:.3f} | {torcs:.3f} |")


def plot_curves(path: str | Path) -> None:
    """Figure of the wake's curves: the drag and downforce factors at full strength against
    the gap (straight behind, and half and one width aside), with the published points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    g = np.linspace(0.0, 30.0, 301)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=True)
    for ax, k, name, pts in (
        (axes[0], 0, "drag factor (tow)", CERUTTI_2021),
        (axes[1], 1, "downforce factor (dirty air)", FIA_2017_21),
    ):
        for y, style in ((0.0, "-"), (0.5, "--"), (1.0, ":")):
            ax.plot(g, [wake_factors(x, y, 1.0)[k] for x in g], style, label=f"{y:g} width aside")
        ax.plot([p[0] for p in pts], [1.0 - p[1] for p in pts], "ko", label="published")
        ax.set_xlabel("gap behind the leader [car lengths, nose to tail]")
        ax.set_title(name)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("factor (1 = clean air)")
    axes[1].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="The wake's fitted curves (print, or --plot a figure)")
    ap.add_argument("--plot", metavar="PNG", help="write the curves' figure to this file")
    a = ap.parse_args()
    if a.plot:
        plot_curves(a.plot)
    else:
        print_fit()
