"""Iterated best response (IBR) for N cars: the paper's game-theoretic baseline (Case IV).

At every decision the IBR car predicts every car's trajectory over a short horizon (default
2 s: ``K = 20`` stages of 0.1 s) and, for a fixed number of rounds (default 6, the paper's),
lets each car in turn compute its best response to the others' current predictions. Car i's
best response maximises its relative progress, the env's utility summed over the horizon,

    sum_k r_i^k = (s_i^K - max_{j != i} s_j^K) - (s_i^0 - max_{j != i} s_j^0),

which, with the other cars' predicted trajectories fixed, is its own terminal progress
``s_i^K``, less small costs (input rates, lateral motion, slip), subject to the MPC's
dynamics (the RK4 stage model of :mod:`agents.mpc`), input and steering-rate bounds, soft
track edges and soft separation from *every* other car's predicted trajectory at every stage:
per stage and car either ``|s_i - s_j| >= sep_s`` (progress, unwrapped) or
``|n_i - n_j| >= sep_n`` (lateral offset), whichever the plan satisfies with the larger
margin, on its side (the MPC's rule; arc length and lateral offset are never mixed). Rivals
are ordered front to back and the IBR car answers last in every round; it applies the first
input of its own final plan.

Each best response is one SQP iteration of the MPC's real-time-iteration machinery: the car's
plan (normalised inputs ``U`` (2, K)) is simulated by the compiled stage function (K = 20 gets
its own cached build), its condensed sensitivities give the linearised states, and one dense
QP in the input correction ``du`` (2K,) is solved with DAQP (see
:meth:`IBR._best_response`). The linear progress objective alone would make the QP a
bang-bang step of arbitrary length, so it carries

* ``w_step ||du||^2`` and a trust region ``trust ||G du||^2`` on the change of the predicted
  positions (strictly convex, bounded, and steps the linearisation can follow);
* the second-order progress loss of lateral motion that the linear model misses (a stage
  moving ``dn`` sideways over ``v dt`` loses about ``dn^2 / (2 v dt)``) and a cost on the body
  lateral velocity ``vy`` (keeps plans out of slides whose linearisation is useless);
* a merit check: a step that does not lower the best-response cost evaluated on the
  *nonlinear* prediction is rejected, and that car's trust weight quadruples (halving back
  towards ``trust_weight`` after accepted steps);
* a guard on the linearisation: where it has blown up (a predicted position moving more than
  ``max_sensitivity`` per unit of input; its QPs are so ill-conditioned that DAQP runs
  for thousands of iterations), the QP is not tried and the step counts as failed; DAQP also stops at ``qp_iter_limit``
  iterations, so a decision's time is bounded.

Rounds re-linearise, so R rounds are up to R SQP iterations per car, and the plans of one
decision, shifted by one stage, warm start the next (a follower rollout starts a car without
one, or whose shifted plan leaves the track). The rounds stop early once no step moved any
predicted position by more than ``tol`` (further rounds would repeat the same QPs); cars
whose plans cannot reach the IBR car's (no chain of plans within ``sep_window``) are not
solved. Robustness choices (the first two switchable): ``cautious`` also keeps every car clear
of each other car going on at its present speed and lateral offset, and caps the progress of
its predicted plan at that speed, since real rivals are not the best responders IBR assumes
(without it IBR cars run into rivals that do not speed away or do not take the predicted
side); ``keep_sides``: a car closing in from behind (at the present progress rates, within
the horizon) and the car ahead, when their offsets differ by at least ``sep_n / 2``, each
keep to their present side of the other (of its plan and of its constant-offset path)
wherever they are beside each other, instead of the side the plans happen to suggest
(without it the IBR car ahead edges into the line of a faster car behind that it predicts
will pass on its other side, while that car holds its line); rivals' previous steering is
unknown, so their first steering step is free.

Never raises on a failed QP (a solver or numerical error; any other exception is a bug and
propagates): a car whose QP fails keeps its current plan; when every QP of
the IBR car fails in a decision it applies its shifted previous plan (a counted fallback).
``IBR.stats`` and ``IBR.last`` report per decision the rounds until the plans stopped
changing, the decision and best-response times, failures and fallbacks.
"""
from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from numba import njit

from racing_env.track import Track
from racing_env.tracks import make_track
from racing_env.vehicle import VehicleParams

from .base import median_p99, register_agent
from .mpc import (EdgeBounds, MPCConfig, condense_states, trajectory_function,
                  follower_rollout, input_rate_matrix, kappa_at_substeps, make_follower,
                  stage_nodes)
from .mpc_agent import progress_rate, split_observation
from .threads import single_blas_thread


@dataclass(frozen=True)
class IBRConfig:
    """IBR settings. Lengths in m, times in s, weights per m of progress / per unit of the
    normalised inputs (throttle and steering in [-1, 1])."""

    horizon: int = 20             # K stages (2 s at dt = 0.1 s, the paper's IBR)
    rounds: int = 6               # best-response rounds per decision (the paper's N = 6)
    dt: float = 0.1
    substeps: int = 3             # RK4 steps per stage (as the MPC)
    v_low: float = 0.5            # slip regularisation of the prediction model [m/s]
    tol: float = 2e-3             # plans have stopped changing when no predicted (s, n) moves more [m]
    progress_weight: float = 10.0   # w_p: per m of terminal progress
    rate_weight: float = 1.0      # w_r: input-rate cost sum_k ||u^k - u^{k-1}||^2 (k = 0: the applied)
    step_weight: float = 2.0      # w_step: regulariser ||du||^2 of one best response
    trust_weight: float = 3.0     # w_tr: trust region sum_k ||d(s^k, n^k)||^2 on the change of
                                  # the predicted positions in one best response
    slip_weight: float = 1.0      # w_vy: cost sum_k vy_k^2 of body lateral velocity [per (m/s)^2]:
                                  # keeps plans out of slides the linearisation cannot follow
    lateral_weight: float = 1.0   # w_n: scale of the second-order progress loss of lateral
                                  # motion, w_p sum_k (n^k - n^{k-1})^2 / (2 v dt)
    track_margin: float = 0.03    # keep the car centre this far inside the edges
    sep_s: float = 0.15           # longitudinal separation [m]
    sep_n: float = 0.08           # lateral separation [m]
    sep_window: float = 2.0       # only stages closer than this in progress constrain [m]
    soft_rho: float = 1e-4        # DAQP rho_soft: reciprocal weight of soft violations
    max_sensitivity: float = 100.0  # a linearisation that moves a predicted position more than
                                    # this per unit of input [m] has blown up: the QP is not tried
    qp_iter_limit: int = 2000     # DAQP iterations before a best response counts as failed
    restart_offtrack: float = 0.25  # warm start from a follower rollout when the shifted plan
                                    # leaves the track by more than this [m]
    early_stop: bool = True       # stop the rounds once the plans have stopped changing
    cautious: bool = True         # also keep clear of every other car going on at its present
                                  # speed and offset, and cap its plan's progress at that speed
    keep_sides: bool = True       # a car closing in from behind and the car ahead each keep to
                                  # their present side of the other while beside each other
    skip_independent: bool = True  # solve only cars whose plans reach the IBR car's through
                                   # plans within sep_window (the others cannot move its plan)

    def __post_init__(self):
        if not (isinstance(self.horizon, (int, np.integer)) and 2 <= self.horizon <= 100):
            raise ValueError(f"IBR horizon must be an integer number of stages in 2..100, "
                             f"got {self.horizon!r}")
        if not (isinstance(self.rounds, (int, np.integer)) and 1 <= self.rounds <= 100):
            raise ValueError(f"IBR rounds must be an integer in 1..100, got {self.rounds!r}")
        if not (isinstance(self.substeps, (int, np.integer)) and 1 <= self.substeps <= 10):
            raise ValueError(f"IBR substeps must be an integer in 1..10, got {self.substeps!r}")
        if not (isinstance(self.slip_weight, (int, float)) and self.slip_weight >= 0):
            raise ValueError(f"IBRConfig.slip_weight must be >= 0, got {self.slip_weight!r}")
        for name in ("dt", "v_low", "tol", "progress_weight", "rate_weight", "step_weight",
                     "trust_weight", "lateral_weight", "sep_s", "sep_n", "sep_window", "soft_rho",
                     "restart_offtrack", "max_sensitivity"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"IBRConfig.{name} must be a positive number, got {v!r}")
        if not (isinstance(self.qp_iter_limit, (int, np.integer)) and self.qp_iter_limit >= 1):
            raise ValueError(f"IBRConfig.qp_iter_limit must be a positive integer, "
                             f"got {self.qp_iter_limit!r}")
        if not (isinstance(self.track_margin, (int, float)) and self.track_margin >= 0):
            raise ValueError(f"IBRConfig.track_margin must be >= 0, got {self.track_margin!r}")

    def mpc_config(self) -> MPCConfig:
        """The :class:`MPCConfig` of the shared stage model, edges and separation rule."""
        return MPCConfig(horizon=int(self.horizon), dt=self.dt, substeps=int(self.substeps),
                         v_low=self.v_low, track_margin=self.track_margin, sep_s=self.sep_s,
                         sep_n=self.sep_n, sep_window=self.sep_window, soft_rho=self.soft_rho,
                         restart_offtrack=self.restart_offtrack)


class _Plan:
    """One car's plan: inputs ``U`` (2, K), its prediction ``X`` (6, K) from ``x0`` (6,) with
    curvature ``kap`` (substeps, K), the stage Jacobians ``A`` (36, K), ``B`` (12, K), and the
    edge bounds ``lo, hi`` (K,) [m] on ``n`` at its predicted progress."""

    __slots__ = ("x0", "U", "kap", "X", "A", "B", "lo", "hi", "ok")


@dataclass
class _Decision:
    """The obstacles of one decision, built by :meth:`IBR.solve` and passed to every best
    response. Rows ``0..N-1`` are every car's current plan ``(S, N)`` (rows, K) [m], kept up
    to date by :meth:`store`; when cautious, rows ``N..2N-1`` every car going on at its
    present progress rate and lateral offset. ``ok`` (rows,) marks usable rows, ``owner``
    (rows,) the car of each row, ``s_cap`` (rows, K) [m] the cap on each row's progress, and
    ``side`` (N, rows) the kept sides (+1 left, -1 right, 0 free) of each car against each
    row."""

    S: np.ndarray
    N: np.ndarray
    ok: np.ndarray
    owner: np.ndarray
    s_cap: np.ndarray
    side: np.ndarray

    def store(self, c: int, plan: _Plan) -> None:
        """Make car ``c``'s row its plan's predicted ``(s, n)`` (or mark it unusable)."""
        self.ok[c] = plan.ok
        if plan.ok:
            self.S[c] = plan.X[0]
            self.N[c] = plan.X[1]


# what a best response may raise on a bad solve (counted as a failed QP): a solver's own error
# (RuntimeError) and numerical errors. Anything else (a TypeError, NameError, ...) is a bug
# and propagates.
_SOLVE_ERRORS = (RuntimeError, ArithmeticError, np.linalg.LinAlgError)


@njit(cache=True)
def _separation_pairs(s, n, S, N, cap, ok, owner, c, sep_s, sep_n, window, length, side):
    """Near (stage, obstacle) pairs of car ``c``'s plan ``s, n`` (K,) [m] against the
    trajectories ``S, N`` (rows, K) of other cars (rows with ``owner != c`` and ``ok``), their
    progress capped at ``cap`` (rows, K): ``(stage (p,), lateral (p,), sign (p,), margin (p,))``.
    Progress differences are unwrapped differences shifted by whole laps ``length`` [m] to the
    nearest image at the first stage (a lapped car beside this one is near, as in the env's
    contact rule; nothing jumps at the start/finish line). Per pair the lateral
    separation ``sign * (n - n_j) >= sep_n`` where ``lateral``, else the longitudinal one
    ``sign * (s - s_j) >= sep_s`` (the rule of :func:`agents.mpc.separation_choice`: never a
    mix of progress and offset); ``margin = sign * gap - need`` is negative where violated.
    ``side`` (rows,): where nonzero, car ``c`` keeps to that side of the row (``+1`` left):
    the pair is lateral, with that sign, whenever ``|s - s_j| < sep_s`` (beside each other)
    or the plan is on that side and the usual rule picks lateral; otherwise longitudinal."""
    cars, K = S.shape
    stage = np.empty(cars * K, np.int64)
    lateral = np.empty(cars * K, np.bool_)
    sign = np.empty(cars * K)
    margin = np.empty(cars * K)
    p = 0
    for j in range(cars):
        if owner[j] == c or not ok[j]:
            continue
        lap = length * np.floor((s[0] - min(S[j, 0], cap[j, 0])) / length + 0.5)
        for k in range(K):
            ds = s[k] - min(S[j, k], cap[j, k]) - lap
            if abs(ds) >= window:
                continue
            dn = n[k] - N[j, k]
            if side[j] != 0.0:
                # a kept side: beside each other (|ds| < sep_s) always laterally, on that side
                lat = abs(ds) < sep_s or (side[j] * dn >= 0.0 and abs(dn) / sep_n >= abs(ds) / sep_s)
                gap = dn if lat else ds
                sg = side[j] if lat else (1.0 if gap >= 0.0 else -1.0)
            else:
                lat = abs(dn) / sep_n >= abs(ds) / sep_s
                gap = dn if lat else ds
                sg = 1.0 if gap >= 0.0 else -1.0
            stage[p] = k
            lateral[p] = lat
            sign[p] = sg
            margin[p] = sg * gap - (sep_n if lat else sep_s)
            p += 1
    return stage[:p], lateral[:p], sign[:p], margin[:p]


@njit(cache=True)
def _assemble(X, x0, u, Gx, lo, hi, stage, lateral, sign, margin, H0, DtD, w_p, w_r, w_n, w_vy,
              trust, rate, u_prev, has_prev):
    """The best-response QP of :meth:`IBR._best_response` in DAQP's form:
    ``(H, f, A, bu, bl, sense, w_lat)``: the first 2K bounds are the input box, then K hard
    steering-rate rows, K soft edge rows and one soft row per separation pair."""
    K = X.shape[1]
    nv = 2 * K
    m = stage.shape[0]
    # quadratic terms as one stacked least-squares block ||r + M du||^2
    w_lat = np.empty(K)
    M = np.zeros((4 * K, nv))
    r = np.zeros(4 * K)
    st = np.sqrt(2.0 * trust)
    sv = np.sqrt(2.0 * w_vy)
    s_prev, n_prev = x0[0], x0[1]
    for k in range(K):
        w_lat[k] = w_n * w_p / (2.0 * max(X[0, k] - s_prev, 0.05))
        sl = np.sqrt(2.0 * w_lat[k])
        for i in range(nv):
            M[k, i] = st * Gx[k, 0, i]
            M[K + k, i] = st * Gx[k, 1, i]
            M[2 * K + k, i] = sv * Gx[k, 4, i]
            M[3 * K + k, i] = sl * (Gx[k, 1, i] - (Gx[k - 1, 1, i] if k > 0 else 0.0))
        r[2 * K + k] = sv * X[4, k]
        r[3 * K + k] = sl * (X[1, k] - n_prev)
        s_prev, n_prev = X[0, k], X[1, k]
    H = H0 + M.T @ M
    f = M.T @ r + 2.0 * w_r * (DtD @ u)
    for i in range(nv):
        f[i] -= w_p * Gx[K - 1, 0, i]
    if has_prev:                                        # the rate cost includes u^0 - u_applied
        for i in range(2):
            H[i, i] += 2.0 * w_r
            f[i] += 2.0 * w_r * (u[i] - u_prev[i])
    # constraints
    A = np.zeros((2 * K + m, nv))
    bu = np.empty(nv + 2 * K + m)
    bl = np.empty(nv + 2 * K + m)
    sense = np.zeros(nv + 2 * K + m, np.int32)
    for i in range(nv):
        bu[i] = 1.0 - u[i]
        bl[i] = -1.0 - u[i]
    for k in range(K):                                  # steering rate (hard)
        A[k, 2 * k + 1] = 1.0
        if k > 0:
            A[k, 2 * k - 1] = -1.0
            d = u[2 * k + 1] - u[2 * k - 1]
        elif has_prev:
            d = u[1] - u_prev[1]
        else:
            d = 0.0
        free = k == 0 and not has_prev
        bu[nv + k] = 1e30 if free else rate - d
        bl[nv + k] = -1e30 if free else -rate - d
    for k in range(K):                                  # track edges (soft)
        for i in range(nv):
            A[K + k, i] = Gx[k, 1, i]
        bu[nv + K + k] = hi[k] - X[1, k]
        bl[nv + K + k] = lo[k] - X[1, k]
        sense[nv + K + k] = 8
    for q in range(m):                                  # separation (soft)
        k = stage[q]
        row = 1 if lateral[q] else 0
        for i in range(nv):
            A[2 * K + q, i] = sign[q] * Gx[k, row, i]
        bu[nv + 2 * K + q] = 1e30
        bl[nv + 2 * K + q] = -margin[q]
        sense[nv + 2 * K + q] = 8
    return H, f, A, bu, bl, sense, w_lat


@njit(cache=True)
def _reach(S, ok, window, length):
    """Cars (bool (N,)) connected to car 0 through plans ``S`` (N, K) that come within
    ``window`` of each other in progress (nearest image over laps of ``length``) at a common
    stage."""
    n, K = S.shape
    reach = np.zeros(n, np.bool_)
    reach[0] = True
    grown = True
    while grown:
        grown = False
        for a in range(n):
            if not reach[a]:
                continue
            for b in range(n):
                if reach[b] or not ok[b]:
                    continue
                lap = length * np.floor((S[a, 0] - S[b, 0]) / length + 0.5)
                for k in range(K):
                    if abs(S[a, k] - S[b, k] - lap) < window:
                        reach[b] = True
                        grown = True
                        break
    return reach


@njit(cache=True)
def _merit(s, n, vy, n0, u, DtD, lo, hi, margin, w_p, w_r, w_lat, w_vy, w_soft):
    """Best-response cost of a plan (see :meth:`IBR._best_response`): ``-w_p s^K`` plus the
    input-rate cost ``w_r u' DtD u``, the lateral-motion cost ``sum_k w_lat_k dn_k^2``, the
    slip cost ``w_vy sum_k vy_k^2`` and ``w_soft`` times the squared edge and separation
    violations (``margin < 0``)."""
    K = s.shape[0]
    cost = -w_p * s[K - 1] + w_r * (u @ (DtD @ u)) + w_vy * (vy @ vy)
    prev = n0
    pen = 0.0
    for k in range(K):
        dn = n[k] - prev
        prev = n[k]
        cost += w_lat[k] * dn * dn
        v = max(n[k] - hi[k], lo[k] - n[k], 0.0)
        pen += v * v
    for i in range(margin.shape[0]):
        if margin[i] < 0.0:
            pen += margin[i] * margin[i]
    return cost + w_soft * pen


class IBR:
    """Iterated best response over N cars (see the module docstring).

    ``solve(states, u_prev)``: ``states`` (N, 6) every car's Frenet state, row 0 the deciding
    car, progress ``s`` on one unwrapped scale; ``u_prev`` (2,) the normalised input it applied
    last (for its steering-rate bound; None leaves the first steering step free). Returns the
    normalised input ``[throttle, steering]`` (2,) to apply now. Warm starts are kept per row,
    so keep the car order fixed within a race and call :meth:`reset` between races.

    ``stats`` accumulates over decisions: counts ``decisions, fallbacks, restarts, br_solves,
    br_failures, br_rejected, unconverged`` and per-decision deques ``decision_ms`` (wall
    time), ``rounds`` (rounds run: until a round changed no predicted position by more than
    ``tol``, or ``rounds``) and per-QP ``br_ms``. ``last`` describes the last decision:
    ``rounds``, ``converged``, ``changes`` (largest position change [m] per round), ``ms``,
    ``br_ms``, ``br_failures``, ``br_rejected``, ``fallback``, ``plans`` (N, 6, K) every car's
    final predicted states at stages 1..K and ``inputs`` (N, 2, K) their normalised inputs.
    """

    def __init__(self, track: Track, vehicle: VehicleParams | None = None,
                 config: IBRConfig | None = None):
        import daqp  # noqa: F401  (fail early with an ImportError naming the package)
        self.track = track
        self.vehicle = vehicle or VehicleParams()
        self.cfg = config or IBRConfig()
        self._mcfg = self.cfg.mpc_config()
        K = self.cfg.horizon
        self._traj = trajectory_function(self.vehicle, self._mcfg)
        self._DtD = input_rate_matrix(K)
        self._H0 = 2.0 * (self.cfg.rate_weight * self._DtD + self.cfg.step_weight * np.eye(2 * K))
        self._bounds_n = EdgeBounds(track, self.vehicle, self._mcfg)
        self._rate = self.vehicle.delta_rate_max * self.cfg.dt / self.vehicle.delta_max
        self._follower = None
        self.stats = {"decisions": 0, "fallbacks": 0, "restarts": 0, "br_solves": 0,
                      "br_failures": 0, "br_rejected": 0, "unconverged": 0,
                      "decision_ms": deque(maxlen=100_000), "br_ms": deque(maxlen=100_000),
                      "rounds": deque(maxlen=100_000)}
        self.last = {}
        self.reset()

    def reset(self) -> None:
        """Forget the warm starts (call at the start of every race)."""
        self._prev = None            # per car: (U (2, K), stage progress (K + 1,) or None)

    # ------------------------------------------------------------------ plans
    def _evaluate(self, plan: _Plan) -> None:
        X, A, B = self._traj(plan.x0, plan.U, plan.kap)
        plan.X, plan.A, plan.B = X, A, B
        plan.ok = bool(np.isfinite(X.sum() + A.sum() + B.sum()))
        if plan.ok:
            plan.lo, plan.hi = self._bounds_n(X[0])

    def _offtrack(self, plan: _Plan) -> float:
        """How far [m] the plan leaves the track edges (minus margins) in stages 1..K-1 (the
        appended last stage of a shifted plan was never optimised); inf if not finite."""
        if not plan.ok:
            return np.inf
        n = plan.X[1, :-1]
        return float(np.maximum(n - plan.hi[:-1], plan.lo[:-1] - n).max())

    def _restart(self, plan: _Plan) -> None:
        """Replace the plan by a raceline-follower rollout from its initial state."""
        if self._follower is None:
            self._follower = make_follower(self.track, self.vehicle)
        cfg = self.cfg
        plan.U = follower_rollout(self.track, self.vehicle, self._follower, plan.x0,
                                  cfg.horizon, cfg.dt)
        plan.kap = kappa_at_substeps(self.track, stage_nodes(None, plan.x0, cfg.horizon, cfg.dt),
                                     cfg.substeps)
        self._evaluate(plan)
        self.stats["restarts"] += 1

    def _warm_start(self, c: int, x0: np.ndarray) -> _Plan:
        """Car ``c``'s previous plan shifted by one stage (last input repeated) and simulated
        from ``x0``; a follower rollout when there is none or it leaves the track."""
        cfg, K = self.cfg, self.cfg.horizon
        plan = _Plan()
        plan.x0 = x0
        prev = self._prev[c] if self._prev is not None else None
        if prev is None:
            self._restart(plan)
            self.stats["restarts"] -= 1            # a first plan is not a restart
            return plan
        U, nodes = prev
        plan.U = np.concatenate([U[:, 1:], U[:, -1:]], axis=1)
        if x0[3] < 2.0 * cfg.v_low:
            # a stopped car's brake has no effect and so no gradient: linearise at drive
            plan.U[0] = np.maximum(plan.U[0], 0.2)
        plan.kap = kappa_at_substeps(self.track, stage_nodes(nodes, x0, K, cfg.dt), cfg.substeps)
        self._evaluate(plan)
        if self._offtrack(plan) > cfg.restart_offtrack:
            self._restart(plan)
        return plan

    # ------------------------------------------------------------------ one best response
    def _plan_merit(self, plan: _Plan, margin, w_lat, u_prev) -> float:
        cfg = self.cfg
        first = 0.0 if u_prev is None else cfg.rate_weight * float(np.sum((plan.U[:, 0] - u_prev) ** 2))
        return first + _merit(plan.X[0], plan.X[1], plan.X[4], plan.x0[1], plan.U.T.reshape(-1),
                      self._DtD, plan.lo, plan.hi, margin, cfg.progress_weight,
                      cfg.rate_weight, w_lat, cfg.slip_weight, 0.5 / cfg.soft_rho)

    def _best_response(self, c: int, plans: list, dec: _Decision, u_prev, trust: float):
        """One SQP iteration of car ``c``'s best response to the other plans (the obstacles of
        ``dec``), with trust-region weight ``trust``.

        The QP in the input correction ``du`` (2K,), with ``G`` the condensed sensitivities
        of the predicted ``(s^k, n^k)``::

            min  -w_p G_s^K du + w_r ||D (u + du)||^2 + w_step ||du||^2 + trust ||G du||^2
                 + sum_k w_lat_k (n^k - n^{k-1} + (G_n du)_k - (G_n du)_{k-1})^2
                 + w_vy ||vy + G_vy du||^2
            s.t. -1 <= u + du <= 1, steering rate (hard); edges, separation (soft)

        Returns ``(new plan or None, the step's largest change of a predicted position [m])``:
        None with an infinite change when the QP fails or the prediction is not finite, None
        with a finite change when the step does not lower the merit (:func:`_merit`, the QP's
        cost on the nonlinear prediction): the caller then keeps the plan and tightens
        ``trust``.
        """
        import daqp
        cfg, K = self.cfg, self.cfg.horizon
        p = plans[c]
        S, N, cap, ok, owner = dec.S, dec.N, dec.s_cap, dec.ok, dec.owner
        sep = (cfg.sep_s, cfg.sep_n, cfg.sep_window, float(self.track.length), dec.side[c])
        stage, lat, sign, margin = _separation_pairs(p.X[0], p.X[1], S, N, cap, ok, owner, c, *sep)
        Gx = condense_states(np.ascontiguousarray(p.A), np.ascontiguousarray(p.B), K)
        if not np.abs(Gx[:, :2, :]).max() <= cfg.max_sensitivity:  # also catches NaN
            return None, np.inf
        u_vec = p.U.T.reshape(-1)
        H, f, A, bu, bl, sense, w_lat = _assemble(
            p.X, p.x0, u_vec, Gx, p.lo, p.hi, stage, lat, sign, margin, self._H0, self._DtD,
            cfg.progress_weight, cfg.rate_weight, cfg.lateral_weight, cfg.slip_weight, trust,
            self._rate, np.zeros(2) if u_prev is None else u_prev, u_prev is not None)
        du, _, exitflag, _ = daqp.solve(H, f, A, bu, bl, sense, rho_soft=cfg.soft_rho,
                                         iter_limit=int(cfg.qp_iter_limit))
        if exitflag < 0 or not np.isfinite(du.sum()):
            return None, np.inf
        new = _Plan()
        new.x0 = p.x0
        new.U = np.clip(u_vec + du, -1.0, 1.0).reshape(K, 2).T
        new.kap = p.kap
        self._evaluate(new)
        if not new.ok:
            return None, np.inf
        change = float(np.abs(new.X[:2] - p.X[:2]).max())
        new_margin = _separation_pairs(new.X[0], new.X[1], S, N, cap, ok, owner, c, *sep)[3]
        if (self._plan_merit(new, new_margin, w_lat, u_prev)
                > self._plan_merit(p, margin, w_lat, u_prev)):
            return None, change
        return new, change

    # ------------------------------------------------------------------ the decision
    def _closing_sides(self, states, s_const) -> np.ndarray:
        """Kept sides (N, N): ``side[a, b] = +1`` (-1) when car ``a`` must stay left (right) of
        car ``b`` wherever they are beside each other, 0 where free. Set for every car ``b``
        behind a car ``a`` and closing in on it within the horizon (going on at their present
        progress rates), when their lateral offsets differ by at least ``sep_n / 2``: each
        keeps to its present side (the car ahead does not move into the line of the faster car
        behind, nor does that car cut across the car ahead)."""
        cfg = self.cfg
        n = len(states)
        side = np.zeros((n, n))
        L = float(self.track.length)
        for a in range(n):
            for b in range(n):
                if a == b:
                    continue
                gap = states[a, 0] - states[b, 0]
                gap -= L * np.floor(gap / L + 0.5)
                if gap < 0.0:
                    continue                                    # b is not behind a
                ahead = gap + (s_const[a] - states[a, 0]) - (s_const[b] - states[b, 0])
                if ahead.min() >= cfg.sep_s:
                    continue                                    # b does not reach a
                dn = states[a, 1] - states[b, 1]
                if abs(dn) >= 0.5 * cfg.sep_n:
                    side[a, b] = 1.0 if dn > 0.0 else -1.0
                    side[b, a] = -side[a, b]
        return side

    def solve(self, states: np.ndarray, u_prev: np.ndarray | None = None) -> np.ndarray:
        t0 = time.perf_counter()
        cfg = self.cfg
        states = np.asarray(states, dtype=float)
        if states.ndim != 2 or states.shape[1] != 6 or len(states) < 1:
            raise ValueError(f"states must have shape (N, 6) with N >= 1, got {states.shape}")
        if not np.isfinite(states).all():
            raise ValueError("states must be finite")
        n = len(states)
        if self._prev is not None and len(self._prev) != n:
            self._prev = None                               # the number of cars changed
        u_prev = None if u_prev is None else np.asarray(u_prev, dtype=float)
        plans = [self._warm_start(c, states[c].copy()) for c in range(n)]
        # cautious separation: each car's progress at stage k is taken as at most its constant-
        # progress-rate extrapolation (N, K), so a car behind keeps its distance even when the
        # car ahead does not speed up as its best response predicts
        K = cfg.horizon
        # obstacles for the separation rows: rows 0..N-1 every car's current plan (s, n), kept
        # up to date; when cautious, rows N..2N-1 every car going on at its present progress
        # rate and lateral offset, and the plans' progress capped by the same extrapolation
        # (a rival that is not the predicted best responder neither speeds up nor swerves
        # into a gap the IBR car leaves it)
        s_const = states[:, :1] + (np.maximum(progress_rate(states, self.track), 0.0)[:, None]
                                   * cfg.dt * np.arange(1, K + 1))
        rows = 2 * n if cfg.cautious else n
        dec = _Decision(S=np.zeros((rows, K)), N=np.zeros((rows, K)),
                        ok=np.zeros(rows, dtype=bool), owner=np.arange(rows) % n,
                        s_cap=np.full((rows, K), np.inf), side=np.zeros((n, rows)))
        if cfg.cautious:
            dec.s_cap[:n] = s_const
            dec.S[n:] = s_const
            dec.N[n:] = states[:, 1:2]
            dec.ok[n:] = True
        # kept sides: a car closing in from behind and the car ahead each keep to their
        # present side of the other, against its plan and its constant-offset path alike
        if cfg.keep_sides:
            sides = self._closing_sides(states, s_const)
            dec.side[:, :n] = sides
            if cfg.cautious:
                dec.side[:, n:] = sides
        for c in range(n):
            dec.store(c, plans[c])
        start_U = plans[0].U.copy()
        # rivals from the front to the back, then the deciding car (it answers the latest plans)
        order = [int(c) for c in np.argsort(-states[1:, 0], kind="stable") + 1] + [0]
        trust = np.full(n, cfg.trust_weight)
        ego_ok = False
        rounds, converged, br_ms, failures, rejected, changes = 0, False, [], 0, 0, []
        for r in range(cfg.rounds):
            rounds = r + 1
            change = 0.0
            active = (_reach(dec.S[:n], dec.ok[:n], cfg.sep_window,
                             float(self.track.length))
                      if cfg.skip_independent else np.ones(n, bool))
            for c in order:
                if not active[c]:
                    continue
                if not plans[c].ok:
                    self._restart(plans[c])
                    dec.store(c, plans[c])
                    if not plans[c].ok:
                        failures += 1
                        continue
                tb = time.perf_counter()
                try:
                    new, step = self._best_response(c, plans, dec, u_prev if c == 0 else None,
                                                    trust[c])
                except _SOLVE_ERRORS:                       # a bad solve, not a bug: a failure
                    new, step = None, np.inf
                br_ms.append(1e3 * (time.perf_counter() - tb))
                if not np.isfinite(step):                   # the QP failed: keep the plan
                    failures += 1
                    change = np.inf
                    continue
                change = max(change, step)
                if c == 0:
                    ego_ok = True                           # the IBR car's own QP worked
                if new is None:                             # no better: a shorter step next
                    rejected += 1
                    trust[c] = min(4.0 * trust[c], 1e6)
                    continue
                trust[c] = max(0.5 * trust[c], cfg.trust_weight)
                plans[c] = new
                dec.store(c, new)
            changes.append(change)
            if change < cfg.tol:
                converged = True
                if cfg.early_stop:
                    break
        fallback = not ego_ok
        U0 = plans[0].U if ego_ok else start_U
        u0 = np.clip(U0[:, 0], -1.0, 1.0)
        # keep every plan (and its stage progress) to warm start the next decision
        self._prev = [(p.U, np.concatenate([[p.x0[0]], p.X[0]]) if p.ok else None) for p in plans]
        ms = 1e3 * (time.perf_counter() - t0)
        st = self.stats
        st["decisions"] += 1
        st["fallbacks"] += int(fallback)
        st["br_solves"] += len(br_ms)
        st["br_failures"] += failures
        st["br_rejected"] += rejected
        st["unconverged"] += int(not converged)
        st["decision_ms"].append(ms)
        st["br_ms"].extend(br_ms)
        st["rounds"].append(rounds)
        self.last = {"rounds": rounds, "converged": converged, "changes": changes, "ms": ms,
                     "br_ms": br_ms, "br_failures": failures, "br_rejected": rejected,
                     "fallback": fallback, "plans": np.stack([p.X for p in plans]),
                     "inputs": np.stack([p.U for p in plans])}
        return u0


@register_agent("ibr")
class IBRAgent:
    """Iterated-best-response agent (the paper's Case IV baseline, for any number of cars).

    Keywords: any :class:`IBRConfig` field (``rounds=6, horizon=20, tol=...``) or a full
    ``config``; ``vehicle`` (:class:`VehicleParams`, assumed for every car); ``n_preview``,
    the env's ``RaceConfig.n_preview`` (to read the observation layout). ``stats``: ``solves``
    (decisions), ``fallbacks`` (decisions whose QPs all failed, applying the shifted previous
    plan), ``restarts`` (plans restarted from a follower rollout), ``br_solves``,
    ``br_failures``, ``br_rejected`` (best-response QPs, failed ones, steps the merit check
    refused), ``rounds_mean``/``rounds_max`` (rounds until the plans stopped changing),
    ``unconverged`` (decisions still changing after ``rounds``), ``decision_ms_median``/``_p99``
    and ``br_ms_median``/``_p99`` (wall times). ``ibr.last`` holds the last decision's record.
    """

    spec_keywords_from = IBRConfig     # what ``**config_fields`` takes (agents.base.agent_parameters)

    def __init__(self, config: IBRConfig | None = None, vehicle: VehicleParams | None = None,
                 n_preview: int = 10, **config_fields):
        if config is not None and config_fields:
            raise ValueError(f"give either config or IBRConfig fields, not both "
                             f"(got {sorted(config_fields)})")
        known = set(IBRConfig.__dataclass_fields__)
        unknown = set(config_fields) - known
        if unknown:
            raise ValueError(f"unknown IBR parameter(s) {sorted(unknown)}; expected IBRConfig "
                             f"fields: {', '.join(sorted(known))}")
        if not (isinstance(n_preview, (int, np.integer)) and n_preview >= 0):
            raise ValueError(f"n_preview must be a non-negative integer, got {n_preview!r}")
        self.config = config or IBRConfig(**config_fields)
        self.vehicle = vehicle or VehicleParams()
        self.n_preview = n_preview
        self.ibr: IBR | None = None
        self.track: Track | None = None

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        track = make_track(track)
        if self.ibr is None or self.track is not track:
            self.ibr = IBR(track, self.vehicle, self.config)
        self.track = track
        self.ibr.reset()
        self.agent_id = agent_id
        self._u_prev = np.zeros(2)

    @property
    def stats(self) -> dict:
        if self.ibr is None:
            return {}
        st = self.ibr.stats
        med, p99 = median_p99(st["decision_ms"])
        br_med, br_p99 = median_p99(st["br_ms"])
        rounds = np.asarray(st["rounds"], dtype=float)
        return {"solves": st["decisions"], "fallbacks": st["fallbacks"],
                "restarts": st["restarts"], "br_solves": st["br_solves"],
                "br_failures": st["br_failures"], "br_rejected": st["br_rejected"],
                "rounds_mean": float(rounds.mean()) if rounds.size else float("nan"),
                "rounds_max": int(rounds.max()) if rounds.size else 0,
                "unconverged": st["unconverged"],
                "decision_ms_median": med, "decision_ms_p99": p99,
                "br_ms_median": br_med, "br_ms_p99": br_p99}

    def act(self, observation: np.ndarray) -> np.ndarray:
        if self.ibr is None:
            raise RuntimeError("IBRAgent.act() before reset(track, ...)")
        ego, others = split_observation(observation, self.n_preview)
        with single_blas_thread():       # results independent of the BLAS thread count
            u = self.ibr.solve(np.vstack([ego[None, :], others]), self._u_prev)
        self._u_prev = u
        return u.astype(np.float32)
