"""Native thread pools of the numerical libraries (OpenBLAS/MKL under numpy, OpenMP, torch,
numba): one thread where results must not depend on the machine's thread count.

Two reasons. Parallel workers are already the parallelism: a BLAS pool of two threads in each of
two workers on two cores spins and swaps (a decision of the alpha agent in ``bench --workers 2``
measured 48 ms instead of 5). And a multi-threaded matrix product may split its sums
differently with another thread count (OpenBLAS does for some shapes); a race whose outcome
hangs on a last bit must not change with ``OPENBLAS_NUM_THREADS``.

* :func:`pin_threads`: for the whole process (a worker process, once at its start).
* :func:`limited_threads`: for a block, restoring the previous limits (a task run in the
  driver process).
* :func:`single_blas_thread`: a cheap (~10 us) block limiting only the BLAS pool, for every
  decision of an agent (the alpha agent's potential maximisation and MPC).
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator

#: variables read by the pools a process starts later (OpenMP of a torch imported afterwards)
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _numba_launched() -> bool:
    parallel = sys.modules.get("numba.np.ufunc.parallel")
    return bool(parallel is not None and parallel._is_initialized)


def _set_torch_numba(n: int) -> tuple:
    """Set torch's intra-op threads and numba's threads for parallel kernels to ``n`` where
    these are loaded and started (neither is imported nor started here: numba's pool started
    before a fork is unsafe in the children, and numba's OpenMP pool started beside torch's
    froze a worker in torch's next OpenMP region); returns the previous counts. numba's parallel
    kernels (the batched simulator over races) give the same result with any thread count:
    each race is one thread's work."""
    old_torch = old_numba = None
    torch = sys.modules.get("torch")
    if torch is not None:
        old_torch = torch.get_num_threads()
        torch.set_num_threads(n)
    if _numba_launched():
        numba = sys.modules["numba"]
        old_numba = numba.get_num_threads()
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    return old_torch, old_numba


def pin_threads(n: int = 1) -> None:
    """Limit every native thread pool of this process to ``n`` threads, for good: the pools
    already loaded (threadpoolctl), the variables for pools started later, torch and numba.
    Meant for worker processes (a pool initialiser, a Ray task's first call); sets the
    process's :func:`thread_budget` to ``n``."""
    global _budget
    from threadpoolctl import threadpool_limits

    for var in THREAD_VARIABLES:
        os.environ[var] = str(n)
    threadpool_limits(n)
    _set_torch_numba(n)
    _budget = n


_budget: int | None = None  # the process's thread budget, where set (pin/limited_threads)


def thread_budget() -> int:
    """Threads this process's own parallel work may use (the MPC steps of a lockstep batch,
    :func:`agents.mpc.compiled_solve.solve_many`): the count of :func:`pin_threads` or the
    innermost :func:`limited_threads` block, else the machine's cores. Python threads over
    compiled code that releases the GIL, not an OpenMP pool: safe beside torch's and after a
    fork."""
    return _budget or os.cpu_count() or 1


@contextmanager
def limited_threads(n: int = 1) -> Iterator[None]:
    """Every native thread pool at ``n`` threads inside the block, the previous limits after
    it. Costs about a millisecond (it scans the loaded libraries): once per task, not per step."""
    from threadpoolctl import threadpool_limits

    global _budget
    with threadpool_limits(n):
        old_torch, old_numba = _set_torch_numba(n)
        old_budget, _budget = _budget, n
        try:
            yield
        finally:
            _budget = old_budget
            if old_torch is not None:
                sys.modules["torch"].set_num_threads(old_torch)
            if old_numba is not None:
                sys.modules["numba"].set_num_threads(old_numba)


_controller = None
_depth = 0
_blas: list = []


@contextmanager
def single_blas_thread() -> Iterator[None]:
    """numpy's BLAS at one thread inside the block (nested blocks cost nothing more).

    Small matrix products of the agents run as fast on one thread, and their results then do
    not depend on the process's BLAS thread count. Uses one threadpoolctl controller per
    process, made at the first call (BLAS is loaded with numpy, before any agent runs). The
    limit is process-wide while the block runs: meant for agents acting from one Python
    thread, as the envs' loops do."""
    global _controller, _depth, _blas
    if _depth:
        _depth += 1
        try:
            yield
        finally:
            _depth -= 1
        return
    if _controller is None:
        from threadpoolctl import ThreadpoolController

        _controller = ThreadpoolController()
        _blas = _controller.select(user_api="blas").lib_controllers
    _depth = 1
    try:
        if all(lib.num_threads == 1 for lib in _blas):  # a pinned worker: nothing to switch
            yield  # (3 us against 21 us for the switch)
        else:
            with _controller.limit(limits=1, user_api="blas"):
                yield
    finally:
        _depth = 0
