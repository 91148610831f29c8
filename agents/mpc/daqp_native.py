"""DAQP's C solver called from numba nopython code: one QP, or a batch of them across threads.

The MPC solves its QPs with ``daqp.solve``, DAQP's Python binding, which keeps the SQP loop in
Python. This module calls the same C function the binding calls, ``daqp_quadprog``, from
compiled code, so a compiled loop can solve its QPs without returning to Python:

* :func:`solve_qp` solves one QP, bit for bit as ``daqp.solve`` does with the same arguments;
* :func:`solve_qps` solves a batch of independent QPs of different sizes (padded arrays), one
  problem per ``numba.prange`` iteration, each exactly as :func:`solve_qp` alone.

How it reaches the C code. The binding (daqp 0.11.0) is one extension module that exports DAQP's
C symbols. Its file is loaded with :mod:`ctypes` (it is already loaded by ``import daqp``; the
same copy is used) and the addresses of ``daqp_quadprog`` and ``daqp_default_settings`` are
registered with LLVM under the names ``alpha_racer_daqp_quadprog`` and
``alpha_racer_daqp_default_settings``; compiled code calls them by name, so the kernels cache on
disk (the address is looked up again in each process; only where :data:`AVAILABLE`, since a
cached kernel would otherwise call an unregistered name). The C structs are numpy
records (:data:`PROBLEM`, :data:`SETTINGS`, :data:`RESULT`) laid out from :mod:`ctypes`
mirrors of DAQP 0.11.0's ``types.h`` / ``api.h`` (field order, ``int`` as ``c_int``, natural
alignment: ``DAQPProblem`` 80 bytes, ``DAQPSettings`` 136, ``DAQPResult`` 64 on x86-64, as the
extension's own debug information has them); compiled code fills them in arrays it owns, so no
Python object is touched inside a call, and the GIL is released (``nogil``).

What ``daqp.solve(H, f, A, bupper, blower, sense, rho_soft=r, iter_limit=k)`` does, and so
what these do: the problem ``n`` = columns of ``A`` (here ``len(f)``, the same for any
``A`` with rows), ``m`` = length of ``bupper``,
``ms = m - rows(A)`` (the first ``ms`` entries of the bounds are simple bounds on ``x[:ms]``),
pointers to the caller's data (``A`` NULL without rows; bounds and ``sense`` NULL if ``m`` is
0), ``break_points`` NULL, ``nh = 0``, ``problem_type = 0`` (a QP); the settings at DAQP's
defaults (``daqp_default_settings``, the same values as the binding's keyword defaults, which
the import checks) except ``rho_soft`` and ``iter_limit``; then ``daqp_quadprog``. DAQP reads
the problem's arrays and does not write them (the binding passes the caller's arrays too).

Memory. ``daqp_quadprog`` allocates its workspace with ``malloc`` and frees it in every call,
as it does under ``daqp.solve``; this first version keeps that (a per-thread persistent
workspace through ``setup_daqp``/``daqp_solve`` would save the allocations but is not what the
binding does). The C library keeps no global state, so calls on different threads are
independent.

Safety checks at import (else :data:`AVAILABLE` is False, :data:`UNAVAILABLE_REASON` says why
and compiling :func:`solve_qp` raises an error naming it): daqp importable at version 0.11.0
(the layouts are DAQP 0.11.0's), both symbols exported, ``daqp_default_settings`` writes
exactly ``sizeof(DAQPSettings)`` bytes (a guard after the record is untouched) and the values
``daqp.solve``'s signature has, and a small QP solved through the records gives what
``daqp.solve`` gives.
"""

from __future__ import annotations

import ctypes
import importlib.metadata
import inspect

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

DAQP_VERSION = "0.11.0"
"""The daqp release whose C structs the records below mirror."""

_SYMBOLS = ("daqp_quadprog", "daqp_default_settings")
_PREFIX = "alpha_racer_"

_ADDR = ctypes.c_size_t  # a C pointer, held as an integer address of the same size


class _Problem(ctypes.Structure):
    """``DAQPProblem`` of DAQP 0.11.0 (``include/types.h``)."""

    _fields_ = [
        ("n", ctypes.c_int),
        ("m", ctypes.c_int),
        ("ms", ctypes.c_int),
        ("H", _ADDR),  # c_float* (double)
        ("f", _ADDR),
        ("A", _ADDR),
        ("bupper", _ADDR),
        ("blower", _ADDR),
        ("sense", _ADDR),  # int*
        ("break_points", _ADDR),  # int*
        ("nh", ctypes.c_int),
        ("problem_type", ctypes.c_int),
    ]


class _Settings(ctypes.Structure):
    """``DAQPSettings`` of DAQP 0.11.0 (``include/types.h``)."""

    _fields_ = [
        ("primal_tol", ctypes.c_double),
        ("dual_tol", ctypes.c_double),
        ("zero_tol", ctypes.c_double),
        ("pivot_tol", ctypes.c_double),
        ("progress_tol", ctypes.c_double),
        ("cycle_tol", ctypes.c_int),
        ("iter_limit", ctypes.c_int),
        ("fval_bound", ctypes.c_double),
        ("eps_prox", ctypes.c_double),
        ("eta_prox", ctypes.c_double),
        ("rho_soft", ctypes.c_double),
        ("rel_subopt", ctypes.c_double),
        ("abs_subopt", ctypes.c_double),
        ("sing_tol", ctypes.c_double),
        ("refactor_tol", ctypes.c_double),
        ("time_limit", ctypes.c_double),
        ("w_soft", ctypes.c_double),
        ("eq_reduction", ctypes.c_int),
        ("presolve", ctypes.c_int),
    ]


class _Result(ctypes.Structure):
    """``DAQPResult`` of DAQP 0.11.0 (``include/api.h``)."""

    _fields_ = [
        ("x", _ADDR),  # c_float*, n entries written
        ("lam", _ADDR),  # c_float*, m entries written
        ("fval", ctypes.c_double),
        ("soft_slack", ctypes.c_double),
        ("exitflag", ctypes.c_int),
        ("iter", ctypes.c_int),
        ("nodes", ctypes.c_int),
        ("solve_time", ctypes.c_double),
        ("setup_time", ctypes.c_double),
    ]


PROBLEM = np.dtype(_Problem, align=True)
"""numpy record of ``DAQPProblem`` (pointers as ``uintp`` addresses)."""
SETTINGS = np.dtype(_Settings, align=True)
"""numpy record of ``DAQPSettings``."""
RESULT = np.dtype(_Result, align=True)
"""numpy record of ``DAQPResult`` (pointers as ``uintp`` addresses)."""

# ---------------------------------------------------------------- loading and checks


def _load() -> str:
    """Register the C symbols with LLVM after the checks of the module docstring; returns ""
    on success, else why the native solver is not available."""
    import llvmlite.binding as llvm

    try:
        import daqp
    except ImportError as e:
        return f"the package daqp is not importable ({e})"
    try:
        version = importlib.metadata.version("daqp")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    if version != DAQP_VERSION:
        return f"daqp {version} is installed; the C struct layouts here are daqp {DAQP_VERSION}'s"
    try:
        lib = ctypes.CDLL(daqp.__file__)
    except OSError as e:
        return f"cannot load daqp's extension {daqp.__file__} with ctypes ({e})"
    missing = [s for s in _SYMBOLS if not hasattr(lib, s)]
    if missing:
        return f"daqp's extension {daqp.__file__} exports no C symbol {', '.join(missing)}"
    guard = 64
    buf = np.full(SETTINGS.itemsize + guard, 0xA5, np.uint8)
    lib.daqp_default_settings.restype = None
    lib.daqp_default_settings(ctypes.c_void_p(buf.ctypes.data))
    if not np.all(buf[SETTINGS.itemsize :] == 0xA5):
        return "daqp_default_settings writes past DAQPSettings as laid out here"
    defaults = buf[: SETTINGS.itemsize].view(SETTINGS)[0]
    try:
        params = inspect.signature(daqp.solve).parameters
    except (TypeError, ValueError) as e:
        return f"cannot read daqp.solve's keyword defaults ({e})"
    for name in (field[0] for field in _Settings._fields_):
        if name not in params or params[name].default != defaults[name]:
            got = params[name].default if name in params else "absent"
            return (
                f"daqp_default_settings gives {name} = {defaults[name]}, daqp.solve {got}: "
                "the layout or the binding's defaults differ from daqp " + DAQP_VERSION
            )
    # a small QP through the records against the binding: a simple bound, a soft row, a row
    lib.daqp_quadprog.restype = None
    H = np.array([[2.0, 0.5], [0.5, 1.0]])
    f = np.array([1.0, -1.0])
    A = np.array([[1.0, 1.0], [1.0, -1.0]])
    bu = np.array([0.25, 0.5, 1e30])
    bl = np.array([-0.25, -1e30, 0.2])
    sense = np.array([0, 8, 0], np.int32)
    x, lam = np.zeros(2), np.zeros(3)
    prob, sett, res = np.zeros(1, PROBLEM), np.zeros(1, SETTINGS), np.zeros(1, RESULT)
    sett[0] = defaults
    sett[0]["rho_soft"] = 1e-3
    p = prob[0]
    p["n"], p["m"], p["ms"] = 2, 3, 1
    p["H"], p["f"], p["A"] = H.ctypes.data, f.ctypes.data, A.ctypes.data
    p["bupper"], p["blower"], p["sense"] = bu.ctypes.data, bl.ctypes.data, sense.ctypes.data
    res[0]["x"], res[0]["lam"] = x.ctypes.data, lam.ctypes.data
    lib.daqp_quadprog(*(ctypes.c_void_p(a.ctypes.data) for a in (res, prob, sett)))
    x_ref, _, flag_ref, info = daqp.solve(H, f, A, bu, bl, sense, rho_soft=1e-3)
    r = res[0]
    if not (
        np.array_equal(x, x_ref) and r["exitflag"] == flag_ref and r["iter"] == info["iterations"]
    ):
        return "a test QP solved through the records differs from daqp.solve"
    for s in _SYMBOLS:  # only now that every check passed
        llvm.add_symbol(_PREFIX + s, ctypes.cast(getattr(lib, s), ctypes.c_void_p).value)
    return ""


UNAVAILABLE_REASON: str = _load()
"""Why the native solver is not available ("" when it is)."""
AVAILABLE: bool = UNAVAILABLE_REASON == ""
"""Whether DAQP's C functions can be called from compiled code here."""
_CACHE = AVAILABLE
# Kernels that call DAQP cache on disk only when it is available: a cached kernel loaded where
# the symbols are not registered would call a null address. Without the cache they compile
# afresh and the compile raises the error naming what is missing. (A kernel of another module
# that calls solve_qp must do the same: ``cache=daqp_native.AVAILABLE``.)


# ---------------------------------------------------------------- compiled calls


def _unavailable() -> RuntimeError:
    return RuntimeError(
        "DAQP's C solver cannot be called from compiled code: " + UNAVAILABLE_REASON
    )


def _data_pointer(context, builder, ty, value):
    """The address of array ``value`` (of numba type ``ty``)'s first element, as ``i8*``."""
    ary = context.make_array(ty)(context, builder, value=value)
    return builder.bitcast(ary.data, ir.IntType(8).as_pointer())


def _call_void(builder, name: str, ptrs: list) -> None:
    """Call the registered C function ``void name(void*, ...)`` with ``ptrs``."""
    i8p = ir.IntType(8).as_pointer()
    fnty = ir.FunctionType(ir.VoidType(), [i8p] * len(ptrs))
    fn = cgutils.get_or_insert_function(builder.module, fnty, _PREFIX + name)
    builder.call(fn, ptrs)


@intrinsic
def _daqp_default_settings(typingctx, settings):
    """``daqp_default_settings(&settings[0])`` on a :data:`SETTINGS` record array. The array is
    an argument of the call, so it lives until the call returns."""
    if not AVAILABLE:
        raise _unavailable()
    if not isinstance(settings, types.Array):
        return None

    def codegen(context, builder, signature, args):
        _call_void(
            builder, "daqp_default_settings", [_data_pointer(context, builder, settings, args[0])]
        )
        return context.get_dummy_value()

    return types.none(settings), codegen


@intrinsic
def _daqp_quadprog(typingctx, res, prob, settings):
    """``daqp_quadprog(&res[0], &prob[0], &settings[0])`` on :data:`RESULT`, :data:`PROBLEM`
    and :data:`SETTINGS` record arrays (arguments of the call, so alive until it returns)."""
    if not AVAILABLE:
        raise _unavailable()
    if not all(isinstance(t, types.Array) for t in (res, prob, settings)):
        return None

    def codegen(context, builder, signature, args):
        ptrs = [_data_pointer(context, builder, t, v) for t, v in zip(signature.args, args)]
        _call_void(builder, "daqp_quadprog", ptrs)
        return context.get_dummy_value()

    return types.none(res, prob, settings), codegen


def _c_float(a):
    """``a`` as a C-contiguous float64 array (itself when it is one)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _c_int32(a):
    """``a`` as a C-contiguous int32 array (itself when it is one)."""
    return np.ascontiguousarray(a, dtype=np.int32)


@overload(_c_float)
def _c_float_impl(a):
    if isinstance(a, types.Array) and a.dtype == types.float64:
        if a.layout == "C":
            return lambda a: a
        return lambda a: np.ascontiguousarray(a)
    return lambda a: np.ascontiguousarray(a).astype(np.float64)


@overload(_c_int32)
def _c_int32_impl(a):
    if isinstance(a, types.Array) and a.dtype == types.int32:
        if a.layout == "C":
            return lambda a: a
        return lambda a: np.ascontiguousarray(a)
    return lambda a: np.ascontiguousarray(a).astype(np.int32)


@njit(cache=_CACHE, nogil=True)
def _solve_into(H, f, A, bupper, blower, sense, rho_soft, iter_limit, x, lam):
    """``daqp_quadprog`` on C-contiguous ``H`` (n, n), ``f`` (n,), ``A`` (m - ms, n),
    ``bupper, blower`` (m,) and ``sense`` (m,) int32, with the settings at DAQP's defaults but
    ``rho_soft`` and ``iter_limit``; writes the solution to ``x`` (n,) and the multipliers to
    ``lam`` (m,); returns ``(exitflag, iterations)``. The data arrays are arguments, so the
    caller keeps them alive through the call; the records are this call's own."""
    n, m, mA = f.shape[0], bupper.shape[0], A.shape[0]
    prob = np.zeros(1, PROBLEM)
    settings = np.zeros(1, SETTINGS)
    res = np.zeros(1, RESULT)
    p = prob[0]
    p.n = n
    p.m = m
    p.ms = m - mA
    p.H = H.ctypes.data
    p.f = f.ctypes.data
    p.A = A.ctypes.data if mA > 0 else 0
    if m > 0:
        p.bupper = bupper.ctypes.data
        p.blower = blower.ctypes.data
        p.sense = sense.ctypes.data
    # break_points NULL, nh 0, problem_type 0 (a QP): the zeros already there
    _daqp_default_settings(settings)
    s = settings[0]
    s.rho_soft = rho_soft
    s.iter_limit = iter_limit
    r = res[0]
    r.x = x.ctypes.data
    r.lam = lam.ctypes.data if m > 0 else 0
    _daqp_quadprog(res, prob, settings)
    return np.int64(r.exitflag), np.int64(r.iter)


@njit(cache=_CACHE, nogil=True)
def _check_sizes(n, m, mA, H, blower, sense):
    """Raise ValueError unless the sizes make one QP (``n`` variables, ``m`` bounds, ``mA``
    rows of ``A``)."""
    if H.shape[0] != n or H.shape[1] != n:
        raise ValueError("H must be (n, n) for n = len(f)")
    if mA > m or m - mA > n:
        raise ValueError("need rows(A) <= len(bupper) <= rows(A) + n")
    if blower.shape[0] != m or sense.shape[0] != m:
        raise ValueError("blower and sense must have len(bupper) entries")


@njit(cache=_CACHE, nogil=True)
def solve_qp(H, f, A, bupper, blower, sense, rho_soft, iter_limit):
    """DAQP's solution of min ``0.5 x'Hx + f'x`` s.t. ``blower <= [x[:ms]; A x] <= bupper``,
    as ``daqp.solve(H, f, A, bupper, blower, sense, rho_soft=rho_soft, iter_limit=iter_limit)``
    gives it, bit for bit: ``(x, exitflag, iterations)``.

    ``H`` (n, n) and ``f`` (n,) the cost (units of the caller's cost over ``x``'s squared and
    plain units), ``A`` (m - ms, n) the general rows, ``bupper, blower`` (m,) the bounds (the
    first ``ms = m - rows(A)`` on ``x[:ms]``, then on the rows; +-1e30 as infinity), ``sense``
    (m,) DAQP's constraint types (0 inequality, 5 equality, 8 soft, ...), ``rho_soft`` DAQP's
    reciprocal quadratic weight of soft violations, ``iter_limit`` its iteration cap; all
    other settings at DAQP's defaults. ``x`` (n,) float64, ``exitflag`` DAQP's (1 optimal,
    2 soft-optimal, negative on failure: -1 infeasible, -4 iteration limit, ...),
    ``iterations`` its active-set iterations. Inputs are not written; non-contiguous ones are
    copied. Releases the GIL; one allocation of DAQP's workspace per call (module docstring).
    """
    f = _c_float(f)
    n, m = f.shape[0], bupper.shape[0]
    A2 = _c_float(A)
    if A2.shape[0] > 0 and A2.shape[1] != n:
        raise ValueError("A must have len(f) columns")
    _check_sizes(n, m, A2.shape[0], H, blower, sense)
    x = np.zeros(n)
    lam = np.zeros(m)
    flag, it = _solve_into(
        _c_float(H),
        f,
        A2,
        _c_float(bupper),
        _c_float(blower),
        _c_int32(sense),
        float(rho_soft),
        np.int32(iter_limit),
        x,
        lam,
    )
    return x, flag, it


@njit(cache=_CACHE, nogil=True, parallel=True)
def solve_qps(H, f, A, bupper, blower, sense, n, m, ms, rho_soft, iter_limit):
    """A batch of B independent QPs of :func:`solve_qp`'s form, in padded arrays, solved in
    parallel (``numba.prange`` over the problems, each on its own records and copies): for
    every problem ``b`` exactly what ``solve_qp`` gives for it alone, bit for bit, whatever
    the batch and the thread count. ``(x, exitflag, iterations)``: ``x`` (B, N) float64 (zero
    past ``n[b]``), ``exitflag`` and ``iterations`` (B,) int64.

    Layout: problem ``b`` is ``H[b, :n[b], :n[b]]``, ``f[b, :n[b]]``,
    ``A[b, :m[b] - ms[b], :n[b]]``, ``bupper[b, :m[b]]``, ``blower[b, :m[b]]``,
    ``sense[b, :m[b]]`` (``ms[b]`` simple bounds first, as in :func:`solve_qp`),
    ``rho_soft[b]`` and ``iter_limit[b]``. Shapes: ``H`` (B, N, N), ``f`` (B, N), ``A``
    (B, R, N), ``bupper, blower, sense`` (B, M) with N >= max n, R >= max(m - ms),
    M >= max m; ``n, m, ms, iter_limit`` (B,) integers, ``rho_soft`` (B,) float. Entries
    past a problem's sizes are not read. A problem whose block is not contiguous in the
    padded arrays (``n[b] < N`` for ``H`` and ``A``) is copied out first; DAQP allocates its
    workspace per problem (module docstring).
    """
    B = H.shape[0]
    N = H.shape[1]
    x = np.zeros((B, N))
    flags = np.zeros(B, np.int64)
    iters = np.zeros(B, np.int64)
    for b in range(B):
        if n[b] > N or m[b] > bupper.shape[1] or m[b] - ms[b] > A.shape[1] or ms[b] < 0:
            raise ValueError("a problem's sizes exceed the padded arrays")
        if ms[b] > n[b] or ms[b] > m[b]:
            raise ValueError("need ms <= n and ms <= m for every problem")
    for b in prange(B):
        nb, mb, mA = n[b], m[b], m[b] - ms[b]
        xb = np.zeros(nb)
        lam = np.zeros(mb)
        flag, it = _solve_into(
            np.ascontiguousarray(H[b, :nb, :nb]),
            np.ascontiguousarray(f[b, :nb]),
            np.ascontiguousarray(A[b, :mA, :nb]),
            np.ascontiguousarray(bupper[b, :mb]),
            np.ascontiguousarray(blower[b, :mb]),
            np.ascontiguousarray(sense[b, :mb]).astype(np.int32),
            float(rho_soft[b]),
            np.int32(iter_limit[b]),
            xb,
            lam,
        )
        x[b, :nb] = xb
        flags[b] = flag
        iters[b] = it
    return x, flags, iters
