"""Step 6 of :func:`agents.reference.reference_trajectory`, the wake policy space's moves
(:data:`agents.theta.WAKE_BOUNDS_DOC`): hold the tow, pull out before the braking point,
cover the inside of the coming corner."""

from __future__ import annotations

import numpy as np

from racing_env.track import STRAIGHT_KAPPA_LENGTHS
from racing_env.vehicle import VehicleParams

from .reference_tables import _interp1, _Tables
from .theta import Theta

_ORCA = VehicleParams()  # the default size (built once, not in every decision)


def wake_moves(
    th: Theta,
    x: np.ndarray,
    rows: list,
    ahead: int,
    behind: int,
    tab: _Tables,
    vehicle: object | None,
    w_half: float,
    s_e_w: float,
    n_ref: np.ndarray,
    n_ot: np.ndarray,
    n_bl: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(n_ref, n_ot, n_bl)`` (K,) after the wake space's hold, pull-out and cover, for the
    ego ``x`` (6,), the other cars' states ``rows`` (lists of 6), the neighbours' indices
    ``ahead`` / ``behind`` (-1: none), the race line's tables ``tab`` (its braking points),
    the car ``vehicle`` (None: the ORCA car), half its width ``w_half`` [m] and its wrapped
    progress ``s_e_w`` [m] (:func:`~agents.reference.reference_trajectory`, step 6)."""
    length = float(getattr(vehicle, "length", _ORCA.length))
    width = float(getattr(vehicle, "width", _ORCA.width))
    s_e, n_e = float(x[0]), float(x[1])
    d_b, d_apex, side = tab.next_brake(s_e_w)
    pull = th.p * length
    if th.h > 0.0 and ahead >= 0 and d_b > pull:
        s_j, n_j = rows[ahead][0], rows[ahead][1]
        straight = abs(_interp1(tab.kap, s_e_w, tab.inv_ds)) * length < STRAIGHT_KAPPA_LENGTHS
        if 0.0 < s_j - s_e <= th.h * length and abs(n_j - n_e) < TOW_RANGE[1] * width and straight:
            zeros = np.zeros_like(n_ref)
            return np.full_like(n_ref, n_j), zeros, zeros.copy()
    if th.c > 0.0 and behind >= 0 and d_b <= pull and side != 0.0:
        s_j, n_j = rows[behind][0], rows[behind][1]
        in_tow = s_e - s_j <= TOW_RANGE[0] * length and abs(n_j - n_e) < TOW_RANGE[1] * width
        if s_e - s_j > 0.0 and in_tow:
            s_apex = (s_e_w + d_apex) % tab.L
            edge = _interp1(tab.wl if side > 0 else tab.wr, s_apex, tab.inv_ds)
            inside = side * (edge - w_half)
            n_ref = n_ref + th.c * (inside - n_ref)
    return n_ref, n_ot, n_bl


#: A car is in a wake (step 1c of :func:`~agents.reference.reference_trajectory`; the wake
#: space's cover) with another car at most this many car lengths ahead and this many car
#: widths to the side: where the wake's drag factor is below 0.91 (racing_env.wake).
TOW_RANGE = (15.0, 1.5)
