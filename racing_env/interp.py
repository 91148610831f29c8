"""Periodic linear interpolation on a uniform closed grid: the one implementation used by the
track, the simulator, the racing line and the general features.

A table holds values at grid points ``0, ds, 2 ds, ...`` of a closed lap of ``length`` [m]; a
lookup at unwrapped arc length ``s`` wraps ``s`` into ``[0, length)``, takes grid coordinate
``f = s_wrapped / ds`` and interpolates linearly between entries ``floor(f)`` and
``floor(f) + 1`` (both modulo the table size). :func:`periodic_interp` does it with numpy on
arrays of any shape, :func:`periodic_lookup` for one ``s`` inside numba kernels; they do the
same floating-point operations in the same order, so they agree bit for bit
(``tests/test_interp.py``).
"""

from __future__ import annotations

import numpy as np
from numba import njit


def periodic_interp(
    table: np.ndarray,
    s: float | np.ndarray,
    length: float,
    ds: float | None = None,
    *,
    per_metre: float | None = None,
    size: int | None = None,
    offset: int = 0,
    snap: float = 0.0,
) -> np.ndarray:
    """Periodic linear interpolation of ``table`` at unwrapped arc lengths ``s`` [m].

    ``table`` (..., M): values at the grid points (the last axis; leading axes are
    interpolated alike). ``length`` [m] the lap length, ``ds`` [m] the grid spacing; or
    ``per_metre`` [1/m] the grid points per metre (the grid coordinate is then
    ``s_wrapped * per_metre``, as the racing line indexes its tables, instead of
    ``s_wrapped / ds``: the two round differently). ``size`` the number of grid points of a
    lap (default M) and ``offset`` the index of its first entry, for many laps stored end to
    end in one table; ``length``, ``ds``, ``per_metre``, ``size`` and ``offset`` may be arrays
    that broadcast with ``s``. ``snap`` > 0 moves a grid coordinate within ``snap`` of an
    integer onto it (grid points then return their own entry exactly). Returns shape
    ``table.shape[:-1] + s.shape``.
    """
    if (ds is None) == (per_metre is None):
        raise ValueError(
            f"give exactly one of ds and per_metre, got ds={ds!r}, per_metre={per_metre!r}"
        )
    sw = np.mod(np.asarray(s, dtype=float), length)
    f = sw / ds if per_metre is None else sw * per_metre
    if snap:
        r = np.rint(f)
        f = np.where(np.abs(f - r) < snap, r, f)
    fl = np.floor(f)
    m = table.shape[-1] if size is None else size
    i0 = fl.astype(np.int64) % m
    t = f - fl
    return table[..., offset + i0] * (1.0 - t) + table[..., offset + (i0 + 1) % m] * t


@njit(cache=True)
def periodic_lookup(table, s, ds, length):
    """:func:`periodic_interp` of a 1-D ``table`` at one ``s`` [m] (grid spacing ``ds``, lap
    ``length`` [m]), for numba kernels."""
    f = (s % length) / ds
    i = int(f)
    t = f - i
    m = table.shape[0]
    i = i % m
    return table[i] * (1.0 - t) + table[(i + 1) % m] * t
