"""Compile the env's step kernel in a background process on a cold cache.

On a fresh cache the step kernel (:func:`racing_env.simulator.advance`, with the integrator and
the contact rule) is the largest single numba compile of a race, and nothing else a race does
before its first step needs it. :func:`start` launches ``python -m racing_env.warmup``, which
compiles it into the shared cache folder (:mod:`racing_env.cache`) on another core while this
process builds the racing line and the agents' code; :func:`wait`, called by
:class:`racing_env.core.BatchedRaces` before its first step, waits for that process, and the
kernel is then loaded from the cache like any cached kernel. Same kernel, same races bit for
bit: only where it is compiled changes. When the kernel is already cached, or compiled in this
process, nothing is started; when the worker fails, this process compiles it itself.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys

_worker: subprocess.Popen | None = None

WAIT_S = 600.0
"""Longest wait [s] for the worker before compiling here instead."""


def _cached() -> bool:
    """Whether the serial step kernel is compiled in this process or has a cache index on disk
    (when numba's cache layout cannot be read: treated as cached, nothing is started)."""
    from .simulator import advance

    if advance.signatures:
        return True
    try:
        cache = advance._cache  # type: ignore[attr-defined]  # numba's private layout
        index = cache._cache_file._index_path
    except AttributeError:
        return True
    return os.path.exists(index)


def start() -> bool:
    """Start compiling the step kernel in a background process if it is not cached yet (once
    per process; ``ALPHA_RACER_WARMUP=0`` turns it off). Returns whether a worker runs."""
    global _worker
    if _worker is not None:
        return True
    if os.environ.get("ALPHA_RACER_WARMUP", "1") == "0" or _cached():
        return False
    try:
        _worker = subprocess.Popen(
            [sys.executable, "-m", "racing_env.warmup"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    except OSError:
        return False
    atexit.register(_stop)
    return True


def wait() -> None:
    """Wait for the worker started by :func:`start`, if any (its kernel then loads from the
    cache at the first step)."""
    global _worker
    if _worker is None:
        return
    try:
        _worker.wait(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        _worker.kill()
    _worker = None


def _stop() -> None:
    if _worker is not None and _worker.poll() is None:
        _worker.kill()


def main() -> None:
    """The worker: one step of a small race, which compiles the serial step kernel (its
    argument types are the same for every track, vehicle class and field size)."""
    import numpy as np

    from .config import RaceConfig
    from .core import BatchedRaces

    races = BatchedRaces("default", RaceConfig(n_cars=2))
    races._advance(np.zeros((1, 2, 2)), normalised=True)


if __name__ == "__main__":
    main()
