"""Data collection speed: seconds per race of ``alpha-racer collect`` in one process, for the
paper's collection (baseline) and the extended space's close races, and where the time goes.

    python benchmarks/collect_speed.py             # 6 races per collection, about a minute
    python benchmarks/collect_speed.py --races 2   # a smoke check

Each race is :func:`experiments.potential.collect.simulate_race` (3 MPC cars, 500 steps), the unit a
collection worker runs; a collection of R races on W cores takes about R x s/race / W (a
little more when both cores race: they share memory bandwidth and turbo). Printed per
collection: seconds per race, the ratio to the paper's collection, the projected minutes for
4000 races on 2 workers against the 45-minute goal, and the share of the MPC's decision time
spent in its compiled SQP steps and plan rollouts (the horizon predictions with and without
Jacobians, with their merit checks: :func:`agents.mpc.solver.sqp_step` and ``MPC._plan``) and
in DAQP's QPs.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

GOAL_MIN = 45.0
CONFIGS = {
    "paper (baseline)": {},
    "extended, close": {"space": "extended", "start": "close", "pace": "close"},
}


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


def seconds_per_race(config, races: int) -> tuple[float, Counter]:
    """Mean seconds per race over ``races`` races (after one warm-up race), and the seconds
    spent in the MPC's decisions, compiled SQP steps and plan rollouts, and QPs during them."""
    import daqp

    import agents.mpc.solver as solver
    from agents.mpc_agent import MPCAgent
    from experiments.potential.collect import simulate_race

    simulate_race(config, 0)  # compiles and caches everything
    totals: Counter = Counter()
    with (
        _Timed(MPCAgent, "act", "decisions", totals),
        _Timed(solver, "sqp_step", "sqp", totals),
        _Timed(solver.MPC, "_plan", "sqp", totals),
        _Timed(daqp, "solve", "qp", totals),
    ):
        t0 = time.perf_counter()
        for i in range(1, races + 1):
            simulate_race(config, i)
        wall = time.perf_counter() - t0
    return wall / races, totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--races", type=int, default=6, help="races timed per collection")
    args = parser.parse_args()
    if args.races < 1:
        raise SystemExit(f"--races must be a positive integer, got {args.races}")

    from agents.threads import single_blas_thread
    from experiments.potential.collect import CollectConfig

    print(
        f"{'collection':18s} {'s/race':>7s} {'ratio':>6s} {'4000 on 2 cores':>16s} "
        f"{'in SQP steps':>13s} {'in QPs':>7s}"
    )
    base = None
    with single_blas_thread():
        for name, kw in CONFIGS.items():
            s, t = seconds_per_race(CollectConfig(races=args.races + 1, **kw), args.races)
            base = base or s
            minutes = 4000 * s / 2 / 60
            flag = "" if minutes <= GOAL_MIN else f" (goal {GOAL_MIN:g})"
            dec = t["decisions"] or 1.0
            print(
                f"{name:18s} {s:7.2f} {s / base:5.2f}x {minutes:12.1f} min{flag} "
                f"{100 * t['sqp'] / dec:12.0f}% {100 * t['qp'] / dec:6.0f}%"
            )


if __name__ == "__main__":
    main()
