"""MPC speed and quality: the RTI-SQP MPC (agents.mpc.MPC) against IPOPT on the same problem.

    python benchmarks/mpc_speed.py            # about a minute
    python benchmarks/mpc_speed.py --quick    # a smoke check
    python benchmarks/mpc_speed.py --quality-only --config sqp_iterations=2 curvature_passes=0
                                              # the plan quality of another MPCConfig
    python benchmarks/mpc_speed.py --quality-only --line curvature --quality-steps 100
                                              # a shorter plan-quality check, one line
    python benchmarks/mpc_speed.py --quality-only --config step_damping=1,10,100 sqp_iterations=20
                                              # damped SQP steps (opt-in): 94% in traffic
    python benchmarks/mpc_speed.py --quality-only --vehicle-class fullsize --line curvature
                                              # the full-size MPC on Monza (slip rows too)

Both solve the same MPC (K = 15, 3 RK4 sub-steps per stage, same cost and soft constraints) in
closed loop on the default track, warm-started from their previous solution:

1. solo: one car, a flying start, 250 steps: solve times, lap times (the RTI's second lap
   against IPOPT's, which is solved to convergence, tol 1e-8) and track-limit violations;
2. race: three cars from the paper's start regions, all driven by the solver under test, each
   with two opponents (separation constraints active), 300 steps: solve times of all cars.

3. plan quality: at every 5th state, the cost of the RTI's plan against IPOPT's optimum of
   the same problem (same state, reference and opponents; the better of IPOPT started from
   the RTI's plan and from the follower's rollout). Both plans are costed the same way
   (:func:`rollout_cost`: the nonlinear rollout with the curvature along the plan's own
   progress, and the MPC's objective on it with the soft rows' penalty). Solo: one car at
   the limit (zeta = 1), 500 steps; traffic: two 3-car races from the paper's start regions
   at the top of the policy box (:data:`TRAFFIC_RACES`), every car driven by the RTI and
   every car's plan compared, 300 steps each. Both along the curvature line and along the
   lap-time line (``--line``). Prints the share of states within 5%, the median and the 90th
   percentile of the relative excess, and the RTI's solve times in those races. The goal:
   within 5% in 90% of the states. ``--config`` sets fields of the :class:`MPCConfig` of
   both solvers here (IPOPT ignores the RTI's iteration settings, so they still solve the
   same problem).

Also prints the env step time beside the MPC time. One core (numba threads = 1).
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import fields, replace

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


def rollout_cost(rti: MPC, x0, U, s_ref, n_ref, q: float, opp) -> float:
    """The cost of inputs ``U`` (2, K) from state ``x0``, the same for every solver's plan: the
    nonlinear rollout with the curvature looked up along the plan's own progress (three
    passes from a constant-speed guess) and the MPC's objective on it (tracking, input rates,
    the soft rows' quadratic penalty for the track edges and the separations chosen along the
    rollout; :meth:`MPC._score`)."""
    K, dt = rti.cfg.horizon, rti.cfg.dt
    nodes = x0[0] + max(float(x0[3]), 0.5) * dt * np.arange(K + 1)
    X = rti._plan(x0, U, s_prev=nodes, jacobians=False, passes=3)[0]
    return rti._merit(X, np.asarray(U, dtype=float), s_ref, n_ref, q, opp)


def plan_quality(
    track,
    steps: int,
    every: int,
    thetas,
    config: MPCConfig | None = None,
    line: str = "curvature",
    seed: int = 0,
    start: str = "grid",
    vehicle_class: str = "orca",
):
    """``(gaps, solve_ms, failed)``: the relative excess cost RTI / IPOPT - 1 (array) of every car's plan at every
    ``every``-th state of a race of ``len(thetas)`` cars, car i driven by the RTI (``config``,
    default :class:`MPCConfig`) with ``thetas[i]`` along racing line ``line``. IPOPT solves the
    same problem (same state, reference, opponents) from the RTI's plan and from the
    follower's rollout, and the better of the two is its optimum; both solvers' plans are
    costed by :func:`rollout_cost`; and the RTI's solve times [ms] (all cars, after the first
    three solves of each); ``failed``: the compared states where neither IPOPT start
    converged (left out of ``gaps``). ``vehicle_class``: the env's (full size: ``track`` a circuit
    name, the start regions at the car's size, the wake on; the reference in the car's
    lengths)."""
    from racing_env.controllers import raceline_config_for

    n_cars = len(thetas)
    env = RacingParallelEnv(
        track=track, n_cars=n_cars, max_cycles=steps, start=start, vehicle_class=vehicle_class
    )
    obs, _ = env.reset(seed=seed)
    car = env.config.vehicle
    rl = get_raceline(env.track, car, raceline_config_for(car, line))
    rtis = [MPC(env.track, config=config, line=line) for _ in range(n_cars)]
    ipopt = IpoptMPC(env.track, config=config)
    ref_vehicle = None if vehicle_class == "orca" else car
    u_prev = [np.zeros(2) for _ in range(n_cars)]
    gaps = []
    failed = 0  # compared states where no IPOPT start converged
    for k in range(steps):
        if not env.agents:
            break
        actions = {}
        for i, agent in enumerate(env.possible_agents):
            theta, rti = thetas[i], rtis[i]
            ego, others = joint_state_from_observation(obs[agent], n_cars)
            ref = reference_trajectory(
                theta, ego, others if len(others) else None, rl, env.track, vehicle=ref_vehicle
            )
            opp = np.zeros((0, 3))
            nb = [j for j in (ref.ahead, ref.behind) if j >= 0]
            if nb:
                o = others[nb]
                opp = np.column_stack([o[:, 0], o[:, 1], progress_rate(o, env.track)])
            u = rti.solve(ego, ref.s_ref, ref.n_ref, theta.q, opp if len(opp) else None, u_prev[i])
            if k % every == 0 and k > 0 and rti.last_status == "ok":
                U_rti = rti.last_plan[0]
                J_rti = rollout_cost(rti, ego, U_rti, ref.s_ref, ref.n_ref, theta.q, opp)
                costs = []
                for U0 in (U_rti, rti._follower_warm_start(ego)):
                    nodes = ego[0] + max(float(ego[3]), 0.5) * rti.cfg.dt * np.arange(
                        rti.cfg.horizon + 1
                    )
                    X0 = np.column_stack(
                        [ego, rti._plan(ego, U0, s_prev=nodes, jacobians=False, passes=3)[0]]
                    )
                    ipopt.solve(
                        ego,
                        ref.s_ref,
                        ref.n_ref,
                        theta.q,
                        opp if len(opp) else None,
                        u_prev[i],
                        init=(X0, U0),
                    )
                    if ipopt.last_U is not None:
                        costs.append(
                            rollout_cost(rti, ego, ipopt.last_U, ref.s_ref, ref.n_ref, theta.q, opp)
                        )
                if costs and np.isfinite(J_rti):
                    gaps.append(J_rti / max(min(costs), 1e-12) - 1.0)
                elif not costs:
                    failed += 1
            u_prev[i] = u
            actions[agent] = u.astype(np.float32)
        obs, _, _, _, _ = env.step(actions)
    solve_ms = np.concatenate([list(r.stats["solve_ms"])[3:] for r in rtis])
    return np.array(gaps), solve_ms, failed


SOLO_THETA = Theta(q=THETA.q, zeta=1.0, s1=THETA.s1, s2=THETA.s2, s3=THETA.s3)
"""The solo plan-quality race's theta: the default agent's at the limit (zeta = 1)."""
TRAFFIC_RACES = (
    (
        0,
        (
            Theta(q=5.0, zeta=1.05, s1=0.3, s2=0.5, s3=0.0),
            Theta(q=10.0, zeta=1.0, s1=0.3, s2=1.0, s3=5.0),
            Theta(q=20.0, zeta=1.05, s1=0.3, s2=0.75, s3=2.5),
        ),
    ),
    (
        1,
        (
            Theta(q=20.0, zeta=1.0, s1=0.3, s2=1.0, s3=0.0),
            Theta(q=5.0, zeta=1.05, s1=0.3, s2=0.75, s3=5.0),
            Theta(q=10.0, zeta=1.05, s1=0.3, s2=0.5, s3=2.5),
        ),
    ),
)
"""(seed, thetas) of the 3-car plan-quality races: the top of the policy box (zeta 1-1.05,
s1 0.3, small s2), from the paper's start regions, so that the cars race close together."""


def summary(ms):
    ms = np.asarray(ms)
    return np.median(ms), np.percentile(ms, 99)


def parse_config(pairs) -> MPCConfig:
    """An :class:`MPCConfig` from ``KEY=VALUE`` strings, KEY a numeric, boolean or tuple field
    (value parsed as the field's type; a boolean from 1/0, true/false; a tuple of numbers
    comma-separated, ``step_damping=0.1,1,10``)."""
    default = MPCConfig()
    numeric = {
        f.name: type(getattr(default, f.name))
        for f in fields(MPCConfig)
        if type(getattr(default, f.name)) in (int, float, bool, tuple)
    }
    kw = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key not in numeric:
            raise SystemExit(
                f"--config takes KEY=VALUE with KEY one of {sorted(numeric)}, got {pair!r}"
            )
        if numeric[key] is bool:
            if value.lower() not in ("1", "0", "true", "false"):
                raise SystemExit(f"--config {key} takes 1/0 or true/false, got {value!r}")
            kw[key] = value.lower() in ("1", "true")
        elif numeric[key] is tuple:
            try:
                kw[key] = tuple(float(v) for v in value.split(",") if v)
            except ValueError:
                raise SystemExit(
                    f"--config {key} takes comma-separated numbers, got {value!r}"
                ) from None
        else:
            kw[key] = numeric[key](value)
    try:
        return MPCConfig(**kw)
    except ValueError as exc:
        raise SystemExit(f"--config: {exc}") from None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument(
        "--quality-only", action="store_true", help="only part 3, the plan quality against IPOPT"
    )
    ap.add_argument(
        "--config",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="MPCConfig fields of both solvers in the plan-quality part",
    )
    ap.add_argument(
        "--line",
        choices=("curvature", "lap_time", "both"),
        default="both",
        help="racing line(s) of the plan-quality races (default both)",
    )
    ap.add_argument(
        "--quality-steps",
        type=int,
        default=None,
        metavar="N",
        help="steps of every plan-quality race (default 500 solo, 300 traffic)",
    )
    ap.add_argument(
        "--vehicle-class",
        choices=("orca", "fullsize"),
        default="orca",
        help="the plan-quality races' class (fullsize: with --quality-only, on --track)",
    )
    ap.add_argument(
        "--track",
        default=None,
        help="the plan-quality races' track (default: default; tumftm:Monza at full size)",
    )
    args = ap.parse_args(argv)
    lines = ("curvature", "lap_time") if args.line == "both" else (args.line,)
    config = parse_config(args.config)
    warnings.simplefilter("ignore")
    numba.set_num_threads(1)
    if args.vehicle_class != "orca":
        if not args.quality_only:
            raise SystemExit(
                "--vehicle-class fullsize measures the plan quality only: add --quality-only"
            )
        name = args.track or "tumftm:Monza"
        return report_quality(
            name, args.quick, config, lines, args.quality_steps, args.vehicle_class
        )
    track = RacingParallelEnv(n_cars=1, track=args.track or "default").track
    if args.quality_only:
        return report_quality(track, args.quick, config, lines, args.quality_steps)
    solo_steps, race_steps = (120, 60) if args.quick else (250, 300)
    print(
        f"MPC: K = 15, dt = 0.1 s, default track; solo {solo_steps} steps, race {race_steps} steps"
    )
    print(
        f"{'solver':<8} {'scenario':<8} {'median ms':>9} {'p99 ms':>7} {'laps s':<18} {'off-track':>9} {'fallbacks':>9}"
    )  # noqa: E501
    closed_loop(
        [MPC(track) for _ in range(3)], 3, 30, StartConfig(mode="regions")
    )  # warm-up (JIT, caches)
    med = {}
    laps = {}
    for name, make in (("RTI", lambda: MPC(track)), ("IPOPT", lambda: IpoptMPC(track))):
        solver = make()
        env, env_s, info = closed_loop([solver], 1, solo_steps, StartConfig(mode="grid", speed=2.0))
        m, p = summary(list(solver.stats["solve_ms"])[3:])
        lt = np.diff([0.0] + env.core.lap_times[0][0])
        laps[name] = lt
        print(
            f"{name:<8} {'solo':<8} {m:>9.3f} {p:>7.3f} {str(np.round(lt, 3)):<18} "
            f"{info['car_0']['off_tracks']:>9} {solver.stats['fallbacks']:>9}"
        )
        solvers = [make(), make(), make()]
        env, env_s, info = closed_loop(solvers, 3, race_steps, StartConfig(mode="regions"))
        m, p = summary(np.concatenate([list(s.stats["solve_ms"])[3:] for s in solvers]))
        med[name] = m
        print(
            f"{name:<8} {'race':<8} {m:>9.3f} {p:>7.3f} {'-':<18} "
            f"{int(env.core.offtracks[0].sum()):>9} {sum(s.stats['fallbacks'] for s in solvers):>9}"
        )
        if name == "RTI":
            print(f"{'':<8} env step with 3 MPC cars: {1e3 * np.median(env_s):.3f} ms median")
    print(f"\nRTI is {med['IPOPT'] / med['RTI']:.0f}x faster than IPOPT (median, race scenario)")
    report_quality(track, args.quick, config, lines, args.quality_steps)
    if len(laps["RTI"]) > 1 and len(laps["IPOPT"]) > 1:
        gap = laps["RTI"][1] / laps["IPOPT"][1] - 1.0
        print(
            f"flying lap: RTI {laps['RTI'][1]:.3f} s vs converged IPOPT {laps['IPOPT'][1]:.3f} s "
            f"({100 * gap:+.2f} %)"
        )


def report_quality(
    track,
    quick: bool,
    config: MPCConfig,
    lines=("curvature", "lap_time"),
    steps: int | None = None,
    vehicle_class: str = "orca",
) -> None:
    """Print part 3: the RTI's plan cost against IPOPT's, alone at zeta = 1 and in 3-car
    races at the top of the box, along each racing line of ``lines``. At full size the top
    of the box is at zeta = 1 (at 1.05 the full-size MPC leaves the track; docs "Full-size
    racing", passes): every traffic theta's zeta capped at 1."""
    traffic = TRAFFIC_RACES
    if vehicle_class != "orca":
        traffic = tuple(
            (seed, tuple(replace(th, zeta=min(th.zeta, 1.0)) for th in thetas))
            for seed, thetas in TRAFFIC_RACES
        )
    changed = {
        f.name: getattr(config, f.name)
        for f in fields(MPCConfig)
        if getattr(config, f.name) != getattr(MPCConfig(), f.name)
    }
    solo_steps = steps or (150 if quick else 500)
    race_steps = steps or (100 if quick else 300)
    print(
        f"\nplan cost, RTI {changed or '(default MPCConfig)'} against IPOPT on the same "
        f"problem, both costed on the same rollout: every 5th state; solo {solo_steps} "
        f"steps at zeta = 1, traffic {len(traffic)} races of 3 cars x {race_steps} "
        f"steps at the top of the box, class {vehicle_class}"
    )
    print(
        f"{'line':<10} {'scenario':<8} {'states':>6} {'within 5%':>9} {'median':>8} "
        f"{'p90':>8} {'solve median ms':>15} {'p99 ms':>7} {'IPOPT failed':>13}"
    )
    for line in lines:
        runs = {
            "solo": [
                plan_quality(
                    track, solo_steps, 5, (SOLO_THETA,), config, line, vehicle_class=vehicle_class
                )
            ],
            "traffic": [
                plan_quality(
                    track, race_steps, 5, thetas, config, line, seed, "regions", vehicle_class
                )
                for seed, thetas in traffic
            ],
        }
        for scenario, results in runs.items():
            gaps = np.concatenate([g for g, _, _ in results])
            ms = np.concatenate([t for _, t, _ in results])
            failed = sum(f for _, _, f in results)
            if not gaps.size:
                continue
            m, p = summary(ms)
            print(
                f"{line:<10} {scenario:<8} {gaps.size:>6} {100 * np.mean(gaps <= 0.05):>8.0f}% "
                f"{100 * np.median(gaps):>+7.2f}% {100 * np.percentile(gaps, 90):>+7.1f}% "
                f"{m:>15.3f} {p:>7.3f} {failed:>13}"
            )


if __name__ == "__main__":
    main()
