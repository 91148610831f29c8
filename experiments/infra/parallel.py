"""Run independent tasks on a local process pool or a Ray cluster (one code path for both).

Tasks are ``fn(*args)`` for each ``args`` of a list; ``fn`` must be a picklable module-level
function without file access (a remote Ray worker need not share the driver's disk). Each
result goes to ``finished(key, result)`` in the driver as soon as it arrives, so a driver that
writes results there loses no finished work when it is killed.

Every task runs with one native thread per library (BLAS, OpenMP, torch, numba; see
:mod:`agents.threads`): pinned for good in pool and Ray workers (the workers are the
parallelism; two BLAS threads in each of two workers on two cores made decisions ten times
slower), for the task's duration when ``workers = 1`` runs it in the driver. So a task's
result does not hang on the worker count, backend or thread variables (the tests compare
bench and collect runs with 1 and 2 workers bit for bit).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass

BACKENDS = ("local", "ray")


def check_backend(backend: str, workers) -> None:
    """Raise a ValueError naming the bad ``backend`` or ``workers``."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    if not (isinstance(workers, int) and workers >= 1):
        raise ValueError(f"workers must be a positive integer, got {workers!r}")


@dataclass(frozen=True)
class Pool:
    """Where the drivers' tasks run, checked when made (:func:`check_backend`).

    ``backend="local"``: a process pool of ``workers`` (``workers = 1`` runs in this process).
    ``backend="ray"``: Ray tasks on the cluster at ``address`` (``None`` starts a local Ray
    with ``workers`` CPUs). ``progress_bar``: show the tqdm bar of the run."""

    workers: int = 2
    backend: str = "local"
    address: str | None = None
    progress_bar: bool = True

    def __post_init__(self) -> None:
        check_backend(self.backend, self.workers)


def pin_worker() -> None:
    """Pool initialiser: one native thread per library in this worker, for good."""
    from agents.threads import pin_threads

    pin_threads(1)


_pinned = False


def _pinned_call(fn, *args):
    """``fn(*args)`` in a Ray worker, pinned to one thread per library at its first task."""
    global _pinned
    if not _pinned:
        pin_worker()
        _pinned = True
    return fn(*args)


def run_tasks(
    fn: Callable,
    tasks: Sequence[tuple[Hashable, tuple]],
    finished: Callable[[Hashable, object], None],
    pool: Pool = Pool(),
) -> None:
    """Run ``fn(*args)`` for every ``(key, args)`` of ``tasks`` on ``pool`` (its progress bar
    aside); call ``finished(key, result)`` in this process as results arrive (completion
    order). An exception in a task propagates.
    """
    if not tasks:
        return
    if pool.backend == "ray":
        _run_ray(fn, tasks, finished, pool.workers, pool.address)
    elif pool.workers <= 1:
        from agents.threads import limited_threads

        for key, args in tasks:
            with limited_threads(1):
                result = fn(*args)
            finished(key, result)
    else:
        with ProcessPoolExecutor(max_workers=pool.workers, initializer=pin_worker) as ex:
            futures = {ex.submit(fn, *args): key for key, args in tasks}
            for f in as_completed(futures):
                finished(futures[f], f.result())


def run_tasks_with_progress(
    fn: Callable,
    tasks: Sequence[tuple[Hashable, tuple]],
    finished: Callable[[Hashable, object], None],
    pool: Pool = Pool(),
    *,
    total: int,
    done: int = 0,
    desc: str,
    unit: str,
    count: Callable[[Hashable], int] | None = None,
    postfix: Callable[[Hashable, object], str] | None = None,
) -> None:
    """:func:`run_tasks` behind a tqdm bar of ``total`` units (``done`` of them finished
    before; no bar without ``pool.progress_bar``): after ``finished(key, result)`` the bar
    advances by ``count(key)`` (default 1) and shows ``postfix(key, result)`` as ``last=``.
    The bar closes even when a task raises."""
    from tqdm import tqdm

    with tqdm(
        total=total,
        initial=done,
        unit=unit,
        desc=desc,
        disable=not pool.progress_bar,
        smoothing=0.05,
    ) as bar:

        def on_result(key, result):
            finished(key, result)
            bar.update(1 if count is None else count(key))
            if postfix is not None:
                bar.set_postfix(last=postfix(key, result))

        run_tasks(fn, tasks, on_result, pool)


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
        task = ray.remote(num_cpus=1)(_pinned_call)
        pending = {task.remote(fn, *args): key for key, args in tasks}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                finished(pending.pop(ref), ray.get(ref))
    finally:
        if started:
            ray.shutdown()
