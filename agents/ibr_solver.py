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

This module is the solve (:class:`IBR`); its settings and the data of a decision are in
:mod:`agents.ibr_data`, the compiled kernels of a best response in :mod:`agents.ibr_kernels`,
the agent that races with it in :mod:`agents.ibr`.
"""

from __future__ import annotations

import time
from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np

from racing_env.track import Track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams

from .ibr_data import IBRConfig, _Decision, _Plan, ibr_class_weights
from .ibr_kernels import _assemble, _merit, _reach, _separation_pairs
from .mpc import (
    EdgeBounds,
    condense_states,
    follower_rollout,
    input_rate_matrix,
    kappa_at_substeps,
    make_follower,
    stage_nodes,
    trajectory_function,
)
from .mpc.prediction import limited_throttle
from .mpc_agent import progress_rate

if TYPE_CHECKING:
    from racing_env.controllers import RacelineFollower

# what a best response may raise on a bad solve (counted as a failed QP): a solver's own error
# (RuntimeError) and numerical errors. Anything else (a TypeError, NameError, ...) is a bug
# and propagates.
_SOLVE_ERRORS = (RuntimeError, ArithmeticError, np.linalg.LinAlgError)


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

    def __init__(
        self,
        track: Track,
        vehicle: VehicleParams | FullSizeParams | None = None,
        config: IBRConfig | None = None,
    ):
        from dataclasses import replace

        import daqp  # noqa: F401  (fail early with an ImportError naming the package)

        from racing_env.vehicles import vehicle_for_track

        from .mpc.config import CLASS_SCALED_FIELDS, class_scale

        self.track = track
        self.vehicle = vehicle_for_track(track, vehicle, "IBR")
        self.cfg = config or IBRConfig()
        k_len, k_wid = class_scale(self.vehicle)
        if (k_len, k_wid) != (1.0, 1.0):  # the ORCA car's lengths, scaled to this car's size
            k = {"length": k_len, "width": k_wid}
            self.cfg = replace(
                self.cfg,
                **{
                    f: getattr(self.cfg, f) * k[kind]
                    for f, kind in CLASS_SCALED_FIELDS.items()
                    if hasattr(self.cfg, f)
                },
            )
            self.cfg = replace(self.cfg, **ibr_class_weights(self.cfg, self.vehicle))
        self._mcfg = self.cfg.mpc_config()
        K = self.cfg.horizon
        self._traj = trajectory_function(self.vehicle, self._mcfg)
        self._DtD = input_rate_matrix(K)
        self._H0 = 2.0 * (self.cfg.rate_weight * self._DtD + self.cfg.step_weight * np.eye(2 * K))
        self._bounds_n = EdgeBounds(track, self.vehicle, self._mcfg)
        self._rate = self.vehicle.delta_rate_max * self.cfg.dt / self.vehicle.delta_max
        self._follower: RacelineFollower | None = None
        bound = self.cfg.braking_bound
        if bound is None:
            bound = isinstance(self.vehicle, FullSizeParams)
        self._vmax = self._braking_limit() if bound else None  # (M + 1,) on the track's grid
        # the grid's indices, built once (a decision looks the limit up a dozen times)
        self._vmax_at = None if self._vmax is None else np.arange(len(self._vmax), dtype=float)
        # counters and the decision, best-response and round logs (deques) by name
        self.stats: dict[str, Any] = {
            "decisions": 0,
            "fallbacks": 0,
            "restarts": 0,
            "br_solves": 0,
            "br_failures": 0,
            "br_rejected": 0,
            "unconverged": 0,
            "decision_ms": deque(maxlen=100_000),
            "br_ms": deque(maxlen=100_000),
            "rounds": deque(maxlen=100_000),
        }
        self.last: dict[str, Any] = {}  # the last decision's figures, plans and inputs
        self.reset()

    def reset(self) -> None:
        """Forget the warm starts (call at the start of every race)."""
        # per car: (U (2, K), stage progress (K + 1,) or None)
        self._prev: list[tuple[np.ndarray, np.ndarray | None]] | None = None

    def _braking_limit(self) -> np.ndarray:
        """The race line's braking limit [m/s] on the track's uniform grid, closed (M + 1,):
        the highest speed at each point from which the car still brakes for every corner
        ahead (:func:`racing_env.raceline.speed.braking_limit`, the line's own grip, the
        straights capped at the tow's cap, :data:`agents.reference_tables.TOW_SPEED_CAP`)."""
        from racing_env.envelope import ggv
        from racing_env.raceline.speed import braking_limit

        from .reference_tables import TOW_SPEED_CAP

        if self._follower is None:
            self._follower = make_follower(self.track, self.vehicle)
        line = self._follower.raceline
        assert line is not None
        s = np.asarray(line.s, dtype=float)
        ds = np.diff(np.append(s, line.length))
        cap = TOW_SPEED_CAP * ggv(self.vehicle).top_speed
        vb = braking_limit(np.asarray(line.kappa), ds, float(line.mu_nominal), self.vehicle, cap)
        return np.append(vb, vb[0])

    def _speed_excess(self, plan: _Plan) -> np.ndarray:
        """``vx^k - vmax(s^k)`` (K,) of the plan's stages (positive: too fast to brake in
        time)."""
        assert self._vmax is not None and self._vmax_at is not None
        M = len(self._vmax) - 1
        L = float(self.track.length)
        x = np.mod(plan.X[0], L) * (M / L)
        return plan.X[3] - np.interp(x, self._vmax_at, self._vmax)

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
        cfg, follower = self.cfg, self._follower
        plan.U = follower_rollout(self.track, self.vehicle, follower, plan.x0, cfg.horizon, cfg.dt)
        plan.kap = kappa_at_substeps(
            self.track, stage_nodes(None, plan.x0, cfg.horizon, cfg.dt), cfg.substeps
        )
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
            self.stats["restarts"] -= 1  # a first plan is not a restart
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
        first = (
            0.0 if u_prev is None else cfg.rate_weight * float(np.sum((plan.U[:, 0] - u_prev) ** 2))
        )
        if self._vmax is not None:  # the braking bound's soft rows, charged as the QP's
            excess = np.maximum(self._speed_excess(plan), 0.0)
            first += (0.5 / cfg.soft_rho) * float(excess @ excess)
        return first + _merit(
            plan.X[0],
            plan.X[1],
            plan.X[4],
            plan.x0[1],
            plan.U.T.reshape(-1),
            self._DtD,
            plan.lo,
            plan.hi,
            margin,
            cfg.progress_weight,
            cfg.rate_weight,
            w_lat,
            cfg.slip_weight,
            0.5 / cfg.soft_rho,
        )

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
            p.X,
            p.x0,
            u_vec,
            Gx,
            p.lo,
            p.hi,
            stage,
            lat,
            sign,
            margin,
            self._H0,
            self._DtD,
            cfg.progress_weight,
            cfg.rate_weight,
            cfg.lateral_weight,
            cfg.slip_weight,
            trust,
            self._rate,
            np.zeros(2) if u_prev is None else u_prev,
            u_prev is not None,
        )
        if self._vmax is not None:  # soft rows vx^k + (G_vx du)_k <= vmax(s^k)
            nv = 2 * K
            A = np.vstack([A, Gx[:, 3, :]])
            bu = np.concatenate([bu, -self._speed_excess(p)])
            bl = np.concatenate([bl, np.full(K, -1e30)])
            sense = np.concatenate([sense, np.full(K, 8, dtype=sense.dtype)])
            assert len(bu) == nv + A.shape[0]
        du, _, exitflag, _ = daqp.solve(
            H, f, A, bu, bl, sense, rho_soft=cfg.soft_rho, iter_limit=int(cfg.qp_iter_limit)
        )
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
        if self._plan_merit(new, new_margin, w_lat, u_prev) > self._plan_merit(
            p, margin, w_lat, u_prev
        ):
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
                    continue  # b is not behind a
                ahead = gap + (s_const[a] - states[a, 0]) - (s_const[b] - states[b, 0])
                if ahead.min() >= cfg.sep_s:
                    continue  # b does not reach a
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
            self._prev = None  # the number of cars changed
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
        s_const = states[:, :1] + (
            np.maximum(progress_rate(states, self.track), 0.0)[:, None]
            * cfg.dt
            * np.arange(1, K + 1)
        )
        rows = 2 * n if cfg.cautious else n
        dec = _Decision(
            S=np.zeros((rows, K)),
            N=np.zeros((rows, K)),
            ok=np.zeros(rows, dtype=bool),
            owner=np.arange(rows) % n,
            s_cap=np.full((rows, K), np.inf),
            side=np.zeros((n, rows)),
        )
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
            active = (
                _reach(dec.S[:n], dec.ok[:n], cfg.sep_window, float(self.track.length))
                if cfg.skip_independent
                else np.ones(n, bool)
            )
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
                    new, step = self._best_response(
                        c, plans, dec, u_prev if c == 0 else None, trust[c]
                    )
                except _SOLVE_ERRORS:  # a bad solve, not a bug: a failure
                    new, step = None, np.inf
                br_ms.append(1e3 * (time.perf_counter() - tb))
                if not np.isfinite(step):  # the QP failed: keep the plan
                    failures += 1
                    change = np.inf
                    continue
                change = max(change, step)
                if c == 0:
                    ego_ok = True  # the IBR car's own QP worked
                if new is None:  # no better: a shorter step next
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
        self.last = {
            "rounds": rounds,
            "converged": converged,
            "changes": changes,
            "ms": ms,
            "br_ms": br_ms,
            "br_failures": failures,
            "br_rejected": rejected,
            "fallback": fallback,
            "plans": np.stack([p.X for p in plans]),
            "inputs": np.stack([p.U for p in plans]),
        }
        if isinstance(self.vehicle, FullSizeParams):  # the prediction's throttle share
            import math

            v = self.vehicle
            u0 = np.array(u0, dtype=float)
            u0[0] = limited_throttle(
                v, float(u0[0]), float(states[0, 3]), math, float(states[0, 5])
            )
        return u0
