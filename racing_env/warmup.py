"""The env's numba kernels compiled in a background process on a cold cache, while the caller
builds its agents: :func:`start_env_warmup`.

On a cold cache a race compiles the env's kernels (the step with its contact rule, the
observations; about 10 s of CPU) at its first step, after the agents' reset and their first
decisions, all on one core. A worker process that builds the same env and steps it once
compiles them on another core meanwhile and writes them to numba's cache, where the race's own
first step finds them (numba looks a kernel up in its cache before compiling it). The kernels
are the ones the race would compile itself, so races stay the same bit for bit. Should the
race get there first, it compiles the kernel itself, as without the worker.

Once the worker has stepped its env it leaves a marker in numba's cache folder (named by a
hash of the sources, so an edit of either package starts over); with the marker there, no
worker is started, nor when numba's cache holds a kernel of :mod:`racing_env.simulator` (an
env has stepped there: a warm cache costs a look-up in one folder). Nor is one started when
the machine has no idle core (the threads running now): there the worker would only take CPU
from the race.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

#: the :class:`~racing_env.RacingParallelEnv` arguments a warm-up takes (plain values only)
WARMUP_ARGS = ("track", "n_cars", "max_cycles", "laps", "start", "vehicle_class", "wake")


def start_env_warmup(*, busy_ok: bool = False, **env_kwargs: Any) -> subprocess.Popen | None:
    """Start a worker process that compiles the kernels of ``RacingParallelEnv(**env_kwargs)``
    into numba's cache (it builds that env, resets it and steps it once with zero actions);
    returns it, or None when there is nothing to do: the kernels were warmed before for these
    arguments, an env has stepped on this cache (numba's cache holds kernels of
    :mod:`racing_env.simulator`), numba does not cache (``NUMBA_DISABLE_JIT``), an argument is not among
    :data:`WARMUP_ARGS` or not a plain value (a :class:`~racing_env.Track` object), or no core
    is idle (:func:`idle_cores` under 0.5; ``busy_ok`` starts one anyway). The worker's output
    is discarded; the caller need not wait for it (a kernel it has not cached yet is compiled
    by the caller as usual)."""
    marker = _marker(env_kwargs)
    if marker is None or marker.exists() or any(marker.parent.rglob("simulator.*.nbi")):
        return None  # warmed before, or an env stepped here (numba's index of its kernels)
    if not busy_ok and idle_cores() < 0.5:
        return None
    args = json.dumps(env_kwargs, sort_keys=True)
    return subprocess.Popen(
        [sys.executable, "-m", "racing_env.warmup", args],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def idle_cores(samples: int = 5) -> float:
    """Cores this process may use minus the threads running now (this one included; Linux's
    ``/proc/loadavg``, the mean of ``samples`` looks 10 ms apart), elsewhere minus the 1-minute
    load average: about 1 on an otherwise idle 2-core machine, 0 or less when it is busy."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    try:  # "0.52 0.58 0.59 2/345 12345": the 4th field is running/existing threads
        running = []
        for i in range(samples):
            if i:
                time.sleep(0.01)
            running.append(int(Path("/proc/loadavg").read_text().split()[3].split("/")[0]))
        return cores - sum(running) / len(running)
    except (OSError, IndexError, ValueError):
        pass
    try:
        return cores - os.getloadavg()[0]
    except (AttributeError, OSError):  # no load average (Windows): assume a free core
        return float(cores)


def _marker(env_kwargs: dict[str, Any]) -> Path | None:
    """The marker file of a finished warm-up of ``env_kwargs``, None if they cannot be warmed."""
    import numba

    config: Any = numba.config  # it sets its names at run time (from the environment)
    if config.DISABLE_JIT or not set(env_kwargs) <= set(WARMUP_ARGS):
        return None
    if not all(v is None or isinstance(v, (str, int, float)) for v in env_kwargs.values()):
        return None
    key = hashlib.sha1(json.dumps(env_kwargs, sort_keys=True).encode()).hexdigest()[:16]
    # racing_env.cache points numba.config.CACHE_DIR at the source-hashed folder on import
    return Path(config.CACHE_DIR) / f"env-warmup-{key}.done"


def warm(env_kwargs: dict[str, Any]) -> None:
    """Build ``RacingParallelEnv(**env_kwargs)``, reset it and step it once (every step kernel
    compiled and cached), then leave the marker of :func:`start_env_warmup`."""
    import numpy as np

    from racing_env.files import atomic_path
    from racing_env.parallel_env import RacingParallelEnv

    env = RacingParallelEnv(**env_kwargs)
    env.reset(seed=0)
    env.step({agent: np.zeros(2) for agent in env.agents})
    env.close()
    marker = _marker(env_kwargs)
    if marker is not None:
        with atomic_path(marker) as tmp:
            tmp.write_text(json.dumps(env_kwargs, sort_keys=True) + "\n")


if __name__ == "__main__":
    warm(json.loads(sys.argv[1]))
