"""One driver alone on a full-size circuit in the env: off-track steps, lap times against the
racing line's estimate, and the MPC's solve time beside the ORCA class's on the same circuit
at 1/43.

    python benchmarks/fullsize_solo_lap.py                          # mpc:zeta=1.0 on Monza
    python benchmarks/fullsize_solo_lap.py --spec raceline --track tumftm:Spa
    python benchmarks/fullsize_solo_lap.py --spec mpc:zeta=1.0 raceline \
        --track tumftm:Monza tumftm:Spa --steps 3200 4200             # a table

The car starts from the grid (a standing start), so the first lap includes the launch; the
second lap is a flying one and is compared with the racing line's estimate (the gap in the
table); the ORCA class's median solve time on the same circuit at 1/43 is beside the MPC's.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from agents import make_agent_spec
from racing_env.controllers import raceline_config_for
from racing_env.raceline import get_raceline
from racing_env.tracks import make_track
from racing_env.vehicles import FullSizeParams


def solo_env(spec: str, track: str, steps: int, vehicle_class: str = "orca") -> dict:
    """Race ``spec`` alone on ``track`` in the env of ``vehicle_class`` from the grid (a
    standing start) for ``steps`` periods: lap times (the first from the standing start, the
    others flying), off-track steps and decision times."""
    from racing_env import RacingParallelEnv

    env = RacingParallelEnv(
        track=track, n_cars=1, max_cycles=steps, start="grid", vehicle_class=vehicle_class
    )
    obs, _ = env.reset(seed=0)
    agent = make_agent_spec(spec)
    agent.reset(env.track, "car_0", 0)
    times = []
    while env.agents:
        t0 = time.perf_counter()
        a = agent.act(obs["car_0"])
        times.append(time.perf_counter() - t0)
        obs, *_ = env.step({"car_0": a})
    core = env.core
    laps = np.diff([0.0] + list(core.lap_times[0][0]))
    stats = getattr(agent, "stats", {}) or {}
    return {
        "laps": [round(float(t), 2) for t in laps],
        "off_track": int(core.offtracks[0][0]),
        "progress": round(float(core.state[0, 0, 0] - core.s_line[0]), 1),
        "act_ms_median": round(1e3 * float(np.median(times)), 3),
        # "-" for a driver without a solver (the follower): no NaN in the table
        **{
            k: round(float(stats[k]), 3) if k in stats else "-"
            for k in ("solve_ms_median", "solve_ms_p99")
        },
        "restarts": stats.get("restarts", "-"),
        "fallbacks": stats.get("fallbacks", "-"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", nargs="+", default=["mpc:zeta=1.0"])
    ap.add_argument("--track", nargs="+", default=["tumftm:Monza"])
    ap.add_argument(
        "--steps",
        type=int,
        nargs="+",
        default=[3200],
        help="control periods at full size (one, or one per track): two laps and a bit",
    )
    ap.add_argument("--orca-steps", type=int, default=600, help="0: no ORCA comparison")
    args = ap.parse_args()
    v = FullSizeParams()
    steps = args.steps * len(args.track) if len(args.steps) == 1 else args.steps
    if len(steps) != len(args.track):
        ap.error("--steps takes one count, or one per track")
    rows = []
    for name, n_steps in zip(args.track, steps):
        track = make_track(name, vehicle_class="fullsize")
        est = get_raceline(track, v, raceline_config_for(v)).lap_time
        for spec in args.spec:
            full = solo_env(spec, name, n_steps, "fullsize")
            flying = full["laps"][1:]
            print(f"full size, {spec} on {name}: {full}", flush=True)
            orca_ms: float | str = "-"  # not measured (a follower, or --orca-steps 0)
            if args.orca_steps and spec.startswith("mpc"):
                orca = solo_env(spec, name, args.orca_steps, "orca")
                orca_ms = orca["solve_ms_median"]
                print(f"  ORCA (1/43), {args.orca_steps} steps: {orca}", flush=True)
            rows.append((name, spec, flying[0] if flying else None, est, full, orca_ms))
    print()
    print(
        "| circuit | driver | flying lap [s] | estimate [s] | gap | off-track steps "
        "| solve median / p99 [ms] | ORCA median [ms] |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, spec, lap, est, full, orca_ms in rows:
        gap = f"{100 * (lap / est - 1):+.1f}%" if lap else "no flying lap"
        lap_s = f"{lap:.2f}" if lap else "-"
        solve = f"{full['solve_ms_median']} / {full['solve_ms_p99']}"
        print(
            f"| {name} | {spec} | {lap_s} | {est:.2f} | {gap} | {full['off_track']} "
            f"| {solve} | {orca_ms} |"
        )


if __name__ == "__main__":
    main()
