"""The cars just ahead and just behind a car, in race order (the paper's ``j^*`` and ``j_*``):
:func:`opponent_neighbours`. :mod:`agents.reference` re-exports it."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    pass

__all__ = ["opponent_neighbours"]


def opponent_neighbours(ego_s: float, opp_s: np.ndarray, length: float) -> tuple[int, int]:
    """Indices ``(ahead, behind)`` into ``opp_s`` of the car just ahead (``j^*``) and just
    behind (``j_*``) the ego, ``-1`` where there is none.

    ``ego_s`` [m] scalar and ``opp_s`` [m] shape (m,), m >= 0, are *unwrapped* progress.
    The choice: neighbours are ranked by the unwrapped progress difference ``d = opp_s - ego_s``
    (race order), not by the physical gap ``d mod length``:

    * ahead = the smallest ``d >= 0`` (a car exactly level counts as ahead), behind = the
      largest ``d < 0``; ties go to the lowest index;
    * a car 0.2 m behind across the start/finish line (ego ``L + 0.1``, car ``L - 0.1``) has
      ``d = -0.2``: it is just behind, with no special case at the line;
    * a car a full lap ahead (``d = L + 0.1``) is *not* 0.1 m ahead; it is "ahead" only if no
      car is nearer in unwrapped progress. Likewise a lapped car physically in front of the ego
      is a car far behind in race order. This keeps the neighbours the cars one is racing for
      position with (and keeps the shift formulas' ``exp(-s2 ds^2)`` negligible for them).

    ``length`` [m] (positive, finite) is the lap length; it is validated but, by the choice
    above, not used to wrap differences.
    """
    e = float(ego_s)
    if not math.isfinite(e):
        raise ValueError(f"ego_s must be finite, got {ego_s!r}")
    L = float(length)
    if not (math.isfinite(L) and L > 0):
        raise ValueError(f"length must be a positive finite number, got {length!r}")
    o = np.asarray(opp_s, dtype=float)
    if o.ndim != 1:
        raise ValueError(f"opp_s must be a 1-D array of unwrapped positions, got shape {o.shape}")
    if o.size == 0:
        return -1, -1
    if not np.all(np.isfinite(o)):
        i = int(np.flatnonzero(~np.isfinite(o))[0])
        raise ValueError(f"opp_s[{i}] must be finite, got {o[i]!r}")
    return _neighbours_list((o - e).tolist())


def _neighbours_list(d) -> tuple[int, int]:
    """(ahead, behind) from a list of unwrapped differences (pure Python, m <= a few)."""
    ahead = behind = -1
    best_a, best_b = math.inf, -math.inf
    for i, di in enumerate(d):
        if di >= 0.0:
            if di < best_a:
                best_a, ahead = di, i
        elif di > best_b:
            best_b, behind = di, i
    return ahead, behind
