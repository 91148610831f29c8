"""Run independent tasks on a local process pool or a Ray cluster (one code path for both).

Tasks are ``fn(*args)`` for each ``args`` of a list; ``fn`` must be a picklable module-level
function without file access (a remote Ray worker need not share the driver's disk). Each
result goes to ``finished(key, result)`` in the driver as soon as it arrives, so a driver that
writes results there loses no finished work when it is killed.
"""
from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Hashable, Sequence

BACKENDS = ("local", "ray")


def check_backend(backend: str, workers) -> None:
    """Raise a ValueError naming the bad ``backend`` or ``workers``."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    if not (isinstance(workers, int) and workers >= 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")


def _single_threaded() -> None:
    """Pool initialiser: one torch thread per worker (the workers are the parallelism). The
    variables reach the thread pools a worker starts itself (OpenMP of a torch first imported
    there); numpy's BLAS, loaded before the fork, keeps the driver's setting."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"
    try:
        import torch
        torch.set_num_threads(1)
    except ImportError:
        pass


def run_tasks(fn: Callable, tasks: Sequence[tuple[Hashable, tuple]],
              finished: Callable[[Hashable, object], None], workers: int = 2,
              backend: str = "local", address: str | None = None) -> None:
    """Run ``fn(*args)`` for every ``(key, args)`` of ``tasks``; call ``finished(key, result)``
    in this process as results arrive (completion order).

    ``backend="local"``: a process pool of ``workers`` (``workers = 1`` runs in this process).
    ``backend="ray"``: Ray tasks on the cluster at ``address`` (``None`` starts a local Ray
    with ``workers`` CPUs). An exception in a task propagates.
    """
    check_backend(backend, workers)
    if not tasks:
        return
    if backend == "ray":
        _run_ray(fn, tasks, finished, workers, address)
    elif workers <= 1:
        for key, args in tasks:
            finished(key, fn(*args))
    else:
        with ProcessPoolExecutor(max_workers=workers, initializer=_single_threaded) as pool:
            futures = {pool.submit(fn, *args): key for key, args in tasks}
            for f in as_completed(futures):
                finished(futures[f], f.result())


def _run_ray(fn, tasks, finished, workers, address) -> None:
    try:
        import ray
    except ImportError:
        raise ImportError("the ray backend needs Ray: pip install 'alpha-racer[ray]'") from None
    started = not ray.is_initialized()
    if started:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False)
    try:
        task = ray.remote(num_cpus=1)(fn)
        pending = {task.remote(*args): key for key, args in tasks}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                finished(pending.pop(ref), ray.get(ref))
    finally:
        if started:
            ray.shutdown()
