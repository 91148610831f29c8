"""The MPC's solver: :class:`MPC`, the RTI-SQP loop of one car (warm start, QP, merit-checked
steps, fallback), run step by step from Python or in one compiled call
(:mod:`.compiled_solve`); each SQP iteration's merit-checked step is
:func:`~agents.mpc.sqp_step.sqp_step` (:meth:`MPC._step_python` is the same step for an
interpreted prediction)."""

from __future__ import annotations

import math
import time
from collections import deque
from typing import Any

import numpy as np

from racing_env.track import Track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams, vehicle_for_track

from . import compiled_solve
from .codegen import CompiledTrajectory
from .config import MPCConfig, class_scale, config_for_vehicle, exact_soft_on, slip_bound
from .prediction import (
    follower_rollout,
    kappa_flat,
    limited_throttle,
    make_follower,
    stage_nodes,
    trajectory_functions,
)
from .qp import (
    EXACT_RHO_FLOOR,
    EdgeBounds,
    ProblemConstants,
    exact_soft_qp,
    input_rate_matrix,
    linearised_qp,
    opponent_paths,
    predicted_decrease,
    score_rollout,
)
from .sqp_step import StepCode, StepConstants, StepResult, sqp_step, trial_step

#: Throttle taken off the whole plan for the second start's braked candidate
#: (:attr:`MPCConfig.second_start`; normalised throttle in [-1, 1]).
SECOND_START_LIFT = 0.5


class MPC:
    """RTI-SQP MPC of one car on a track (see :mod:`agents.mpc`).

    ``solve(x0, s_ref, n_ref, q, opponents, u_prev)``: ``x0`` (6,) the car's Frenet state,
    ``s_ref, n_ref`` (K,) references for the predicted states 1..K, ``q`` the tracking
    weight, ``opponents`` the cars just ahead / behind: (M, 3) rows ``(s, n, s_dot)`` that
    keep their progress rate and lateral offset (the paper's prediction), or their predicted
    ``(s, n)`` at stages 1..K, (M, K, 2) (:func:`~agents.mpc.qp.opponent_paths`; progress on
    the same unwrapped scale as ``x0[0]``), ``u_prev`` (2,) the input applied
    last (physical ``d, delta``). Returns the physical input ``(d, delta)`` to apply now.

    The car is ``vehicle``, else the default car of the track's class
    (``track.vehicle_class``; a vehicle of another class is a ``ValueError``). The config's
    lengths are the ORCA car's, scaled to the car's size, and the cost measures position
    errors in ORCA-car widths (:func:`~agents.mpc.config.class_scale`); for the ORCA car
    nothing changes.
    """

    def __init__(
        self,
        track: Track,
        vehicle: VehicleParams | FullSizeParams | None = None,
        config: MPCConfig | None = None,
        line: str = "curvature",
    ):
        import daqp  # noqa: F401  (fail early with an ImportError naming the package)

        self.track = track
        self.line = line  # the racing line of the follower's warm start
        self.vehicle: VehicleParams | FullSizeParams = vehicle_for_track(track, vehicle, "MPC")
        self.cfg = config_for_vehicle(config or MPCConfig(), self.vehicle)
        # position errors and soft violations in ORCA-car widths: q / k^2, rho k^2 (1 for ORCA)
        self._ls2 = class_scale(self.vehicle)[1] ** 2
        # with and without the jacobians, compiled at the same time
        self._traj, self._roll = trajectory_functions(self.vehicle, self.cfg)
        self._step_sizes = np.array(self.cfg.step_sizes, dtype=float)
        if isinstance(self._traj, CompiledTrajectory) and isinstance(
            self._roll, CompiledTrajectory
        ):
            self._kernels = (self._roll.kernel_args(), self._traj.kernel_args())
            self._step = self._compiled_step
        else:  # interpreted prediction: the same step in Python
            self._step = self._step_python
        K = self.cfg.horizon
        # input-rate cost sum_{k=1..K-1} ||u^k - u^{k-1}||^2 as D^T D
        self._DtD = input_rate_matrix(K)
        self._rate = (
            self.vehicle.delta_rate_max * self.cfg.dt / self.vehicle.delta_max
        )  # normalised
        self._bounds_n = EdgeBounds(track, self.vehicle, self.cfg)
        self._slip = slip_bound(self.cfg, self.vehicle)  # slip-angle rows (none: all zeros)
        self._exact_soft = exact_soft_on(self.cfg, self.vehicle)
        self._full = isinstance(self.vehicle, FullSizeParams)
        self._tables = None  # the compiled solve's constant tables, built on first use
        self._key: tuple | None = None  # batch_key's, built on first use
        # counters and the solve times (a deque) by name
        self.stats: dict[str, Any] = {
            "solves": 0,
            "fallbacks": 0,
            "restarts": 0,
            "second_starts": 0,
            "damped_steps": 0,
            "qp_iterations": 0,
            "rejected_steps": 0,
            "extra_iterations": 0,
            "exact_failed": 0,
            "solve_ms": deque(maxlen=100_000),
        }
        self.reset()

    #: what a copy shares with its original (:meth:`__deepcopy__`): the compiled predictions
    #: (ctypes handles, with work buffers that every call overwrites and copies out of) and
    #: the constant tables; never written after construction
    _SHARED = (
        "track",
        "vehicle",
        "cfg",
        "_traj",
        "_roll",
        "_kernels",
        "_bounds_n",
        "_DtD",
        "_tables",
        "_key",
    )

    def __deepcopy__(self, memo: dict) -> MPC:
        """A copy with its own warm start, follower and counters that shares the compiled
        predictions and the constant tables with this MPC (the predictions hold ctypes
        handles, which cannot be copied). Both then solve bit for bit alike; use them from
        one thread (the shared predictions' work buffers are overwritten by every call)."""
        import copy

        new = MPC.__new__(MPC)
        memo[id(self)] = new
        for key, value in self.__dict__.items():
            if key == "_step":
                continue  # a method bound to this MPC: bound to the copy below
            setattr(new, key, value if key in self._SHARED else copy.deepcopy(value, memo))
        compiled = self.__dict__.get("_step") == self._compiled_step
        new._step = new._compiled_step if compiled else new._step_python
        return new

    def reset(self) -> None:
        """Forget the warm start (call at the start of every race)."""
        self._U: np.ndarray | None = None  # the shifted plan (2, K), the next warm start
        self._s_nom: np.ndarray | None = None
        self._follower = getattr(self, "_follower", None)

    # -------------------------------------------------------------- internals
    def _follower_warm_start(self, x0):
        """Inputs (2, K) from rolling out the raceline follower's law in the simulator model:
        an on-track initial guess when the shifted previous plan has left the track."""
        if self._follower is None:
            self._follower = make_follower(self.track, self.vehicle, self.line)
        return follower_rollout(
            self.track, self.vehicle, self._follower, x0, self.cfg.horizon, self.cfg.dt
        )

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
        nodes = (
            stage_nodes(self._s_nom, x0, cfg.horizon, cfg.dt)
            if s_prev is None
            else np.asarray(s_prev, dtype=float)
        )
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

    def _compiled_step(
        self, c: StepConstants, u_vec, du, ds_lin, s_pred, J: float, relinearise: bool
    ) -> StepResult:
        """:func:`sqp_step` on this MPC's two compiled predictions."""
        return sqp_step(c, u_vec, du, ds_lin, s_pred, J, relinearise, *self._kernels)

    def _step_python(
        self, c: StepConstants, u_vec, du, ds_lin, s_pred, J: float, relinearise: bool
    ) -> StepResult:
        """:func:`sqp_step` with an interpreted prediction (no C compiler)."""
        K = s_pred.shape[0]
        x0, m, p = c.x0, c.m, c.problem
        best: tuple[Any, ...] | None = None  # (cost, inputs, states, lo, hi) of the cheapest
        for alpha in c.step_sizes:
            ua, kap_a = trial_step(
                u_vec, du, alpha, x0[0], s_pred, ds_lin, c.kappa_tab, p.ds, p.length, m
            )
            Xa = self._roll.states(x0, ua, kap_a, K)
            Ja, lo, hi = score_rollout(Xa, ua, p)
            if best is None or Ja < best[0]:
                best = (Ja, ua, Xa, lo, hi)
            if Ja <= J:
                break
        assert best is not None  # step_sizes is not empty
        Ja, ua, Xa, lo, hi = best
        if Ja > J:
            return StepResult(StepCode.REJECTED, J, u_vec, Xa, None, None, lo, hi, s_pred)
        s_nom = np.concatenate([[x0[0]], Xa[0]])
        if not relinearise:
            return StepResult(StepCode.ACCEPTED, Ja, ua, Xa, None, None, lo, hi, s_nom)
        X, A, B = self._traj.full(x0, ua, kappa_flat(c.kappa_tab, s_nom, m, p.ds, p.length), K)
        J2, lo2, hi2 = score_rollout(X, ua, p)
        return StepResult(StepCode.RELINEARISED, J2, ua, X, A, B, lo2, hi2, s_nom)

    def _problem(self, s_ref, n_ref, q, opp, u_prev) -> ProblemConstants:
        """The :class:`~agents.mpc.qp.ProblemConstants` of a solve: references ``s_ref, n_ref``
        (K,), tracking weight ``q``, opponents ``opp`` (any form :func:`opponent_paths` takes),
        the input ``u_prev`` (2,) applied
        last."""
        cfg, b, t = self.cfg, self._bounds_n, self.track
        q_cost, w_soft = self._cost_weights(q)
        return ProblemConstants(
            s_ref,
            n_ref,
            q_cost,
            self._DtD,
            float(u_prev[1]),
            self._rate,
            b.lo_table,
            b.hi_table,
            t.ds,
            t.length,
            opponent_paths(opp, cfg.horizon, cfg.dt),
            cfg.dt,
            cfg.sep_s,
            cfg.sep_n,
            cfg.sep_window,
            w_soft,
            *self._slip,
        )

    def _cost_weights(self, q: float) -> tuple[float, float]:
        """``(q_cost, w_soft)``: theta's tracking weight ``q`` in the cost's units (position
        errors in ORCA-car widths) and the soft rows' weight ``1 / (2 rho)`` of the cost."""
        return float(q) / self._ls2, 0.5 / (self.cfg.soft_rho_at(q) * self._ls2)

    def _soft_rho(self, q_cost: float) -> float:
        """DAQP's ``rho_soft`` for the cost's tracking weight ``q_cost``."""
        return self.cfg.soft_rho_at(q_cost * self._ls2) * self._ls2

    @staticmethod
    def _score(X, U, p: ProblemConstants):
        """``(cost, edges)`` of a plan on its *nonlinear* rollout ``X`` (6, K) with inputs
        ``U`` (2, K) under the solve's constants ``p``: tracking, input rates and the soft rows'
        quadratic penalty ``violation^2 / (2 rho)`` (DAQP's, for the track edges and the
        separations chosen along ``X``; :func:`~agents.mpc.qp.score_rollout`), and the bounds
        ``(lo, hi)`` on n along ``X``; ``(inf, None)`` for a non-finite rollout."""
        J, lo, hi = score_rollout(X, np.ascontiguousarray(U.T).reshape(-1), p)
        return J, (None if J == np.inf else (lo, hi))

    def _merit(self, X, U, s_ref, n_ref, q, opp):
        """The cost of :meth:`_score` alone, of the solve with these references, weight and
        opponents."""
        return self._score(X, U, self._problem(s_ref, n_ref, q, opp, np.zeros(2)))[0]

    def _sqp(self, consts: StepConstants, U, X, A, B, J: float, edges):
        """The SQP iterations of :meth:`solve` from the plan ``U`` (2, K) with rollout ``X``,
        Jacobians ``A, B``, cost ``J`` and edges: ``(U, X, J, edges, status)`` of the last
        accepted plan (``status`` "ok", else why it failed). Sets ``_s_nom``."""
        import daqp

        cfg, K = self.cfg, self.cfg.horizon
        problem = consts.problem
        q, w_soft = problem.q, problem.w_soft
        status = "ok"
        for it in range(cfg.sqp_iterations):
            if edges is None:
                status = "nonfinite prediction"
                break
            s_pred = X[0]
            lo_n, hi_n = edges
            u_vec = np.ascontiguousarray(U.T).reshape(-1)  # [d0, delta0, d1, ...]
            ok, G, H, f, Acon, blo, bhi, sense = linearised_qp(X, A, B, u_vec, lo_n, hi_n, problem)
            if not ok:
                status = "nonfinite prediction"
                break
            du, exitflag = self._qp(daqp, H, f, Acon, blo, bhi, sense, q)
            if exitflag < 0 or not np.all(np.isfinite(du)):
                status = f"qp exitflag {exitflag}" if it == 0 else status
                break
            if predicted_decrease(H, f, Acon, blo, bhi, sense, du, w_soft) <= cfg.merit_rtol * J:
                break  # converged: the model sees nothing left to gain
            # merit check on the nonlinear rollout: the full step, else shorter ones, each
            # with the curvature along its own linearised progress (no extra rollout)
            ds_lin = G[0::2] @ du
            relinearise = it + 1 < cfg.sqp_iterations
            step = self._step(consts, u_vec, du, ds_lin, s_pred, J, relinearise)
            if step.code == StepCode.REJECTED and cfg.step_damping:
                qp = (G, H, f, Acon, blo, bhi, sense, q)
                step = self._damped_step(daqp, consts, u_vec, s_pred, J, relinearise, qp, step)
            if step.code == StepCode.FAILED:
                raise RuntimeError("compiled MPC prediction failed")
            if step.code == StepCode.REJECTED:  # no step improves the plan: keep it
                self.stats["rejected_steps"] += 1
                break
            U, X, J = step.u_vec.reshape(K, 2).T, step.X, step.J
            edges = None if J == np.inf else (step.lo, step.hi)
            self._s_nom = step.s_nominal
            if step.code == StepCode.ACCEPTED:  # the last SQP iteration
                break
            # linearised again at the new plan, along its own progress (the trial was rolled
            # out along its linearised progress; s_nom is its own, so that rollout is already
            # the curvature pass)
            self.stats["extra_iterations"] += 1
            A, B = step.A, step.B
        return U, X, J, edges, status

    def _qp(self, daqp, H, f, Acon, blo, bhi, sense, q: float):
        """DAQP's step ``(du, exitflag)`` of the QP ``H, f`` with rows ``Acon`` (soft rows
        weighted as the solve's tracking weight ``q`` asks; ``q`` is the problem's, in the
        cost's units: theta's ``q / k_wid^2``). With ``exact_soft`` (the full-size default)
        every soft row is charged as the cost charges it (:func:`~agents.mpc.qp.exact_soft_qp`);
        else DAQP weighs it by ``1 / |row|^2`` (the paper's MPC, as its races were stored)."""
        rho = self._soft_rho(q)
        nv = f.shape[0]
        exact = exact_soft_qp(H, f, Acon, blo, bhi, sense, rho) if self._exact_soft else None
        if exact is not None and exact[6] >= EXACT_RHO_FLOOR:
            H2, f2, A2, lo2, hi2, sense2, rho2 = exact
            du, _, exitflag, info = daqp.solve(
                H2, f2, A2, hi2, lo2, sense2, rho_soft=rho2, iter_limit=self.cfg.qp_iter_limit
            )
            self.stats["qp_iterations"] += int(info.get("iterations", 0))
            if exitflag >= 0:
                return du[:nv], exitflag
        if exact is not None:  # rows of very different norms (slip rows near rest) leave
            # DAQP's tolerances too coarse for the scaled rows, or rho below its floor
            self.stats["exact_failed"] += 1  # DAQP's own weighting instead
        du, _, exitflag, info = daqp.solve(
            H, f, Acon, bhi, blo, sense, rho_soft=rho, iter_limit=self.cfg.qp_iter_limit
        )
        self.stats["qp_iterations"] += int(info.get("iterations", 0))
        return du, exitflag

    def _damped_step(
        self, daqp, consts, u_vec, s_pred, J, relinearise, qp, rejected: StepResult
    ) -> StepResult:
        """After a QP step that no step length lets lower the cost (``rejected``): the QP
        ``qp = (G, H, f, Acon, blo, bhi, sense, q)`` again with ``lam * mean(diag H) I`` added
        to ``H`` for each ``lam`` of ``cfg.step_damping`` in turn (Levenberg-Marquardt), and
        the first of their steps that the merit check accepts; else ``rejected``. A damped
        step is shorter and turned toward the model's steepest descent, which the line search
        along the first step cannot reach where the linearisation of the soft rows (a track
        edge, a separation) misleads it."""
        G, H, f, Acon, blo, bhi, sense, q = qp
        scale = float(np.mean(np.diag(H)))
        eye = np.eye(H.shape[0])
        for lam in self.cfg.step_damping:
            du, exitflag = self._qp(daqp, H + (lam * scale) * eye, f, Acon, blo, bhi, sense, q)
            if exitflag < 0 or not np.all(np.isfinite(du)):
                continue
            step = self._step(consts, u_vec, du, G[0::2] @ du, s_pred, J, relinearise)
            if step.code != StepCode.REJECTED:
                self.stats["damped_steps"] += 1
                return step
        return rejected

    def _limited_throttle(self, u: float, vx: float, omega: float = 0.0) -> float:
        """The env's normalised throttle for the MPC's throttle ``u`` of the full-size car at
        speed ``vx``: a share of its traction or brake limit
        (:func:`~agents.mpc.prediction.limited_throttle`), as its prediction applies it."""
        v = self.vehicle
        assert isinstance(v, FullSizeParams)
        mid, half = 0.5 * (v.d_max + v.d_min), 0.5 * (v.d_max - v.d_min)
        return (limited_throttle(v, u, vx, math, omega) - mid) / half

    @staticmethod
    def _pays_penalty(X, U, J: float, p: ProblemConstants) -> bool:
        """Whether the plan's cost ``J`` under the solve's constants ``p`` includes the soft
        rows' penalty (an edge or a separation violated along its rollout ``X``)."""
        u_vec = np.ascontiguousarray(U.T).reshape(-1)
        J0, _, _ = score_rollout(X, u_vec, p._replace(w_soft=0.0))
        return J > J0 * (1.0 + 1e-9)

    # ------------------------------------------------------- the compiled solve
    #: whether solves may run in one compiled call (:attr:`compiled`); a process that races
    #: once sets it False (the ``race`` command): the compiled solve's kernels take about
    #: 10 s to compile on a cold cache, and save about 0.4 ms per decision after
    compiled_solves: bool = True

    @property
    def compiled(self) -> bool:
        """Whether :meth:`solve` runs in one compiled call
        (:mod:`agents.mpc.compiled_solve`): :attr:`compiled_solves`, a compiled prediction,
        the ORCA car, no damped steps, no second start and DAQP's own weighting of the soft
        rows (the paper's MPC). Otherwise the same solve runs step by step from Python: the
        same plans, bit for bit."""
        return (
            self.compiled_solves
            and self._step == self._compiled_step
            and not self._full
            and not self.cfg.step_damping
            and not self.cfg.second_start
            and not self._exact_soft
        )

    def _solve_tables(self):
        """The :class:`~agents.mpc.compiled_solve.SolveTables` of this MPC (built on first
        use, shared by its copies: :func:`~agents.mpc.compiled_solve.tables_for`)."""
        if getattr(self, "_tables", None) is None:
            if self._follower is None:
                self._follower = make_follower(self.track, self.vehicle, self.line)
            self._tables = compiled_solve.tables_for(self, self._follower)
        return self._tables

    def batch_key(self) -> tuple:
        """Solvers with equal keys share their :meth:`_solve_tables` and can be solved in one
        call (:func:`~agents.mpc.compiled_solve.solve_many`): the same track, car, config and
        warm-start line."""
        if not self.compiled:
            return (id(self),)
        if self._key is None:  # built once: its parts never change (11 us per decision)
            specs = (self._roll.kernel_spec().fn, self._traj.kernel_spec().fn)  # type: ignore[union-attr]
            self._key = (id(self.track), specs, repr(self.vehicle), repr(self.cfg), self.line)
        return self._key

    def _compiled_args(self, x0, s_ref, n_ref, q, opponents, u_prev) -> tuple:
        """The per-problem arguments of :func:`~agents.mpc.compiled_solve.solve_problem` for
        ``solve(x0, s_ref, n_ref, q, opponents, u_prev)``: ``(x0, s_ref, n_ref, q_cost, w_soft,
        rho, delta_applied, opp, fresh)``, the weights those of the Python solve."""
        cfg = self.cfg
        q_cost, w_soft = self._cost_weights(q)
        return (
            np.asarray(x0, dtype=float),
            np.ascontiguousarray(s_ref, dtype=float),
            np.ascontiguousarray(n_ref, dtype=float),
            q_cost,
            w_soft,
            self._soft_rho(q_cost),
            0.0 if u_prev is None else float(u_prev[1]),
            opponent_paths(opponents, cfg.horizon, cfg.dt),
            self._U is None,
        )

    def _warm(self) -> tuple:
        """``(u_warm (2K,), s_nom (K + 1,), has_nom)``: this MPC's warm start for the compiled
        solve."""
        K = self.cfg.horizon
        u = np.zeros(2 * K) if self._U is None else np.ascontiguousarray(self._U.T).reshape(-1)
        has_nom = self._s_nom is not None
        return u, (self._s_nom if has_nom else np.zeros(K + 1)), has_nom

    def _finish(self, x0, result, seconds: float) -> np.ndarray:
        """Apply one compiled solve's ``result`` (:func:`~agents.mpc.compiled_solve
        .solve_problem`'s tuple): its counters and nominal, then :meth:`_conclude`; returns
        the input to apply now."""
        from .compiled_solve import COUNTERS, OK, PREDICTION_FAILED, QP_FAILED

        code, exitflag, u_vec, X, J, s_nom, has_nom, counters = result
        if code == PREDICTION_FAILED:
            raise RuntimeError("compiled MPC prediction failed")
        for key, n in zip(COUNTERS, counters):
            self.stats[key] += int(n)
        self._s_nom = s_nom.copy() if has_nom else None
        status = "ok" if code == OK else "nonfinite prediction"
        if code == QP_FAILED:
            status = f"qp exitflag {int(exitflag)}"
        U = u_vec.reshape(self.cfg.horizon, 2).T
        return self._conclude(x0, U, X, J, status, seconds)

    def solve(
        self,
        x0: np.ndarray,
        s_ref: np.ndarray,
        n_ref: np.ndarray,
        q: float,
        opponents: np.ndarray | None = None,
        u_prev: np.ndarray | None = None,
    ) -> np.ndarray:
        """The input ``(d, delta)`` to apply now (see the class docstring): one compiled call
        where :attr:`compiled`, else the same solve step by step."""
        if self.compiled:
            t0 = time.perf_counter()
            args = self._compiled_args(x0, s_ref, n_ref, q, opponents, u_prev)
            u_warm, s_nom, has_nom = self._warm()
            inputs = (self._solve_tables(), *args[:8], u_warm, args[8], s_nom, has_nom)
            result = compiled_solve.solve_problem(*inputs)
            return self._finish(args[0], result, time.perf_counter() - t0)
        return self._solve_python(x0, s_ref, n_ref, q, opponents, u_prev)

    def _solve_python(
        self,
        x0: np.ndarray,
        s_ref: np.ndarray,
        n_ref: np.ndarray,
        q: float,
        opponents: np.ndarray | None = None,
        u_prev: np.ndarray | None = None,
    ) -> np.ndarray:
        """:meth:`solve` step by step from Python (every config; the reference of the compiled
        solve)."""
        t0 = time.perf_counter()
        cfg = self.cfg
        x0 = np.asarray(x0, dtype=float)
        s_ref = np.asarray(s_ref, dtype=float)
        n_ref = np.asarray(n_ref, dtype=float)
        u_prev = np.zeros(2) if u_prev is None else np.asarray(u_prev, dtype=float)
        problem = self._problem(s_ref, n_ref, q, opponents, u_prev)

        def score(X_, U_):
            return self._score(X_, U_, problem)

        fresh = self._U is None
        if fresh:  # first solve: start from the follower
            U = self._follower_warm_start(x0)
        else:
            U = self._U
        X, A, B = self._plan(x0, U)
        J, edges = score(X, U)
        if not fresh:
            off = np.inf if edges is None else np.maximum(X[1] - edges[1], edges[0] - X[1]).max()
            if off > cfg.restart_offtrack or x0[3] < 2.0 * cfg.v_low:
                # the shifted plan leaves the track, or the car is (nearly) stopped, where the
                # linearisation sees little of what drive does: also try a follower rollout
                Uf = self._follower_warm_start(x0)
                Xf, Af, Bf = self._plan(x0, Uf)
                Jf, edges_f = score(Xf, Uf)
                # a stopped full-size car whose plan brakes starts from the follower: its
                # reference leaves a car at rest so slowly (a few metres in the horizon, a
                # tenth of a car width in the cost's units) that staying costs less than the
                # throttle swing, a local minimum it never left (Monza, after a contact)
                stuck = self._full and x0[3] < 2.0 * cfg.v_low and U[0, 0] <= 0.0
                if Jf < J or stuck:
                    U, X, A, B, J, edges = Uf, Xf, Af, Bf, Jf, edges_f
                    self.stats["restarts"] += 1
        consts = StepConstants(x0, self._step_sizes, self.track.kappa, cfg.substeps, problem)
        U, X, J, edges, status = self._sqp(consts, U, X, A, B, J, edges)
        if cfg.second_start and status == "ok" and self._pays_penalty(X, U, J, problem):
            # a local solution in traffic: try the follower's rollout, and the plan with less
            # throttle (the basin behind the car ahead, not beside it); keep the cheapest
            s_nom, best = self._s_nom, None
            lifted = U.copy()
            lifted[0] = np.clip(lifted[0] - SECOND_START_LIFT, -1.0, 1.0)
            for U2 in (self._follower_warm_start(x0), lifted):
                self._s_nom = s_nom  # each start guesses progress along the first plan
                X2, A2, B2 = self._plan(x0, U2)
                J2, edges2 = score(X2, U2)
                plan = self._sqp(consts, U2, X2, A2, B2, J2, edges2)
                if plan[4] == "ok" and plan[2] < (J if best is None else best[0][2]):
                    best = (plan, self._s_nom)
            if best is None:
                self._s_nom = s_nom
            else:
                (U, X, J, edges, _), self._s_nom = best
                self.stats["second_starts"] += 1
        return self._conclude(x0, U, X, J, status, time.perf_counter() - t0)

    def _conclude(self, x0, U, X, J: float, status: str, seconds: float) -> np.ndarray:
        """How every solve ends, from its plan ``U`` (2, K) with rollout ``X`` and cost ``J``
        and its ``status``: the fallback where it failed, the shifted warm start, the
        records (``last_*``, ``stats``); returns the input to apply now."""
        self.stats["solves"] += 1
        if status != "ok":
            self.stats["fallbacks"] += 1
            if x0[3] < 2.0 * self.cfg.v_low:
                # (nearly) stopped: lifting off would keep the car where it is, and the same
                # failed solve would repeat at every step (Silverstone's grid: the QP hit its
                # iteration limit, the car never left); drive the follower's rollout instead
                U = self._follower_warm_start(x0)
            else:
                U = (U if self._U is None else self._U).copy()  # the plan for now (shifted)
                U[0, :] = np.minimum(U[0, :], 0.0)  # fallback: keep the steering, lift off
            self._s_nom = None
        u0 = U[:, 0].copy()
        if isinstance(self.vehicle, FullSizeParams):  # the prediction's throttle limits
            u0[0] = self._limited_throttle(u0[0], float(x0[3]), float(x0[5]))
        self._U = np.concatenate([U[:, 1:], U[:, -1:]], axis=1)  # shifted warm start
        self.last_status = status
        self.last_prediction = X if status == "ok" else None
        self.last_plan = (U, J if status == "ok" else np.inf)  # inputs (2, K) and their cost
        self.stats["solve_ms"].append(1e3 * seconds)
        return u0
