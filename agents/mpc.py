"""The paper's MPC (equation 2) as a real-time iteration (RTI) SQP.

At every call: simulate the horizon with the shifted previous inputs (single shooting,
``K`` stages of ``substeps`` RK4 steps of the *same* model code as the simulator, evaluated
symbolically by CasADi and compiled to C), take the stage sensitivities ``A_k, B_k``, condense
them into ``d(s, n)^k / d u``, and solve one dense QP in the input corrections (2K
variables) with DAQP:

    min  q sum_{k=1..K} ||(s^k, n^k) - (s_ref^k, n_ref^k)||^2
         + sum_{k=1..K-1} ||u^k - u^{k-1}||^2                      (R = I)
    s.t. d_min <= d^k <= d_max, |delta^k| <= delta_max             (k = 0..K-1)
         |delta^k - delta^{k-1}| <= delta_rate_max dt               (k = 0..K-1, delta^{-1} applied)
         -w_right + margin <= n^k <= w_left - margin                (k = 1..K, soft)
         separation from the cars just ahead / behind               (k = 1..K, soft)

The tracking sum runs over the predicted states 1..K: the first state after the current one
through the last (the authors' code compared the current state with the first reference
point and never penalised the last). The paper lists the lateral *and* the longitudinal
separation as constraints; both at once would forbid ever being beside or behind another car,
so per stage and opponent we impose the one that the nominal prediction satisfies with the
larger margin, on the side where it is (the usual convexification of "not overlapping").
Opponents move at constant progress rate and lateral position (paper). Soft constraints
use DAQP's soft rows, a *quadratic* penalty: a violation ``v`` of a soft row costs
``v^2 / (2 rho)`` (in the units of the cost above), so the QP is always feasible. The weight
grows with the tracking gain above ``soft_q_ref`` (``rho = soft_rho * min(1, soft_q_ref / q)``,
:meth:`MPCConfig.soft_rho_at`): with a fixed rho a tight tracker (q = 500) traded 10 cm off
the track for 30 cm of tracking error and left the track on 22% of a 64-theta solo sweep of
``default``; scaled, the trade stays the one of q = 20 at every q.

Each QP step is checked on the nonlinear model (a merit test): the rollout of the new inputs
must lower the cost (tracking, input rates and the same quadratic penalty of the soft rows,
:func:`plan_cost`) below the current plan's, trying the full step and then shorter ones
(``step_sizes``, down to 1/8); a step that lowers nothing is rejected and the current plan
kept. An accepted step is linearised again, so the SQP iterates until a QP step promises
(:func:`predicted_decrease`) less than ``merit_rtol`` (0.1%) of the cost, no step length
lowers it, or ``sqp_iterations`` (12) QPs are spent; at the limit one linearisation of the car
over 1.5 s is poor, and a single QP step left plans up to 360x IPOPT's optimum of the same
problem. The first solve after a reset, and any solve whose shifted plan leaves the track or
whose car is nearly stopped, also rolls out the raceline follower's law and starts from
whichever plan costs less (a *restart*, counted in ``stats``). A failed QP or a non-finite
prediction falls back to the shifted previous plan with the throttle lifted (counted in
``stats``).

The curvature is a parameter of the compiled prediction, looked up at the stage progress of
a guess (the previous plan). Every plan is therefore rolled out again with the curvature
along its own progress (``curvature_passes``), and a trial step with the curvature along its
own linearised progress: scored along another plan's progress, a step that changes the speed
is judged on the wrong corner, and the merit test rejected the steps that would have fixed
the plan. Together these bring the RTI's plans within 5% of IPOPT's optimum in about 90% of
the states of a race at the limit (24-36% before; ``benchmarks/mpc_speed.py``).

The prediction model uses a larger low-speed slip regularisation (``v_low``, default 0.5 m/s)
than the simulator so that the RK4 sub-steps of a 0.1 s stage stay stable at a standing
start; above about 2 m/s the two models agree to a few percent. The QP's matrices are built
in one compiled pass (:func:`linearised_qp`); DAQP's iterations are capped (``qp_iter_limit``),
since a rare cycling QP otherwise spends 10k iterations before giving up. The rest of an SQP
iteration (the trial steps' rollouts and merit checks, the new linearisation) is one numba
call that calls the compiled predictions itself (:func:`sqp_step`); with an
interpreted prediction the same step runs in Python. Both do the same arithmetic, so the
plans are the same bit for bit. With the fused helpers (:func:`trial_step`,
:func:`score_rollout`, :func:`linearised_qp`) a race of MPC cars takes about 20% less time
than with the separate numpy and ctypes calls before them; the kernel's own share is about
6% (``benchmarks/sqp_step.py``: 0.90 against 0.96 ms per decision on the collection's races).
"""
from __future__ import annotations

import hashlib
from collections import deque
import os
import shlex
import shutil
import subprocess
import tempfile
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from racing_env.controllers import follower_action
from racing_env.simulator import _lookup, _n_substeps, integrate_car
from racing_env.track import Track
from racing_env.vehicle import P_VLOW, VehicleParams

@dataclass(frozen=True)
class MPCConfig:
    """MPC settings. Lengths in m, times in s."""

    horizon: int = 15             # K
    dt: float = 0.1
    substeps: int = 3             # RK4 steps per stage
    v_low: float = 0.5            # slip regularisation of the prediction model at rest [m/s]
    v_blend: float = 1.0          # ... fading to the simulator's v_low above this speed [m/s]
    track_margin: float = 0.03    # keep the car centre this far inside the edges
    sep_s: float = 0.15           # longitudinal separation p_x^min
    sep_n: float = 0.08           # lateral separation p_y^min
    sep_window: float = 2.0       # only opponents within this progress distance constrain
    soft_rho: float = 1e-4        # DAQP rho_soft at q <= soft_q_ref: a soft violation v costs
                                  # v^2 / (2 rho), rho = soft_rho_at(q)
    soft_q_ref: float = 20.0      # above this tracking weight rho shrinks like 1 / q
    sqp_iterations: int = 12      # most SQP iterations (QPs) per solve: the SQP stops earlier
                                  # when a QP step predicts a relative decrease of the cost
                                  # below merit_rtol, or when no step length lowers it
    merit_rtol: float = 1e-3      # predicted relative cost decrease worth a merit check
    step_sizes: tuple = (1.0, 0.5, 0.25, 0.125)  # merit-checked step lengths of each QP step
    curvature_passes: int = 1     # re-rollouts of a plan with the curvature along its own
                                  # progress (0: along the previous plan's progress only)
    restart_offtrack: float = 0.06  # warm start from a follower rollout when the shifted plan
                                    # leaves the track by more than this [m]
    qp_iter_limit: int = 300        # DAQP active-set iterations; a QP that needs more (rare
                                    # cycling) falls back instead of spinning for 10 ms

    def __post_init__(self):
        if not (isinstance(self.horizon, int) and 2 <= self.horizon <= 100):
            raise ValueError(f"MPC horizon must be an integer in 2..100, got {self.horizon!r}")
        if not (isinstance(self.substeps, int) and 1 <= self.substeps <= 10):
            raise ValueError(f"MPC substeps must be an integer in 1..10, got {self.substeps!r}")
        for name in ("dt", "v_low", "v_blend", "sep_s", "sep_n", "sep_window", "soft_rho",
                     "soft_q_ref"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"MPCConfig.{name} must be positive, got {v!r}")
        if not (isinstance(self.qp_iter_limit, int) and self.qp_iter_limit >= 1):
            raise ValueError(f"MPCConfig.qp_iter_limit must be a positive integer, got "
                             f"{self.qp_iter_limit!r}")
        if self.track_margin < 0 or self.sqp_iterations < 1:
            raise ValueError(f"MPCConfig needs track_margin >= 0 and sqp_iterations >= 1, got "
                             f"{self.track_margin}, {self.sqp_iterations}")
        if not (isinstance(self.curvature_passes, int) and 0 <= self.curvature_passes <= 5):
            raise ValueError(f"MPCConfig.curvature_passes must be an integer in 0..5, got "
                             f"{self.curvature_passes!r}")
        if not (np.isfinite(self.merit_rtol) and self.merit_rtol >= 0):
            raise ValueError(f"MPCConfig.merit_rtol must be >= 0, got {self.merit_rtol!r}")
        steps = tuple(self.step_sizes)
        if not steps or any(not (0 < a <= 1) for a in steps):
            raise ValueError(f"MPCConfig.step_sizes must be step lengths in (0, 1], got "
                             f"{self.step_sizes!r}")

    def soft_rho_at(self, q: float) -> float:
        """DAQP's ``rho_soft`` for tracking weight ``q``: ``soft_rho * min(1, soft_q_ref / q)``,
        so the soft rows (track edges, separations) keep their weight relative to tracking."""
        return self.soft_rho * min(1.0, self.soft_q_ref / float(q))


# ---------------------------------------------------------------------------- the prediction
def _cache_root() -> Path:
    """Folder of the compiled predictions: ``mpc/`` of the alpha-racer cache folder."""
    from racing_env.cache import cache_dir
    return cache_dir("mpc")


def prediction_v_low(vx, v_low_sim: float, cfg: MPCConfig, exp=np.exp):
    """Slip regularisation [m/s] of the prediction model at speed ``vx`` [m/s]:
    ``v_low_sim + (cfg.v_low - v_low_sim) exp(-(vx / cfg.v_blend)^2)``. Near rest the larger
    ``cfg.v_low`` keeps the RK4 sub-steps stable; at racing speed (within 1e-3 above
    ``2.7 v_blend``) it is the simulator's own, so the prediction holds the tyre forces the car
    really has (a constant 0.5 m/s cost 4% of lateral force at 2.5 m/s)."""
    return v_low_sim + (cfg.v_low - v_low_sim) * exp(-(vx / cfg.v_blend) ** 2)


def stage_function(vehicle: VehicleParams, cfg: MPCConfig, jacobians: bool = True):
    """CasADi ``stage(x[6], u[2], kap[substeps]) -> (x_next, vec(dx_next/dx), vec(dx_next/du))``:
    one 0.1 s stage of ``substeps`` RK4 steps of the simulator's model (``frenet_ode``) with
    the prediction's ``v_low``; ``u`` are the env's normalised inputs. Without ``jacobians``
    it returns ``x_next`` only."""
    import casadi as ca
    from racing_env.vehicle import frenet_ode_casadi

    ode = frenet_ode_casadi()
    p = [float(v) for v in vehicle.pack()]
    x = ca.SX.sym("x", 6)
    u = ca.SX.sym("u", 2)
    kap = ca.SX.sym("kap", cfg.substeps)
    # decision variables are the env's normalised inputs in [-1, 1]^2 (so R = I weighs a full
    # throttle swing like a full steering swing); map them to physical (d, delta) here
    d_phys = 0.5 * (vehicle.d_max + vehicle.d_min) + 0.5 * (vehicle.d_max - vehicle.d_min) * u[0]
    delta_phys = vehicle.delta_max * u[1]

    def f(xx, kk):
        pp = list(p)
        pp[P_VLOW] = prediction_v_low(xx[3], vehicle.v_low, cfg, ca.exp)
        return ca.vertcat(*ode(xx[1], xx[2], xx[3], xx[4], xx[5], d_phys, delta_phys, kk, pp))

    h = cfg.dt / cfg.substeps
    xn = x
    for j in range(cfg.substeps):
        k1 = f(xn, kap[j])
        k2 = f(xn + h / 2 * k1, kap[j])
        k3 = f(xn + h / 2 * k2, kap[j])
        k4 = f(xn + h * k3, kap[j])
        xn = xn + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    if not jacobians:
        return ca.Function("stage_x", [x, u, kap], [xn])
    return ca.Function("stage", [x, u, kap],
                       [xn, ca.densify(ca.vec(ca.jacobian(xn, x))),
                        ca.densify(ca.vec(ca.jacobian(xn, u)))])


def _trajectory_function(vehicle: VehicleParams, cfg: MPCConfig, jacobians: bool = True):
    """The horizon ``(x0[6], U[2xK], KAP[substeps x K]) -> (X[6xK], A[36xK], B[12xK])`` (numpy
    arrays): the stage function folded K times (mapaccum), compiled to C and cached on disk
    (``mpc/`` of the cache folder, see :mod:`racing_env.cache`). Without ``jacobians``:
    ``(X,)`` only, a rollout several times cheaper.

    The compiler is ``$CC`` if set (a command, e.g. ``"ccache gcc"``), else ``gcc`` or ``cc``.
    When there is none, or it fails (its error message is shown), or the library does not load,
    the prediction runs interpreted by CasADi with a warning: same results, slower."""
    import casadi as ca

    stage = stage_function(vehicle, cfg, jacobians)
    name = "mpc_traj" if jacobians else "mpc_roll"
    traj = stage.mapaccum(name, cfg.horizon)
    gen = ca.CodeGenerator(f"{name}.c", {"with_header": False})
    gen.add(traj)
    code = gen.dump()
    flags = ["-O3", "-fPIC", "-shared"]
    key = hashlib.sha1((code + " ".join(flags)).encode()).hexdigest()[:16]
    lib = _cache_root() / f"{name}_{key}.so"
    interpreted = "the MPC runs its prediction interpreted by CasADi (same results, slower)"
    if not lib.exists():
        cc = _c_compiler()
        if cc is None:
            cc_env = os.environ.get("CC", "").strip()
            why = f"CC={cc_env!r} is not a program on the PATH" if cc_env else "set CC or install gcc"
            warnings.warn(f"no C compiler found ({why}): {interpreted}", RuntimeWarning, stacklevel=2)
            return _InterpretedTrajectory(traj)
        with tempfile.TemporaryDirectory(dir=lib.parent) as tmp:
            src = Path(tmp) / f"{name}.c"
            src.write_text(code)
            out = Path(tmp) / lib.name
            cmd = [*cc, *flags, str(src), "-o", str(out)]
            try:
                subprocess.run(cmd, check=True, capture_output=True, text=True)
            except subprocess.CalledProcessError as exc:
                output = (exc.stderr or exc.stdout or "").strip()[-2000:]
                failure = f"exited with status {exc.returncode}:\n{output}"
            except OSError as exc:          # not executable, not a program, ...
                failure = f"could not run: {exc}"
            else:
                failure = None
            if failure is not None:
                warnings.warn(f"compiling the MPC prediction failed: {shlex.join(cmd)} {failure}\n"
                              f"{interpreted}", RuntimeWarning, stacklevel=2)
                return _InterpretedTrajectory(traj)
            os.replace(out, lib)            # atomic: a killed compile leaves no broken library
    try:
        return _CompiledTrajectory(lib, cfg.horizon, cfg.substeps, name)
    except (OSError, AttributeError) as exc:  # not a loadable library, or not ours
        warnings.warn(f"cannot load the compiled MPC prediction {str(lib)!r} ({exc}): {interpreted}",
                      RuntimeWarning, stacklevel=2)
        return _InterpretedTrajectory(traj)


def _c_compiler() -> list[str] | None:
    """The C compiler command: ``$CC`` split like a shell would (None if its program is not
    found), else ``gcc`` or ``cc`` on the PATH, else None."""
    env = os.environ.get("CC", "").strip()
    if env:
        cmd = shlex.split(env)
        exe = shutil.which(cmd[0])
        return [exe, *cmd[1:]] if exe else None
    cc = shutil.which("gcc") or shutil.which("cc")
    return [cc] if cc else None


class _InterpretedTrajectory:
    """The CasADi Function with numpy arrays out, like :class:`_CompiledTrajectory`."""

    def __init__(self, fn):
        self._fn = fn

    def __call__(self, x0, U, kap):
        out = self._fn(x0, U, kap)
        out = out if isinstance(out, (tuple, list)) else (out,)   # one output comes bare
        return tuple(np.asarray(o, dtype=float) for o in out)

    def states(self, x0, u_vec, kap_flat, K: int):
        """Predicted states (6, K) of flat inputs: ``u_vec`` (2K,) ``[d0, delta0, d1, ...]``,
        ``kap_flat`` (substeps K,) stage after stage (the layouts of the compiled buffers)."""
        return np.ascontiguousarray(self.full(x0, u_vec, kap_flat, K)[0])

    def full(self, x0, u_vec, kap_flat, K: int):
        """``(X, A, B)`` (or ``(X,)``) of flat inputs, like :meth:`states`."""
        U = np.asarray(u_vec).reshape(K, 2).T
        kap = np.asarray(kap_flat).reshape(K, -1).T
        return tuple(np.ascontiguousarray(o) for o in self(x0, U, kap))


class _CompiledTrajectory:
    """Calls the generated C function through ctypes on preallocated numpy buffers (the
    CasADi Python call with DM conversions costs more than the maths itself here).

    The buffers are views of one workspace array ``ws``: ``x0`` (6), ``U`` (2K), ``kap``
    (substeps K), ``X`` (6K), ``A`` (36K), ``B`` (12K), then CasADi's work vector; ``ptrs``
    holds the argument pointers (``n_arg`` of them) and then the result pointers. The
    kernel :func:`sqp_step` calls the function from numba on the same buffers."""

    def __init__(self, lib: Path, horizon: int, substeps: int, name: str = "mpc_traj"):
        import ctypes
        self._lib = ctypes.CDLL(str(lib))
        fn = getattr(self._lib, name)
        i64 = ctypes.c_longlong
        sizes = [i64() for _ in range(4)]
        getattr(self._lib, f"{name}_work")(*[ctypes.byref(v) for v in sizes])
        n_arg, n_res, n_iw, n_w = (v.value for v in sizes)
        self.n_arg, n_res_slots = max(n_arg, 3), max(n_res, 3)
        K = horizon
        self.states_only = n_res == 1
        offsets = workspace_offsets(K, substeps)
        self.ws = np.zeros(offsets[-1] + max(n_w, 1))
        self.x0, self.U, self.kap, self.X, self.A, self.B = (
            self.ws[a:b] for a, b in zip(offsets[:-1], offsets[1:]))
        self._w = self.ws[offsets[-1]:]
        self.iw = np.zeros(max(n_iw, 1), dtype=np.int64)
        self.ptrs = np.zeros(self.n_arg + n_res_slots, dtype=np.uint64)
        self.ptrs[:3] = [a.ctypes.data for a in (self.x0, self.U, self.kap)]
        self.ptrs[self.n_arg:self.n_arg + 3] = [a.ctypes.data for a in (self.X, self.A, self.B)]
        vp = ctypes.c_void_p
        self._args = (vp(self.ptrs.ctypes.data), vp(self.ptrs.ctypes.data + 8 * self.n_arg),
                      vp(self.iw.ctypes.data), vp(self._w.ctypes.data), 0)
        fn.restype = ctypes.c_int
        fn.argtypes = [vp, vp, vp, vp, ctypes.c_int]
        self._fn = fn
        self.K = K

    def kernel_args(self) -> tuple:
        """``(ws, ptrs, iw, address of the C function, byte offset of the result pointers in
        ptrs)``: what :func:`sqp_step` needs to call this prediction."""
        import ctypes
        return (self.ws, self.ptrs, self.iw, ctypes.cast(self._fn, ctypes.c_void_p).value,
                8 * self.n_arg)

    def _run(self, x0, u_vec, kap_flat) -> None:
        """Write the inputs into the buffers and run the C function on them."""
        self.x0[:] = x0
        self.U[:] = u_vec
        self.kap[:] = kap_flat
        if self._fn(*self._args):
            raise RuntimeError("compiled MPC prediction failed")

    def __call__(self, x0, U, kap):
        """Same inputs and outputs as the CasADi Function (U (2, K), kap (m, K) arrays)."""
        return self.full(x0, np.asarray(U).T.ravel(), np.asarray(kap).T.ravel(), self.K)

    def states(self, x0, u_vec, kap_flat, K: int):
        """Predicted states (6, K) of flat inputs: ``u_vec`` (2K,) ``[d0, delta0, d1, ...]``,
        ``kap_flat`` (substeps K,) stage after stage: the buffers' own layouts, so the inputs
        are copied once and not transposed."""
        self._run(x0, u_vec, kap_flat)
        return self.X.reshape(K, 6).T.copy()

    def full(self, x0, u_vec, kap_flat, K: int):
        """``(X (6, K), A (36, K), B (12, K))`` (``(X,)`` for a states-only prediction) of
        flat inputs, like :meth:`states`."""
        self._run(x0, u_vec, kap_flat)
        X = self.X.reshape(K, 6).T.copy()
        if self.states_only:
            return (X,)
        return X, self.A.reshape(K, 36).T.copy(), self.B.reshape(K, 12).T.copy()


@njit(cache=True)
def workspace_offsets(K, m):
    """Where ``x0, U, kap, X, A, B`` start in a compiled prediction's workspace (K stages of
    m sub-steps), and where CasADi's work vector starts (the last of the 7 offsets)."""
    o_u, o_kap = 6, 6 + 2 * K
    o_x = o_kap + m * K
    return 0, o_u, o_kap, o_x, o_x + 6 * K, o_x + 42 * K, o_x + 54 * K


@njit(cache=True)
def condense_states(A, B, K):
    """Sensitivities (K, 6, 2K) of every predicted state to the inputs:
    ``G[k, r, 2j + c] = d x_r^{k+1} / d u_c^j`` (zero for j > k), from the column-major stage
    Jacobians ``A`` (36, K), ``B`` (12, K) of the CasADi function."""
    G = np.zeros((K, 6, 2 * K))
    M = np.empty((6, 2))
    T = np.empty((6, 2))
    for j in range(K):
        for r in range(6):
            for c in range(2):
                M[r, c] = B[r + 6 * c, j]
        for k in range(j, K):
            for r in range(6):
                for c in range(2):
                    G[k, r, 2 * j + c] = M[r, c]
            if k + 1 < K:
                for r in range(6):
                    for c in range(2):
                        acc = 0.0
                        for q in range(6):
                            acc += A[r + 6 * q, k + 1] * M[q, c]
                        T[r, c] = acc
                M[:, :] = T
    return G


@njit(cache=True)
def condense(A, B, n_steps):
    """Sensitivities of (s, n) at stages 1..K to the inputs: (2K, 2K) rows [s^1, n^1, ...],
    ``G[2k + r, 2j + c] = d x_r^{k+1} / d u_c^j`` (rows r = 0, 1 of :func:`condense_states`)."""
    return np.ascontiguousarray(condense_states(A, B, n_steps)[:, :2, :]).reshape(2 * n_steps,
                                                                                  2 * n_steps)


@njit(cache=True)
def _grid_interp(table, s, ds, length):
    """The simulator's periodic grid interpolation (``_lookup``) at every element of ``s``."""
    out = np.empty_like(s)
    flat_s, flat_o = s.ravel(), out.ravel()
    for i in range(flat_s.size):
        flat_o[i] = _lookup(table, flat_s[i], ds, length)
    return out


def stage_nodes(s_nominal, x0, K: int, dt: float) -> np.ndarray:
    """Progress (K + 1,) at the stage boundaries to look curvature up at: the previous nominal
    (K + 1,) shifted by one stage and re-anchored at ``x0``, or, without one, constant speed."""
    if s_nominal is None:
        return x0[0] + max(float(x0[3]), 0.5) * dt * np.arange(K + 1)
    nodes = np.concatenate([s_nominal[1:], [2 * s_nominal[-1] - s_nominal[-2]]])
    return nodes - nodes[0] + x0[0]


def kappa_at_substeps(track: Track, s_nodes, substeps: int) -> np.ndarray:
    """Track curvature (substeps, K) at the start of every RK4 sub-step between the stage
    boundaries ``s_nodes`` (K + 1,) (progress interpolated linearly within a stage)."""
    s_nodes = np.asarray(s_nodes, dtype=float)
    flat = kappa_flat(track.kappa, s_nodes, substeps, track.ds, track.length)
    return np.ascontiguousarray(flat.reshape(s_nodes.shape[0] - 1, substeps).T)


@njit(cache=True)
def kappa_flat(table, s_nodes, m, ds, length):
    """:func:`kappa_at_substeps` laid out stage after stage (substeps K,), the layout of the
    compiled prediction's buffer."""
    K = s_nodes.shape[0] - 1
    out = np.empty(m * K)
    for k in range(K):
        step = s_nodes[k + 1] - s_nodes[k]
        for i in range(m):
            out[k * m + i] = _lookup(table, s_nodes[k] + step * i / m, ds, length)
    return out


class EdgeBounds:
    """Bounds on the car centre's lateral offset: the track edges minus half the car width and
    the MPC's ``track_margin``; ``(lo, hi) = bounds(s)`` for any array of (unwrapped) s."""

    def __init__(self, track: Track, vehicle: VehicleParams, cfg: MPCConfig):
        half = 0.5 * vehicle.width + cfg.track_margin
        self.track = track
        self.lo_table = np.ascontiguousarray(-track.w_right + half)    # per track station
        self.hi_table = np.ascontiguousarray(track.w_left - half)

    def __call__(self, s):
        t = self.track
        s = np.ascontiguousarray(s, dtype=float)
        return (_grid_interp(self.lo_table, s, t.ds, t.length),
                _grid_interp(self.hi_table, s, t.ds, t.length))


@njit(cache=True)
def _rollout(x, n_ref, mu_ref, kappa_ref, v_ref, kappa_tab, ds, length, gains, p, act_map, dt, U):
    """Roll the follower law forward from state ``x`` in the simulator's model; inputs into U."""
    for k in range(U.shape[1]):
        a0, a1 = follower_action(x, n_ref, mu_ref, kappa_ref, v_ref, ds, length, gains)
        U[0, k] = a0
        U[1, k] = a1
        integrate_car(x, act_map[0] + act_map[1] * a0, act_map[2] * a1, kappa_tab, ds, length,
                      p, dt, _n_substeps(x[3], p, dt, 1.0, 100))


def separation_choice(s_pred, n_pred, opponent, cfg: MPCConfig):
    """Which separation to impose against one opponent at each predicted stage k = 1..K.

    ``opponent = (s_j, n_j, s_dot_j)`` moves at constant progress rate and lateral position.
    Returns ``(near, lateral, sign, s_jk)`` (K,) each: constrain only ``near`` stages
    (``|s - s_j^k| < sep_window``); there impose ``sign * (n - n_j) >= sep_n`` where
    ``lateral`` else ``sign * (s - s_j^k) >= sep_s``: the separation the nominal prediction
    satisfies with the larger margin, on the side where the nominal is.
    """
    s_j, n_j, v_j = opponent
    s_jk = s_j + v_j * cfg.dt * np.arange(1, len(s_pred) + 1)
    ds, dn = s_pred - s_jk, n_pred - n_j
    near = np.abs(ds) < cfg.sep_window
    lateral = np.abs(dn) / cfg.sep_n >= np.abs(ds) / cfg.sep_s
    sign = np.where(np.where(lateral, dn, ds) >= 0.0, 1.0, -1.0)
    return near, lateral, sign, s_jk


def input_rate_matrix(K: int) -> np.ndarray:
    """``DtD`` (2K, 2K) on the stacked inputs ``[d0, delta0, d1, ...]``:
    ``u^T DtD u = sum_{k=1..K-1} ||u^k - u^{k-1}||^2``."""
    D = np.zeros((2 * (K - 1), 2 * K))
    for k in range(1, K):
        D[2 * (k - 1):2 * k, 2 * k:2 * k + 2] = np.eye(2)
        D[2 * (k - 1):2 * k, 2 * (k - 1):2 * k] = -np.eye(2)
    return D.T @ D


def follower_rollout(track: Track, vehicle: VehicleParams, follower, x0, K: int, dt: float):
    """Normalised inputs (2, K) from rolling the raceline follower's law forward from ``x0``
    (6,) in the simulator's model for ``K`` stages of ``dt`` s: an on-track initial guess.
    ``follower`` is a :class:`racing_env.controllers.RacelineFollower` reset on ``track``."""
    U = np.empty((2, K))
    v = vehicle
    _rollout(np.array(x0, dtype=float), *follower.tables(), track.kappa, track.ds, track.length,
             follower.gains(), v.pack(),
             np.array([0.5 * (v.d_max + v.d_min), 0.5 * (v.d_max - v.d_min), v.delta_max]),
             dt, U)
    return U


def make_follower(track: Track, vehicle: VehicleParams, line: str = "curvature"):
    """A raceline follower of racing line ``line`` reset on ``track`` (for
    :func:`follower_rollout`)."""
    from racing_env.controllers import RacelineFollower
    follower = RacelineFollower(vehicle, line=line)
    follower.reset(track)
    return follower


@njit(cache=True)
def qp_arrays(G, s_pred, n_pred, s_ref, n_ref, q, DtD, u_vec, delta_applied, rate, nlo, nhi,
              opponents, dt, sep_s, sep_n, sep_window):
    """The condensed QP in the input corrections ``du`` (2K,) for DAQP, built in one pass.

    Cost ``0.5 du' H du + f' du`` of ``q ||(s, n) - ref||^2 + ||D u||^2``; constraint rows
    ``blo <= Acon du <= bhi`` after the 2K simple input bounds (which lead ``blo``/``bhi``):
    K steering-rate rows (hard), K track-edge rows on n (soft), and one separation row per
    opponent and nearby stage (soft), chosen exactly as :func:`separation_choice` does.
    ``opponents`` (M, 3) rows ``(s, n, s_dot)``; ``sense`` is DAQP's (0 hard, 8 soft).
    """
    K = s_pred.shape[0]
    nv = 2 * K
    sn_err = np.empty(nv)
    for k in range(K):
        sn_err[2 * k] = s_pred[k] - s_ref[k]
        sn_err[2 * k + 1] = n_pred[k] - n_ref[k]
    H = 2.0 * (q * (G.T @ G) + DtD)
    for i in range(nv):
        H[i, i] += 1e-8
    f = 2.0 * (q * (G.T @ sn_err) + DtD @ u_vec)
    M = opponents.shape[0]
    rows = np.zeros((2 * K + M * K, nv))
    lo = np.empty(2 * K + M * K)
    hi = np.empty(2 * K + M * K)
    soft = np.zeros(2 * K + M * K, dtype=np.int32)
    # steering rate: delta^k - delta^{k-1} within +-rate (normalised), delta^{-1} applied
    for k in range(K):
        rows[k, 2 * k + 1] = 1.0
        d_now = u_vec[2 * k + 1] - (u_vec[2 * k - 1] if k else delta_applied)
        if k:
            rows[k, 2 * k - 1] = -1.0
        lo[k] = -rate - d_now
        hi[k] = rate - d_now
    # track edges on n (soft)
    for k in range(K):
        rows[K + k, :] = G[2 * k + 1, :]
        lo[K + k] = nlo[k] - n_pred[k]
        hi[K + k] = nhi[k] - n_pred[k]
        soft[K + k] = 8
    r = 2 * K
    for m in range(M):
        s_j, n_j, v_j = opponents[m, 0], opponents[m, 1], opponents[m, 2]
        for k in range(K):
            s_jk = s_j + v_j * dt * (k + 1)
            ds = s_pred[k] - s_jk
            dn = n_pred[k] - n_j
            if not abs(ds) < sep_window:
                continue
            lateral = abs(dn) / sep_n >= abs(ds) / sep_s
            gap = dn if lateral else ds
            sign = 1.0 if gap >= 0.0 else -1.0
            row = 2 * k + 1 if lateral else 2 * k
            for c in range(nv):
                rows[r, c] = sign * G[row, c]
            lo[r] = (sep_n if lateral else sep_s) - sign * gap
            hi[r] = 1e30
            soft[r] = 8
            r += 1
    blo = np.empty(nv + r)
    bhi = np.empty(nv + r)
    sense = np.zeros(nv + r, dtype=np.int32)
    for i in range(nv):
        blo[i] = -1.0 - u_vec[i]
        bhi[i] = 1.0 - u_vec[i]
    blo[nv:] = lo[:r]
    bhi[nv:] = hi[:r]
    sense[nv:] = soft[:r]
    return H, f, rows[:r].copy(), blo, bhi, sense


@njit(cache=True)
def plan_cost(s_pred, n_pred, s_ref, n_ref, q, u_vec, nlo, nhi, opponents, dt, sep_s, sep_n,
              sep_window, w_soft):
    """The MPC's objective at a plan's rollout (:func:`qp_arrays`' cost before linearisation):
    ``q ||(s, n) - ref||^2 + ||D u||^2 + w_soft * (sum of squared violations of the track
    edges and of the separations, chosen per stage as in qp_arrays)``."""
    K = s_pred.shape[0]
    J = 0.0
    for k in range(K):
        J += q * ((s_pred[k] - s_ref[k]) ** 2 + (n_pred[k] - n_ref[k]) ** 2)
        v = max(n_pred[k] - nhi[k], nlo[k] - n_pred[k], 0.0)
        J += w_soft * v * v
    for k in range(1, K):
        J += (u_vec[2 * k] - u_vec[2 * k - 2]) ** 2 + (u_vec[2 * k + 1] - u_vec[2 * k - 1]) ** 2
    for m in range(opponents.shape[0]):
        s_j, n_j, v_j = opponents[m, 0], opponents[m, 1], opponents[m, 2]
        for k in range(K):
            ds = s_pred[k] - (s_j + v_j * dt * (k + 1))
            dn = n_pred[k] - n_j
            if not abs(ds) < sep_window:
                continue
            if abs(dn) / sep_n >= abs(ds) / sep_s:
                v = max(sep_n - abs(dn), 0.0)
            else:
                v = max(sep_s - abs(ds), 0.0)
            J += w_soft * v * v
    return J


@njit(cache=True)
def predicted_decrease(H, f, Acon, blo, bhi, sense, du, w_soft):
    """Decrease of the QP's model of the cost (:func:`qp_arrays`' quadratic plus the soft rows'
    penalty ``w_soft v^2``) from ``du = 0`` to the step ``du``: what the linearisation
    promises, in the units of :func:`plan_cost`."""
    nv = du.shape[0]
    gain = -(0.5 * du @ (H @ du) + f @ du)
    a = Acon @ du
    for r in range(a.shape[0]):
        if sense[nv + r] == 8:
            lo, hi = blo[nv + r], bhi[nv + r]
            v_old = max(lo, -hi, 0.0)
            v_new = max(lo - a[r], a[r] - hi, 0.0)
            gain += w_soft * (v_old * v_old - v_new * v_new)
    return gain


@njit(cache=True)
def _all_finite(a):
    for v in a.ravel():
        if not np.isfinite(v):
            return False
    return True


@njit(cache=True)
def linearised_qp(X, A, B, s_ref, n_ref, q, DtD, u_vec, delta_applied, rate, nlo, nhi,
                  opponents, dt, sep_s, sep_n, sep_window):
    """One SQP iteration's QP at the plan ``X`` (6, K) with stage Jacobians ``A`` (36, K),
    ``B`` (12, K), in one call: ``(ok, G, H, f, Acon, blo, bhi, sense)`` with ``G`` from
    :func:`condense` and the rest from :func:`qp_arrays`; ``ok`` False (and the arrays empty)
    when the prediction is not finite."""
    K = X.shape[1]
    if not (_all_finite(X) and _all_finite(A) and _all_finite(B)):
        e = np.empty((0, 0))
        return False, e, e, np.empty(0), e, np.empty(0), np.empty(0), np.empty(0, np.int32)
    G = condense(A, B, K)
    H, f, Acon, blo, bhi, sense = qp_arrays(G, X[0], X[1], s_ref, n_ref, q, DtD, u_vec,
                                            delta_applied, rate, nlo, nhi, opponents, dt, sep_s,
                                            sep_n, sep_window)
    return True, G, H, f, Acon, blo, bhi, sense


@njit(cache=True)
def trial_step(u_vec, du, alpha, s0, s_pred, ds_lin, kappa_tab, ds, length, m):
    """A trial step's inputs and curvature, in one pass: ``u_vec + alpha du`` clipped to
    [-1, 1] (2K,), and the curvature (substeps K,) along the step's linearised progress
    ``[s0, s_pred + alpha ds_lin]``, stage after stage (the compiled prediction's layouts)."""
    nv = u_vec.shape[0]
    K = s_pred.shape[0]
    u_new = np.empty(nv)
    for i in range(nv):
        v = u_vec[i] + alpha * du[i]
        u_new[i] = -1.0 if v < -1.0 else (1.0 if v > 1.0 else v)
    nodes = np.empty(K + 1)
    nodes[0] = s0
    for k in range(K):
        nodes[k + 1] = s_pred[k] + alpha * ds_lin[k]
    return u_new, kappa_flat(kappa_tab, nodes, m, ds, length)


@njit(cache=True)
def score_rollout(X, u_vec, s_ref, n_ref, q, lo_tab, hi_tab, ds, length, opponents, dt, sep_s,
                  sep_n, sep_window, w_soft):
    """``(cost, lo, hi)`` of a plan's rollout ``X`` (6, K) in one pass: the bounds (K,) on n
    along ``X[0]`` (:class:`EdgeBounds`) and :func:`plan_cost` on them; ``inf`` cost (and
    bounds not filled) for a non-finite rollout."""
    K = X.shape[1]
    lo = np.empty(K)
    hi = np.empty(K)
    if not _all_finite(X):
        return np.inf, lo, hi
    for k in range(K):
        lo[k] = _lookup(lo_tab, X[0, k], ds, length)
        hi[k] = _lookup(hi_tab, X[0, k], ds, length)
    J = plan_cost(X[0], X[1], s_ref, n_ref, q, u_vec, lo, hi, opponents, dt, sep_s, sep_n,
                  sep_window, w_soft)
    return J, lo, hi


# ---------------------------------------------------------------------------- the SQP step
@intrinsic
def _call_casadi(typingctx, fn, arg, res, iw, w):
    """Call the CasADi-generated C function at address ``fn``,
    ``int f(const double** arg, double** res, long long* iw, double* w, int mem)``, with the
    addresses ``arg, res, iw, w`` and ``mem = 0``; returns its status (0: success). Addresses
    are plain integers, so a kernel that calls it caches on disk like any other."""
    if not all(isinstance(t, types.Integer) for t in (fn, arg, res, iw, w)):
        return None
    sig = types.int32(fn, arg, res, iw, w)

    def codegen(context, builder, signature, args):
        i8p = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.IntType(32), [i8p, i8p, i8p, i8p, ir.IntType(32)])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        ptrs = [builder.inttoptr(a, i8p) for a in args[1:]]
        return builder.call(f, ptrs + [ir.Constant(ir.IntType(32), 0)])
    return sig, codegen


@njit(cache=True)
def _run_prediction(fn, res_offset, ws, ptrs, iw, K, m):
    """Run a compiled prediction on its workspace ``ws`` (inputs already written; see
    :class:`_CompiledTrajectory`); returns its status."""
    o_w = workspace_offsets(K, m)[-1]
    return _call_casadi(fn, ptrs.ctypes.data, ptrs.ctypes.data + res_offset, iw.ctypes.data,
                        ws.ctypes.data + 8 * o_w)


@njit(cache=True)
def sqp_step(x0, u_vec, du, ds_lin, s_pred, J, step_sizes, relinearise, kappa_tab, ds, length,
             m, s_ref, n_ref, q, lo_tab, hi_tab, opponents, dt, sep_s, sep_n, sep_window, w_soft,
             roll_ws, roll_ptrs, roll_iw, roll_fn, roll_res, traj_ws, traj_ptrs, traj_iw,
             traj_fn, traj_res):
    """The merit-checked step of one SQP iteration in one compiled call, for
    :meth:`MPC.solve`: it calls the two compiled predictions itself, on their workspaces
    (``*_ws``, ``*_ptrs``, ``*_iw``, the function's address ``*_fn`` and the byte offset
    ``*_res`` of its result pointers, see :class:`_CompiledTrajectory`).

    Tries the step lengths ``step_sizes`` in order (:func:`trial_step`, the nonlinear rollout,
    :func:`score_rollout`), stops at the first that does not raise the cost ``J`` and keeps the
    cheapest; then, if ``relinearise``, rolls the accepted plan out again with its Jacobians
    and the curvature along its own progress. Returns ``(code, J, u_vec (2K,), X (6, K),
    A (36, K), B (12, K), lo (K,), hi (K,), s_nominal (K + 1,))``: ``code`` 0 no step lowers
    the cost (the rest is meaningless), 1 accepted (``A``, ``B`` empty), 2 accepted and
    linearised again, -1 a prediction failed. The arithmetic is :meth:`MPC._step_python`'s,
    kernel for kernel, so the plans are the same bit for bit."""
    K = s_pred.shape[0]
    _, o_u, o_kap, o_x, o_a, o_b, o_w = workspace_offsets(K, m)
    empty = np.empty((0, K))
    found = False
    best_J = np.inf
    best_u = u_vec
    best_X = np.empty((6, K))
    best_lo = np.empty(K)
    best_hi = np.empty(K)
    for a in range(step_sizes.shape[0]):
        ua, kap_a = trial_step(u_vec, du, step_sizes[a], x0[0], s_pred, ds_lin, kappa_tab, ds,
                               length, m)
        roll_ws[:o_u] = x0
        roll_ws[o_u:o_kap] = ua
        roll_ws[o_kap:o_x] = kap_a
        if _run_prediction(roll_fn, roll_res, roll_ws, roll_ptrs, roll_iw, K, m):
            return -1, J, u_vec, best_X, empty, empty, best_lo, best_hi, s_pred
        Xa = roll_ws[o_x:o_a].reshape(K, 6).T.copy()
        Ja, lo, hi = score_rollout(Xa, ua, s_ref, n_ref, q, lo_tab, hi_tab, ds, length,
                                   opponents, dt, sep_s, sep_n, sep_window, w_soft)
        if not found or Ja < best_J:
            found = True
            best_J, best_u, best_X, best_lo, best_hi = Ja, ua, Xa, lo, hi
        if Ja <= J:
            break
    if best_J > J:
        return 0, J, u_vec, best_X, empty, empty, best_lo, best_hi, s_pred
    s_nom = np.empty(K + 1)
    s_nom[0] = x0[0]
    s_nom[1:] = best_X[0]
    if not relinearise:
        return 1, best_J, best_u, best_X, empty, empty, best_lo, best_hi, s_nom
    traj_ws[:o_u] = x0
    traj_ws[o_u:o_kap] = best_u
    traj_ws[o_kap:o_x] = kappa_flat(kappa_tab, s_nom, m, ds, length)
    if _run_prediction(traj_fn, traj_res, traj_ws, traj_ptrs, traj_iw, K, m):
        return -1, J, u_vec, best_X, empty, empty, best_lo, best_hi, s_pred
    X = traj_ws[o_x:o_a].reshape(K, 6).T.copy()
    A = traj_ws[o_a:o_b].reshape(K, 36).T.copy()
    B = traj_ws[o_b:o_w].reshape(K, 12).T.copy()
    J2, lo2, hi2 = score_rollout(X, best_u, s_ref, n_ref, q, lo_tab, hi_tab, ds, length,
                                 opponents, dt, sep_s, sep_n, sep_window, w_soft)
    return 2, J2, best_u, X, A, B, lo2, hi2, s_nom


# ---------------------------------------------------------------------------- the solver
class MPC:
    """RTI-SQP MPC of one car on a track (see the module docstring).

    ``solve(x0, s_ref, n_ref, q, opponents, u_prev)``: ``x0`` (6,) the car's Frenet state,
    ``s_ref, n_ref`` (K,) references for the predicted states 1..K, ``q`` the tracking
    weight, ``opponents`` (M, 3) rows ``(s, n, s_dot)`` of the cars just ahead / behind
    (progress on the same unwrapped scale as ``x0[0]``), ``u_prev`` (2,) the input applied
    last (physical ``d, delta``). Returns the physical input ``(d, delta)`` to apply now.
    """

    def __init__(self, track: Track, vehicle: VehicleParams | None = None,
                 config: MPCConfig | None = None, line: str = "curvature"):
        import daqp  # noqa: F401  (fail early with an ImportError naming the package)
        self.track = track
        self.line = line                        # the racing line of the follower's warm start
        self.vehicle = vehicle or VehicleParams()
        self.cfg = config or MPCConfig()
        self._traj = _trajectory_function(self.vehicle, self.cfg)
        self._roll = _trajectory_function(self.vehicle, self.cfg, jacobians=False)
        self._step_sizes = np.array(self.cfg.step_sizes, dtype=float)
        if isinstance(self._traj, _CompiledTrajectory) and isinstance(self._roll, _CompiledTrajectory):
            self._step = sqp_step
            self._step_buffers = (*self._roll.kernel_args(), *self._traj.kernel_args())
        else:                                   # interpreted prediction: the same step in Python
            self._step, self._step_buffers = self._step_python, ()
        K = self.cfg.horizon
        # input-rate cost sum_{k=1..K-1} ||u^k - u^{k-1}||^2 as D^T D
        self._DtD = input_rate_matrix(K)
        self._rate = self.vehicle.delta_rate_max * self.cfg.dt / self.vehicle.delta_max  # normalised
        self._bounds_n = EdgeBounds(track, self.vehicle, self.cfg)
        self.stats = {"solves": 0, "fallbacks": 0, "restarts": 0, "qp_iterations": 0,
                      "rejected_steps": 0, "extra_iterations": 0,
                      "solve_ms": deque(maxlen=100_000)}
        self.reset()

    def reset(self) -> None:
        """Forget the warm start (call at the start of every race)."""
        self._U = None
        self._s_nom = None
        self._follower = getattr(self, "_follower", None)

    # -------------------------------------------------------------- internals
    def _follower_warm_start(self, x0):
        """Inputs (2, K) from rolling out the raceline follower's law in the simulator model:
        an on-track initial guess when the shifted previous plan has left the track."""
        if self._follower is None:
            self._follower = make_follower(self.track, self.vehicle, self.line)
        return follower_rollout(self.track, self.vehicle, self._follower, x0, self.cfg.horizon,
                                self.cfg.dt)

    def _plan(self, x0, U, s_prev=None, jacobians=True, passes=None):
        """Nonlinear rollout of inputs ``U`` (2, K) from ``x0``: ``(X (6, K), A, B)`` (A, B
        ``None`` without ``jacobians``).

        The curvature is a parameter of the compiled prediction, looked up at guessed stage
        progress: ``s_prev`` (K + 1,), else the previous nominal. ``passes`` (default
        ``cfg.curvature_passes``) rollouts then look it up again along the plan's own progress,
        so that two plans are costed on the stretch of track each one drives: scored along
        another plan's progress, a step that changes the speed is judged on the wrong corner
        and the merit test rejects the steps that would fix the plan."""
        cfg, t = self.cfg, self.track
        nodes = (stage_nodes(self._s_nom, x0, cfg.horizon, cfg.dt) if s_prev is None
                 else np.asarray(s_prev, dtype=float))
        kap = kappa_flat(t.kappa, nodes, cfg.substeps, t.ds, t.length)
        u_vec = np.ascontiguousarray(np.asarray(U, dtype=float).T).reshape(-1)
        for _ in range(cfg.curvature_passes if passes is None else passes):
            X = self._roll.states(x0, u_vec, kap, cfg.horizon)
            if not np.isfinite(X).all():
                break
            nodes = np.concatenate([[x0[0]], X[0]])
            kap = kappa_flat(t.kappa, nodes, cfg.substeps, t.ds, t.length)
        if not jacobians:
            return self._roll.states(x0, u_vec, kap, cfg.horizon), None, None
        X, A, B = self._traj.full(x0, u_vec, kap, cfg.horizon)
        return X, A, B

    def _step_python(self, x0, u_vec, du, ds_lin, s_pred, J, step_sizes, relinearise,
                     kappa_tab, ds, length, m, s_ref, n_ref, q, lo_tab, hi_tab, opponents, dt,
                     sep_s, sep_n, sep_window, w_soft):
        """:func:`sqp_step` with an interpreted prediction (no C compiler)."""
        K = s_pred.shape[0]
        best = None
        for alpha in step_sizes:
            ua, kap_a = trial_step(u_vec, du, alpha, x0[0], s_pred, ds_lin, kappa_tab, ds,
                                   length, m)
            Xa = self._roll.states(x0, ua, kap_a, K)
            Ja, lo, hi = score_rollout(Xa, ua, s_ref, n_ref, q, lo_tab, hi_tab, ds, length,
                                       opponents, dt, sep_s, sep_n, sep_window, w_soft)
            if best is None or Ja < best[0]:
                best = (Ja, ua, Xa, lo, hi)
            if Ja <= J:
                break
        Ja, ua, Xa, lo, hi = best
        if Ja > J:
            return 0, J, u_vec, Xa, None, None, lo, hi, s_pred
        s_nom = np.concatenate([[x0[0]], Xa[0]])
        if not relinearise:
            return 1, Ja, ua, Xa, None, None, lo, hi, s_nom
        X, A, B = self._traj.full(x0, ua, kappa_flat(kappa_tab, s_nom, m, ds, length), K)
        J2, lo2, hi2 = score_rollout(X, ua, s_ref, n_ref, q, lo_tab, hi_tab, ds, length,
                                     opponents, dt, sep_s, sep_n, sep_window, w_soft)
        return 2, J2, ua, X, A, B, lo2, hi2, s_nom

    def _score(self, X, U, s_ref, n_ref, q, opp):
        """``(cost, edges)`` of a plan on its *nonlinear* rollout ``X`` (6, K) with inputs
        ``U`` (2, K): tracking, input rates and the soft rows' quadratic penalty
        ``violation^2 / (2 rho)`` (DAQP's, for the track edges and the separations chosen
        along ``X``; :func:`score_rollout`), and the bounds ``(lo, hi)`` on n along ``X``;
        ``(inf, None)`` for a non-finite rollout."""
        cfg, b, t = self.cfg, self._bounds_n, self.track
        J, lo, hi = score_rollout(X, np.ascontiguousarray(U.T).reshape(-1), s_ref, n_ref,
                                  float(q), b.lo_table, b.hi_table, t.ds, t.length, opp, cfg.dt,
                                  cfg.sep_s, cfg.sep_n, cfg.sep_window, 0.5 / cfg.soft_rho_at(q))
        return J, (None if J == np.inf else (lo, hi))

    def _merit(self, X, U, s_ref, n_ref, q, opp):
        """The cost of :meth:`_score` alone."""
        return self._score(X, U, s_ref, n_ref, q, opp)[0]

    def solve(self, x0, s_ref, n_ref, q: float, opponents=None, u_prev=None) -> np.ndarray:
        import daqp
        t0 = time.perf_counter()
        cfg, K = self.cfg, self.cfg.horizon
        x0 = np.asarray(x0, dtype=float)
        s_ref = np.asarray(s_ref, dtype=float)
        n_ref = np.asarray(n_ref, dtype=float)
        u_prev = np.zeros(2) if u_prev is None else np.asarray(u_prev, dtype=float)
        opp = (np.zeros((0, 3)) if opponents is None
               else np.ascontiguousarray(opponents, dtype=float).reshape(-1, 3))

        w_soft = 0.5 / cfg.soft_rho_at(q)
        bounds, track = self._bounds_n, self.track

        def score(X_, U_):
            return self._score(X_, U_, s_ref, n_ref, q, opp)

        fresh = self._U is None
        if fresh:                                   # first solve: start from the follower
            U = self._follower_warm_start(x0)
        else:
            U = self._U
        X, A, B = self._plan(x0, U)
        J, edges = score(X, U)
        if not fresh:
            off = (np.inf if edges is None
                   else np.maximum(X[1] - edges[1], edges[0] - X[1]).max())
            if off > cfg.restart_offtrack or x0[3] < 2.0 * cfg.v_low:
                # the shifted plan leaves the track, or the car is (nearly) stopped, where the
                # linearisation sees little of what drive does: also try a follower rollout
                Uf = self._follower_warm_start(x0)
                Xf, Af, Bf = self._plan(x0, Uf)
                Jf, edges_f = score(Xf, Uf)
                if Jf < J:
                    U, X, A, B, J, edges = Uf, Xf, Af, Bf, Jf, edges_f
                    self.stats["restarts"] += 1
        status = "ok"
        for it in range(cfg.sqp_iterations):
            if edges is None:
                status = "nonfinite prediction"
                break
            s_pred = X[0]
            lo_n, hi_n = edges
            u_vec = np.ascontiguousarray(U.T).reshape(-1)                 # [d0, delta0, d1, ...]
            ok, G, H, f, Acon, blo, bhi, sense = linearised_qp(
                X, A, B, s_ref, n_ref, float(q), self._DtD, u_vec, float(u_prev[1]),
                self._rate, lo_n, hi_n, opp, cfg.dt, cfg.sep_s, cfg.sep_n, cfg.sep_window)
            if not ok:
                status = "nonfinite prediction"
                break
            du, _, exitflag, info = daqp.solve(H, f, Acon, bhi, blo, sense, rho_soft=cfg.soft_rho_at(q),
                                               iter_limit=cfg.qp_iter_limit)
            self.stats["qp_iterations"] += int(info.get("iterations", 0))
            if exitflag < 0 or not np.all(np.isfinite(du)):
                status = f"qp exitflag {exitflag}" if it == 0 else status
                break
            if predicted_decrease(H, f, Acon, blo, bhi, sense, du, w_soft) \
                    <= cfg.merit_rtol * J:
                break                          # converged: the model sees nothing left to gain
            # merit check on the nonlinear rollout: the full step, else shorter ones, each
            # with the curvature along its own linearised progress (no extra rollout)
            ds_lin = G[0::2] @ du
            code, J_new, u_new, X_new, A_new, B_new, lo_new, hi_new, s_nom = self._step(
                x0, u_vec, du, ds_lin, s_pred, J, self._step_sizes, it + 1 < cfg.sqp_iterations,
                track.kappa, track.ds, track.length, cfg.substeps, s_ref, n_ref, float(q),
                bounds.lo_table, bounds.hi_table, opp, cfg.dt, cfg.sep_s, cfg.sep_n, cfg.sep_window,
                w_soft, *self._step_buffers)
            if code < 0:
                raise RuntimeError("compiled MPC prediction failed")
            if code == 0:                      # no step improves the plan: keep it
                self.stats["rejected_steps"] += 1
                break
            U, X, J = u_new.reshape(K, 2).T, X_new, J_new
            edges = None if J == np.inf else (lo_new, hi_new)
            self._s_nom = s_nom
            if code == 1:                      # the last SQP iteration
                break
            # linearised again at the new plan, along its own progress (the trial was rolled
            # out along its linearised progress; s_nom is its own, so that rollout is already
            # the curvature pass)
            self.stats["extra_iterations"] += 1
            A, B = A_new, B_new
        self.stats["solves"] += 1
        if status != "ok":
            self.stats["fallbacks"] += 1
            U = (U if self._U is None else self._U).copy()   # the plan for now (shifted)
            U[0, :] = np.minimum(U[0, :], 0.0)          # fallback: keep the steering plan, lift off
            self._s_nom = None
        u0 = U[:, 0].copy()
        self._U = np.concatenate([U[:, 1:], U[:, -1:]], axis=1)          # shifted warm start
        self.last_status = status
        self.last_prediction = X if status == "ok" else None
        self.last_plan = (U, J if status == "ok" else np.inf)   # inputs (2, K) and their cost
        self.stats["solve_ms"].append(1e3 * (time.perf_counter() - t0))
        return u0
