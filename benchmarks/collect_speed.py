"""Data collection speed: seconds per race of ``alpha-racer collect`` in one process, for the
paper's collection and the extended space's close races, by path, and where the time goes.

    python benchmarks/collect_speed.py             # 8 races per collection and path, ~3 min
    python benchmarks/collect_speed.py --races 2   # a smoke check

The same races (3 MPC cars, 500 steps) are run by three paths, back to back:

* ``per race, python solve`` (the baseline: the path before the compiled solve): each race
  :func:`experiments.potential.collect.simulate_race` in its own env, every MPC solving step
  by step from Python (``MPC.compiled_solves = False``);
* ``per race``: the same, every solve in one compiled call (:mod:`agents.mpc.compiled_solve`);
* ``lockstep``: the races in one batch (:func:`experiments.potential.collect.simulate_races`,
  what a collection worker runs per shard), every period's MPC steps of all cars in one
  compiled call on one thread (a worker's setting).

The races of every path are checked equal bit for bit. Printed per collection and path:
seconds per race, the speed-up over the baseline (its s/race over the path's), the projected minutes for 4000 races on 2
workers against the 15-minute goal, and the share of the decision time in the compiled
predictions, SQP steps and QPs (baseline only: :func:`agents.mpc.solver.sqp_step` and
``MPC._plan``, the horizon predictions with their merit checks, and DAQP's QPs, timed from
Python). A collection of R races on W cores takes about R x s/race / W (a little more when
both cores race: they share memory bandwidth and turbo).
"""

from __future__ import annotations

import argparse
import time
from collections import Counter
from contextlib import nullcontext

GOAL_MIN = 15.0
CONFIGS = {
    "paper": {},
    "extended, close": {"space": "extended", "start": "close", "pace": "close"},
}
PATHS = ("per race, python solve", "per race", "lockstep")


class _Timed:
    """Wrap ``owner.name`` so that its calls add their seconds to ``totals[key]``."""

    def __init__(self, owner, name: str, key: str, totals: Counter):
        self.owner, self.name, self.f = owner, name, getattr(owner, name)
        self.key, self.totals = key, totals

    def __enter__(self):
        f, key, totals = self.f, self.key, self.totals

        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return f(*args, **kwargs)
            finally:
                totals[key] += time.perf_counter() - t0

        setattr(self.owner, self.name, timed)
        return self

    def __exit__(self, *exc):
        setattr(self.owner, self.name, self.f)


def run_path(config, races: list[int], path: str) -> tuple[float, Counter, list]:
    """Wall seconds per race of ``races`` run by ``path`` (:data:`PATHS`), the seconds in the
    decisions, compiled SQP steps and plan rollouts, and QPs (the baseline's), and the
    races' states."""
    import daqp

    import agents.mpc.solver as solver
    from agents.mpc import stepwise_solves
    from agents.mpc_agent import MPCAgent
    from experiments.potential.collect import simulate_race, simulate_races

    totals: Counter = Counter()
    with (
        stepwise_solves() if path == PATHS[0] else nullcontext(),
        _Timed(MPCAgent, "act", "decisions", totals),
        _Timed(solver, "sqp_step", "sqp", totals),
        _Timed(solver.MPC, "_plan", "sqp", totals),
        _Timed(daqp, "solve", "qp", totals),
    ):
        t0 = time.perf_counter()
        if path == "lockstep":
            out = simulate_races(config, races)
        else:
            out = [simulate_race(config, i) for i in races]
        wall = time.perf_counter() - t0
    return wall / len(races), totals, [r["states"] for r in out]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--races", type=int, default=8, help="races per collection and path")
    args = parser.parse_args()
    if args.races < 1:
        raise SystemExit(f"--races must be a positive integer, got {args.races}")

    import numpy as np

    from agents.threads import limited_threads
    from experiments.potential.collect import CollectConfig, simulate_races

    print(
        f"{'collection':16s} {'path':23s} {'s/race':>7s} {'ratio':>6s} {'4000 on 2 cores':>16s} "
        f"{'in SQP steps':>13s} {'in QPs':>7s}"
    )
    races = list(range(1, args.races + 1))
    with limited_threads(1):  # a collection worker's setting
        for name, kw in CONFIGS.items():
            config = CollectConfig(races=args.races + 1, **kw)
            simulate_races(config, [0])  # compiles and caches everything
            base, ref = None, None
            for path in PATHS:
                s, t, states = run_path(config, races, path)
                ref = ref or states
                if not all(np.array_equal(a, b) for a, b in zip(ref, states)):
                    raise SystemExit(f"{name}, {path}: the races differ from the baseline's")
                base = base or s
                minutes = 4000 * s / 2 / 60
                flag = "" if minutes <= GOAL_MIN else f" (goal {GOAL_MIN:g})"
                dec = t["decisions"]
                shares = (
                    f"{100 * t['sqp'] / dec:12.0f}% {100 * t['qp'] / dec:6.0f}%"
                    if path == PATHS[0] and dec
                    else ""
                )
                print(
                    f"{name:16s} {path:23s} {s:7.2f} {base / s:5.2f}x {minutes:12.1f} min{flag} "
                    f"{shares}"
                )


if __name__ == "__main__":
    main()
