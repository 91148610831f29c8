"""Each driver alone on a track: progress, best flying lap, off-track steps, MPC restarts.

    python benchmarks/solo_laps.py                                   # the README's table
    python benchmarks/solo_laps.py --tracks oval --agents mpc:zeta=1.0 raceline --steps 300

One car from the grid (seed 0) for ``--steps`` control periods of 0.1 s; the racing line's
lap estimate (its speed profile at the nominal envelope scale) is printed beside each track,
so the closed-loop laps can be compared with it, and the lap-time line's too when a driver
races it (``mpc:line=lap_time``, ``raceline:line=lap_time``).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from agents import make_agent_spec
from experiments.evaluation.policy_map import DEFAULT_TRACKS
from racing_env import RacingParallelEnv
from racing_env.raceline import RacelineConfig, get_raceline

AGENTS = [
    "mpc:zeta=1.0",
    "mpc:zeta=1.02",
    "mpc:zeta=1.05",
    "mpc:zeta=1.02,q=60",
    "mpc",
    "ibr",
    "ppo",
    "raceline",
]
TRACKS = list(DEFAULT_TRACKS)  # the policy map's, so its best thetas compare with these drivers


def solo(spec: str, track: str, steps: int, seed: int = 0) -> dict:
    """Race agent ``spec`` alone on ``track`` from the grid; returns its figures."""
    env = RacingParallelEnv(track=track, n_cars=1, max_cycles=steps, start="grid")
    obs, _ = env.reset(seed=seed)
    agent = make_agent_spec(spec)
    agent.reset(env.track, "car_0", seed)
    t_act = 0.0
    while env.agents:
        t0 = time.perf_counter()
        action = agent.act(obs["car_0"])
        t_act += time.perf_counter() - t0
        obs, _, _, _, _ = env.step({"car_0": action})
    core = env.core
    laps = np.diff([0.0] + core.lap_times[0][0])
    stats = getattr(agent, "stats", {}) or {}
    return {
        "progress": float(core.state[0, 0, 0] - core.s_line[0]),
        "best_lap": float(laps[1:].min()) if len(laps) > 1 else float("nan"),
        "off_track": int(core.offtracks[0][0]),
        "restarts": stats.get("restarts", "-"),
        "ms": 1e3 * t_act / steps,
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tracks", nargs="+", default=TRACKS)
    ap.add_argument("--agents", nargs="+", default=AGENTS)
    ap.add_argument("--steps", type=int, default=500)
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    for track in args.tracks:
        extra = ""
        if any("line=lap_time" in spec for spec in args.agents):
            fast = get_raceline(track, config=RacelineConfig(objective="lap_time"))
            extra = f", lap-time line {fast.lap_time:.2f} s"
        print(f"{track}: racing-line lap estimate {get_raceline(track).lap_time:.2f} s{extra}")
        print(
            f"  {'driver':<18} {'progress m':>10} {'best lap s':>10} {'off-track':>9} "
            f"{'restarts':>8} {'ms/decision':>11}"
        )
        for spec in args.agents:
            r = solo(spec, track, args.steps)
            print(
                f"  {spec:<18} {r['progress']:>10.2f} {r['best_lap']:>10.2f} "
                f"{r['off_track']:>9} {r['restarts']!s:>8} {r['ms']:>11.2f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
