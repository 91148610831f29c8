"""MPC speed and quality: the RTI-SQP MPC (agents.mpc.MPC) against IPOPT on the same problem.

    python benchmarks/mpc_speed.py            # about a minute
    python benchmarks/mpc_speed.py --quick    # a smoke check
    python benchmarks/mpc_speed.py --quality-only --config sqp_iterations=2 curvature_passes=0
                                              # the plan quality of another MPCConfig

Both solve the same MPC (K = 15, 3 RK4 sub-steps per stage, same cost and soft constraints) in
closed loop on the default track, warm-started from their previous solution:

1. solo: one car, a flying start, 250 steps: solve times, lap times (the RTI's second lap
   against IPOPT's, which is solved to convergence, tol 1e-8) and track-limit violations;
2. race: three cars from the paper's start regions, all driven by the solver under test, each
   with two opponents (separation constraints active), 300 steps: solve times of all cars.

3. plan quality: one car driven by the RTI at the limit (zeta = 1), every 5th state of a
   50 s solo race: the cost of the RTI's plan (its nonlinear rollout, the MPC's own
   objective with the soft rows' penalty) against IPOPT's optimum of the same problem (the
   better of IPOPT started from the RTI's plan and from the follower's rollout), both costed
   on the same rollout model. The goal: within 5% in 90% of the states. ``--config`` sets
   fields of the :class:`MPCConfig` of both solvers here (IPOPT ignores the RTI's iteration
   settings, so they still solve the same problem).

Also prints the env step time beside the MPC time. One core (numba threads = 1).
"""
from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import fields

import numba
import numpy as np

from agents.mpc import MPC, MPCConfig
from agents.mpc_agent import joint_state_from_observation, progress_rate
from agents.mpc_ipopt import IpoptMPC
from agents.reference import Theta, reference_trajectory
from racing_env import RacingParallelEnv, StartConfig
from racing_env.raceline import get_raceline

THETA = Theta(q=20.0, zeta=0.9, s1=0.1, s2=4.0, s3=1.0)


def closed_loop(solvers, n_cars, steps, start):
    """Drive ``n_cars`` cars, car i with solvers[i]; returns (env, env step seconds list)."""
    env = RacingParallelEnv(n_cars=n_cars, max_cycles=steps, start=start)
    obs, _ = env.reset(seed=0)
    track = env.track
    rl = get_raceline(track)
    u_prev = [np.zeros(2) for _ in range(n_cars)]
    env_s = []
    while env.agents:
        actions = {}
        for i, agent in enumerate(env.possible_agents):
            ego, others = joint_state_from_observation(obs[agent], n_cars)
            ref = reference_trajectory(THETA, ego, others if len(others) else None, rl, track)
            opp = None
            nb = [j for j in (ref.ahead, ref.behind) if j >= 0]
            if nb:
                o = others[nb]
                opp = np.column_stack([o[:, 0], o[:, 1], progress_rate(o, track)])
            u_prev[i] = solvers[i].solve(ego, ref.s_ref, ref.n_ref, THETA.q, opp, u_prev[i])
            actions[agent] = u_prev[i].astype(np.float32)
        t0 = time.perf_counter()
        obs, _, _, _, info = env.step(actions)
        env_s.append(time.perf_counter() - t0)
    return env, env_s, info


def plan_quality(track, steps: int, every: int, theta: Theta, config: MPCConfig | None = None):
    """Cost ratios RTI / IPOPT - 1 (array) at every ``every``-th state of a solo race; the RTI
    with ``config`` (default :class:`MPCConfig`)."""
    env = RacingParallelEnv(n_cars=1, max_cycles=steps, start=StartConfig(mode="grid"))
    obs, _ = env.reset(seed=0)
    rl = get_raceline(env.track)
    rti, ipopt = MPC(env.track, config=config), IpoptMPC(env.track, config=config)
    u_prev, gaps = np.zeros(2), []
    for k in range(steps):
        ego, _ = joint_state_from_observation(obs["car_0"], 1)
        ref = reference_trajectory(theta, ego, None, rl, env.track)
        u = rti.solve(ego, ref.s_ref, ref.n_ref, theta.q, None, u_prev)
        if k % every == 0 and k > 0:
            U_rti, J_rti = rti.last_plan
            X_rti = rti.last_prediction
            nodes = np.concatenate([[ego[0]], X_rti[0]])
            costs = []
            for U0 in (U_rti, rti._follower_warm_start(ego)):
                X0 = np.column_stack([ego, rti._plan(ego, U0, s_prev=nodes, jacobians=False)[0]])
                ipopt.solve(ego, ref.s_ref, ref.n_ref, theta.q, None, u_prev, init=(X0, U0))
                if getattr(ipopt, "last_U", None) is not None:
                    Xi = rti._plan(ego, ipopt.last_U, s_prev=nodes, jacobians=False)[0]
                    costs.append(rti._merit(Xi, ipopt.last_U, ref.s_ref, ref.n_ref, theta.q,
                                            np.zeros((0, 3))))
            if costs and np.isfinite(J_rti):
                gaps.append(J_rti / max(min(costs), 1e-12) - 1.0)
        u_prev = u
        obs, _, _, _, _ = env.step({"car_0": u.astype(np.float32)})
    return np.array(gaps)


def summary(ms):
    ms = np.asarray(ms)
    return np.median(ms), np.percentile(ms, 99)


def parse_config(pairs) -> MPCConfig:
    """An :class:`MPCConfig` from ``KEY=VALUE`` strings, KEY a numeric field (value parsed as
    the field's type)."""
    default = MPCConfig()
    numeric = {f.name: type(getattr(default, f.name)) for f in fields(MPCConfig)
               if type(getattr(default, f.name)) in (int, float)}
    kw = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key not in numeric:
            raise SystemExit(f"--config takes KEY=VALUE with KEY one of {sorted(numeric)}, "
                             f"got {pair!r}")
        kw[key] = numeric[key](value)
    return MPCConfig(**kw)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--quality-only", action="store_true",
                    help="only part 3, the plan quality against IPOPT")
    ap.add_argument("--config", nargs="*", default=[], metavar="KEY=VALUE",
                    help="MPCConfig fields of both solvers in the plan-quality part")
    args = ap.parse_args(argv)
    config = parse_config(args.config)
    warnings.simplefilter("ignore")
    numba.set_num_threads(1)
    track = RacingParallelEnv(n_cars=1).track
    if args.quality_only:
        return report_quality(track, args.quick, config)
    solo_steps, race_steps = (120, 60) if args.quick else (250, 300)
    print(f"MPC: K = 15, dt = 0.1 s, default track; solo {solo_steps} steps, race {race_steps} steps")
    print(f"{'solver':<8} {'scenario':<8} {'median ms':>9} {'p99 ms':>7} {'laps s':<18} {'off-track':>9} {'fallbacks':>9}")  # noqa: E501
    closed_loop([MPC(track) for _ in range(3)], 3, 30, StartConfig(mode="regions"))   # warm-up (JIT, caches)
    med = {}
    laps = {}
    for name, make in (("RTI", lambda: MPC(track)), ("IPOPT", lambda: IpoptMPC(track))):
        solver = make()
        env, env_s, info = closed_loop([solver], 1, solo_steps, StartConfig(mode="grid", speed=2.0))
        m, p = summary(list(solver.stats["solve_ms"])[3:])
        lt = np.diff([0.0] + env.core.lap_times[0][0])
        laps[name] = lt
        print(f"{name:<8} {'solo':<8} {m:>9.3f} {p:>7.3f} {str(np.round(lt, 3)):<18} "
              f"{info['car_0']['off_tracks']:>9} {solver.stats['fallbacks']:>9}")
        solvers = [make(), make(), make()]
        env, env_s, info = closed_loop(solvers, 3, race_steps, StartConfig(mode="regions"))
        m, p = summary(np.concatenate([list(s.stats["solve_ms"])[3:] for s in solvers]))
        med[name] = m
        print(f"{name:<8} {'race':<8} {m:>9.3f} {p:>7.3f} {'-':<18} "
              f"{int(env.core.offtracks[0].sum()):>9} {sum(s.stats['fallbacks'] for s in solvers):>9}")
        if name == "RTI":
            print(f"{'':<8} env step with 3 MPC cars: {1e3 * np.median(env_s):.3f} ms median")
    print(f"\nRTI is {med['IPOPT'] / med['RTI']:.0f}x faster than IPOPT (median, race scenario)")
    report_quality(track, args.quick, config)
    if len(laps["RTI"]) > 1 and len(laps["IPOPT"]) > 1:
        gap = laps["RTI"][1] / laps["IPOPT"][1] - 1.0
        print(f"flying lap: RTI {laps['RTI'][1]:.3f} s vs converged IPOPT {laps['IPOPT'][1]:.3f} s "
              f"({100 * gap:+.2f} %)")


def report_quality(track, quick: bool, config: MPCConfig) -> None:
    """Print part 3: the RTI's plan cost against IPOPT's at zeta = 1."""
    gaps = plan_quality(track, 150 if quick else 500, 5,
                        Theta(q=THETA.q, zeta=1.0, s1=THETA.s1, s2=THETA.s2, s3=THETA.s3), config)
    if gaps.size:
        changed = {f.name: getattr(config, f.name) for f in fields(MPCConfig)
                   if getattr(config, f.name) != getattr(MPCConfig(), f.name)}
        print(f"\nplan cost, RTI {changed or '(default MPCConfig)'} against IPOPT on the same "
              f"problem ({gaps.size} states of a solo race at zeta = 1): within 5% in "
              f"{100 * np.mean(gaps <= 0.05):.0f}% of them, median {100 * np.median(gaps):+.2f}%, "
              f"p90 {100 * np.percentile(gaps, 90):+.2f}%")


if __name__ == "__main__":
    main()
