"""Checks of the config dataclasses' fields, each message naming the config and the field."""

from __future__ import annotations

import numpy as np


def check_counts(config: object, names, minimum: int = 1) -> None:
    """Each field of ``config`` named in ``names`` an integer (Python's or numpy's, never a
    bool) of at least ``minimum`` (1: a count, 0: a seed); else a ValueError naming the
    config's class, the field and the value."""
    what = {1: "a positive integer", 0: "a non-negative integer"}.get(
        minimum, f"an integer >= {minimum}"
    )
    for name in names:
        v = getattr(config, name)
        if isinstance(v, bool) or not (isinstance(v, (int, np.integer)) and v >= minimum):
            raise ValueError(f"{type(config).__name__}.{name} must be {what}, got {v!r}")
