"""One driver alone on a full-size circuit in the env: off-track steps, lap times against the
racing line's estimate, and the MPC's solve time beside the ORCA class's on the same circuit
at 1/43.

    python benchmarks/fullsize_solo_lap.py                          # mpc:zeta=1.0 on Monza
    python benchmarks/fullsize_solo_lap.py --spec raceline --track tumftm:Spa

The car starts from the grid (a standing start), so the first lap includes the launch; the
following laps are flying ones and the best is compared with the racing line's estimate.
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
        "solve_ms_median": round(float(stats.get("solve_ms_median", float("nan"))), 3),
        "restarts": stats.get("restarts", "-"),
        "fallbacks": stats.get("fallbacks", "-"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default="mpc:zeta=1.0")
    ap.add_argument("--track", default="tumftm:Monza")
    ap.add_argument("--steps", type=int, default=3200, help="control periods at full size")
    ap.add_argument("--orca-steps", type=int, default=600, help="0: no ORCA comparison")
    args = ap.parse_args()
    v = FullSizeParams()
    track = make_track(args.track, vehicle_class="fullsize")
    est = get_raceline(track, v, raceline_config_for(v)).lap_time
    full = solo_env(args.spec, args.track, args.steps, "fullsize")
    flying = full["laps"][1:]
    gap = f"{100 * (min(flying) / est - 1):+.1f}%" if flying else "no flying lap"
    print(f"full size, {args.spec} on {args.track}: {full}")
    print(f"  racing line's lap estimate {est:.2f} s; best flying lap vs estimate: {gap}")
    if args.orca_steps:
        orca = solo_env(args.spec, args.track, args.orca_steps, "orca")
        ratio = full["solve_ms_median"] / orca["solve_ms_median"]
        print(f"ORCA (1/43), {args.orca_steps} steps: {orca}")
        print(f"  median MPC solve, full size / ORCA: {ratio:.2f}")


if __name__ == "__main__":
    main()
