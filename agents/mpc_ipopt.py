"""The same MPC as :class:`agents.mpc.MPC`, solved to convergence by IPOPT.

The baseline of ``benchmarks/mpc_speed.py`` and the "fully converged" reference for the RTI's
closed-loop quality: multiple shooting over the same RK4 stage model, the same cost (tracking
with ``Q = q I`` on stages 1..K, input-rate cost with ``R = I``), the same input, steering-rate
and (soft, quadratically penalised slack) track and separation constraints, warm-started
from the previous solution. It takes the same arguments and returns the same action.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Any

import numpy as np

from racing_env.track import Track
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams, vehicle_for_track

from .mpc import (
    EdgeBounds,
    MPCConfig,
    kappa_at_substeps,
    opponent_paths,
    separation_choice,
    stage_function,
)
from .mpc.config import class_scale, config_for_vehicle, slip_bound


class IpoptMPC:
    """IPOPT solve of the MPC; ``solve(x0, s_ref, n_ref, q, opponents, u_prev)`` like :class:`MPC`.

    The car is ``vehicle``, else the track's class's default car, as for :class:`MPC`. For
    the full-size class the problem is the full-size MPC's: the config's lengths scaled to
    the car, position errors and soft violations in ORCA-car widths, and soft bounds on the
    rear and front slip angles of the predicted states (:func:`agents.mpc.qp.slip_rows`;
    here as slacks, so every soft row is charged ``v^2 / (2 rho)``, as the full-size MPC's
    ``exact_soft`` QP and the merit charge it)."""

    def __init__(
        self,
        track: Track,
        vehicle: VehicleParams | FullSizeParams | None = None,
        config: MPCConfig | None = None,
        max_opponents: int = 2,
        tol: float = 1e-8,
    ):
        import casadi as ca

        self.track = track
        self.vehicle = v = vehicle_for_track(track, vehicle, "IpoptMPC")
        self.cfg = cfg = config_for_vehicle(config or MPCConfig(), v)
        ls2 = class_scale(v)[1] ** 2  # 1 for the ORCA car
        slip_max, slip_max_f, slip_scale, l_f, l_r, delta_max, v_low = slip_bound(cfg, v)
        n_slip = 2 * cfg.horizon if slip_max > 0.0 else 0
        K, m = cfg.horizon, cfg.substeps
        stage = stage_function(v, cfg)
        X = ca.MX.sym("X", 6, K + 1)
        U = ca.MX.sym("U", 2, K)
        S_track = ca.MX.sym("St", K)
        S_sep = ca.MX.sym("Ss", max_opponents * K)
        S_slip = ca.MX.sym("Sa", n_slip)
        P_x0 = ca.MX.sym("x0", 6)
        P_ref = ca.MX.sym("ref", 2, K)
        P_kap = ca.MX.sym("kap", m, K)
        P_q = ca.MX.sym("q")
        P_uprev = ca.MX.sym("uprev", 2)
        P_nlo = ca.MX.sym("nlo", K)
        P_nhi = ca.MX.sym("nhi", K)
        # separation rows: coefficient on s, on n, and the bound: cs*s + cn*n >= b
        P_sep = ca.MX.sym("sep", 3, max_opponents * K)
        g, lbg, ubg = [X[:, 0] - P_x0], [np.zeros(6)], [np.zeros(6)]
        for k in range(K):
            xn = stage(X[:, k], U[:, k], P_kap[:, k])[0]
            g.append(X[:, k + 1] - xn)
            lbg.append(np.zeros(6))
            ubg.append(np.zeros(6))
        rate = v.delta_rate_max * cfg.dt / v.delta_max
        dsteer = ca.horzcat(U[1, 0] - P_uprev[1], U[1, 1:] - U[1, :-1])
        g.append(dsteer.T)
        lbg.append(-rate * np.ones(K))
        ubg.append(rate * np.ones(K))
        n_pred = X[1, 1:].T
        g.append(n_pred - P_nlo + S_track)
        lbg.append(np.zeros(K))
        ubg.append(np.full(K, np.inf))
        g.append(P_nhi - n_pred + S_track)
        lbg.append(np.zeros(K))
        ubg.append(np.full(K, np.inf))
        s_pred = X[0, 1:]
        for r in range(max_opponents):
            for k in range(K):
                col = r * K + k
                g.append(
                    P_sep[0, col] * s_pred[k]
                    + P_sep[1, col] * n_pred[k]
                    - P_sep[2, col]
                    + S_sep[col]
                )
                lbg.append(np.zeros(1))
                ubg.append(np.full(1, np.inf))
        for k in range(n_slip // 2):  # |slip angle| <= bound, in metres (slip_scale per rad)
            x = X[:, k + 1]  # the state at the end of the stage that U[:, k] steers
            w_v = ca.sqrt(x[3] ** 2 + v_low**2)
            a_r = ca.atan((x[5] * l_r - x[4]) / w_v)
            a_f = delta_max * U[1, k] - ca.atan((x[5] * l_f + x[4]) / w_v)
            for a, bound, col in ((a_r, slip_max, k), (a_f, slip_max_f, K + k)):
                g.append(S_slip[col] + slip_scale * (bound - a))
                g.append(S_slip[col] + slip_scale * (bound + a))
                lbg += [np.zeros(1), np.zeros(1)]
                ubg += [np.full(1, np.inf), np.full(1, np.inf)]
        err = X[:2, 1:] - P_ref
        du = U[:, 1:] - U[:, :-1]
        # DAQP's quadratic penalty of soft rows, 1 / (2 rho) with rho = cfg.soft_rho_at(q), and
        # the tracking weight q, both in ORCA-car widths (MPC._problem; ls2 = 1 for ORCA)
        w_soft = 0.5 / cfg.soft_rho * ca.fmax(1.0, P_q / cfg.soft_q_ref)
        soft = ca.sumsqr(S_track) + ca.sumsqr(S_sep)
        if n_slip:
            soft = soft + ca.sumsqr(S_slip)
        cost = (P_q / ls2) * ca.sumsqr(err) + ca.sumsqr(du) + (w_soft / ls2) * soft
        w = ca.vertcat(ca.vec(X), ca.vec(U), S_track, S_sep, S_slip)
        p = ca.vertcat(
            P_x0, ca.vec(P_ref), ca.vec(P_kap), P_q, P_uprev, P_nlo, P_nhi, ca.vec(P_sep)
        )
        nlp = {"x": w, "p": p, "f": cost, "g": ca.vertcat(*g)}
        opts: dict[str, bool | int | float | str] = {
            "expand": True,
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.tol": tol,
            "ipopt.sb": "yes",
            "ipopt.warm_start_init_point": "yes",
            "ipopt.max_iter": 500,
        }
        self._solver = ca.nlpsol("mpc_ipopt", "ipopt", nlp, opts)
        self._lbg = np.concatenate([np.atleast_1d(a) for a in lbg])
        self._ubg = np.concatenate([np.atleast_1d(a) for a in ubg])
        nx, nu = 6 * (K + 1), 2 * K
        n_slack = K + max_opponents * K + n_slip
        self._lbw = np.concatenate([np.full(nx, -np.inf), np.full(nu, -1.0), np.zeros(n_slack)])
        self._ubw = np.concatenate(
            [np.full(nx, np.inf), np.full(nu, 1.0), np.full(n_slack, np.inf)]
        )
        self._n_slack = n_slack
        self._nx, self._nu, self._m = nx, nu, max_opponents
        self._bounds_n = EdgeBounds(track, v, cfg)
        self.stats: dict[str, Any] = {
            "solves": 0,
            "fallbacks": 0,
            "solve_ms": deque(maxlen=100_000),
        }
        self.reset()

    def reset(self) -> None:
        self._w0: np.ndarray | None = None  # the last solution, the next warm start
        self.last_U: np.ndarray | None = None
        self.last_cost = float("nan")  # the NLP's objective at the last solution

    def solve(
        self,
        x0: np.ndarray,
        s_ref: np.ndarray,
        n_ref: np.ndarray,
        q: float,
        opponents: np.ndarray | None = None,
        u_prev: np.ndarray | None = None,
        init: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """Like :meth:`MPC.solve`; ``init = (X (6, K + 1), U (2, K))`` replaces the warm start
        by an explicit initial guess (states from ``x0`` on). ``last_U`` (2, K) holds the plan,
        ``None`` after a failed solve, and ``last_cost`` its objective."""
        t0 = time.perf_counter()
        cfg, K = self.cfg, self.cfg.horizon
        x0 = np.asarray(x0, dtype=float)
        u_prev = np.zeros(2) if u_prev is None else np.asarray(u_prev, dtype=float)
        if init is not None:
            X0, U0 = (np.array(a, dtype=float) for a in init)
        elif self._w0 is None:
            U0 = np.zeros((2, K))
            X0 = np.tile(x0[:, None], (1, K + 1))
            X0[0] = x0[0] + max(x0[3], 0.5) * cfg.dt * np.arange(K + 1)
        else:
            Xp = self._w0[: self._nx].reshape(K + 1, 6).T
            Up = self._w0[self._nx : self._nx + self._nu].reshape(K, 2).T
            X0 = np.concatenate([Xp[:, 1:], Xp[:, -1:]], axis=1)
            X0[:, 0] = x0
            U0 = np.concatenate([Up[:, 1:], Up[:, -1:]], axis=1)
        kap = kappa_at_substeps(self.track, X0[0], cfg.substeps)  # X0 is already shifted to now
        nlo, nhi = self._bounds_n(X0[0, 1:])
        sep = np.zeros((3, self._m * K))
        sep[2] = -1e3  # inactive rows
        if opponents is not None:
            for r, path in enumerate(opponent_paths(opponents, K, cfg.dt)[: self._m]):
                near, lat, sign, s_jk, n_jk = separation_choice(X0[0, 1:], X0[1, 1:], path, cfg)
                cols = slice(r * K, (r + 1) * K)
                sep[0, cols] = np.where(near & ~lat, sign, 0.0)
                sep[1, cols] = np.where(near & lat, sign, 0.0)
                sep[2, cols] = np.where(
                    near, np.where(lat, cfg.sep_n + sign * n_jk, cfg.sep_s + sign * s_jk), -1e3
                )
        p = np.concatenate(
            [
                x0,
                np.column_stack([s_ref, n_ref]).ravel(),
                kap.T.ravel(),
                [q],
                u_prev,
                nlo,
                nhi,
                sep.T.ravel(),
            ]
        )
        w0 = np.concatenate([X0.T.ravel(), U0.T.ravel(), np.zeros(self._n_slack)])
        sol = self._solver(x0=w0, p=p, lbx=self._lbw, ubx=self._ubw, lbg=self._lbg, ubg=self._ubg)
        ok = self._solver.stats()["success"]
        w = np.asarray(sol["x"]).ravel()
        self.stats["solves"] += 1
        self.stats["solve_ms"].append(1e3 * (time.perf_counter() - t0))
        if not ok or not np.isfinite(w).all():
            self.stats["fallbacks"] += 1
            self._w0 = None
            self.last_U = None
            return np.array([0.0, u_prev[1]])
        self._w0 = w
        self.last_U = w[self._nx : self._nx + self._nu].reshape(K, 2).T.copy()
        self.last_cost = float(sol["f"])
        return w[self._nx : self._nx + 2].copy()
