"""Lockstep races: races per second of ``alpha-racer collect``'s races run one by one and in
lockstep batches (:mod:`experiments.infra.lockstep`), measured back to back in one process,
and where the time goes.

    python benchmarks/lockstep_speed.py                 # 2 x 8 races of 500 steps per path, ~3 min
    python benchmarks/lockstep_speed.py --steps 50      # a smoke check

The same races (the paper's collection: 3 MPC cars, races 1..R of seed 0) are run by each
path: one by one (:func:`experiments.potential.collect.simulate_race`, one
``RacingParallelEnv`` per race), first with every MPC solving step by step from Python (the
baseline: the path before the compiled solve) and then in one compiled call per decision
(:mod:`agents.mpc.compiled_solve`), and in lockstep batches of 4 and 8
(:func:`experiments.potential.collect.simulate_races`, one ``BatchedRaces`` core per batch,
every period's MPC steps of all cars in one call: ``MPCAgent.act_group``, on ``--threads`` threads);
the states of every path are checked equal bit for bit. The paths take turns for ``--rounds``
rounds (the machine's load shifts alike on each). Printed per path: races/s, the ratio
to the baseline, and the seconds per race in the agents' decisions (``act``, ``act_group``),
in the core's step (kernel and observations, ``BatchedRaces.step``), in the agents' resets
and in the rest (glue: the env's dicts, the runner's bookkeeping, the seeds and thetas).
``--threads 1`` measures the batches on one thread (a collection worker's setting; default:
the machine's cores).
"""

from __future__ import annotations

import argparse
import os
import time
from collections import Counter
from contextlib import nullcontext

from collect_speed import _Timed  # the sibling benchmark's timer (benchmarks/ runs as scripts)


def run_path(
    config, races: list[int], batch: int | None, python: bool = False
) -> tuple[float, Counter, list]:
    """Wall seconds to run ``races`` one by one (``batch`` None) or in lockstep batches of
    ``batch`` (with ``python``, every MPC solving from Python); the seconds in the decisions
    (act, act_group), core step and resets; the races' states."""
    from agents.mpc import stepwise_solves
    from agents.mpc_agent import MPCAgent
    from experiments.potential.collect import simulate_race, simulate_races
    from racing_env import BatchedRaces

    totals: Counter = Counter()
    with (
        stepwise_solves() if python else nullcontext(),
        _Timed(MPCAgent, "act", "act", totals),
        _Timed(MPCAgent, "act_group", "act", totals),
        _Timed(MPCAgent, "reset", "reset", totals),
        _Timed(BatchedRaces, "step", "step", totals),
    ):
        t0 = time.perf_counter()
        if batch is None:
            out = [simulate_race(config, i) for i in races]
        else:
            out = []
            for k in range(0, len(races), batch):
                out += simulate_races(config, races[k : k + batch])
        wall = time.perf_counter() - t0
    return wall, totals, [r["states"] for r in out]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--races", type=int, default=8, help="races per path (default 8)")
    parser.add_argument("--steps", type=int, default=500, help="steps per race (default 500)")
    parser.add_argument("--rounds", type=int, default=2, help="rounds over the paths (default 2)")
    parser.add_argument(
        "--threads", type=int, default=os.cpu_count() or 1, help="the batches' threads"
    )
    args = parser.parse_args()
    if min(args.races, args.steps, args.rounds, args.threads) < 1:
        raise SystemExit(
            f"--races, --steps, --rounds and --threads must be positive, got {args.races}, "
            f"{args.steps}, {args.rounds}, {args.threads}"
        )

    import numpy as np

    from agents.threads import limited_threads
    from experiments.potential.collect import CollectConfig, simulate_races

    config = CollectConfig(races=args.races + 1, steps=args.steps)
    races = list(range(1, args.races + 1))
    paths = {  # name: (batch, python solve)
        "one by one, python solve": (None, True),
        "one by one": (None, False),
        "lockstep 4": (4, False),
        "lockstep 8": (8, False),
    }
    base_name = next(iter(paths))
    with limited_threads(args.threads):
        simulate_races(config, [0] * 8)  # compiles, builds and resets the 24 agents
        print(
            f"{args.races} races of {args.steps} steps (3 MPC cars) per path and round, "
            f"{args.rounds} rounds"
        )
        print(
            f"{'path':25s} {'races/s':>8s} {'ratio':>6s} {'s/race:':>8s} {'act':>6s} "
            f"{'step':>6s} {'reset':>6s} {'glue':>6s}"
        )
        walls: dict[str, float] = dict.fromkeys(paths, 0.0)
        parts: dict[str, Counter] = {name: Counter() for name in paths}
        ref = None
        for _ in range(args.rounds):  # the paths interleaved, round after round
            for name, (batch, python) in paths.items():
                wall, t, states = run_path(config, races, batch, python)
                ref = ref or states
                if not all(np.array_equal(a, b) for a, b in zip(ref, states)):
                    raise SystemExit(f"{name}: the races differ from {base_name}'s")
                walls[name] += wall
                parts[name].update(t)
        n = args.races * args.rounds
        base = n / walls[base_name]
        for name in paths:
            t, wall = parts[name], walls[name]
            glue = wall - t["act"] - t["step"] - t["reset"]
            print(
                f"{name:25s} {n / wall:8.3f} {n / wall / base:5.2f}x {'':8s} {t['act'] / n:6.3f} "
                f"{t['step'] / n:6.3f} {t['reset'] / n:6.3f} {glue / n:6.3f}"
            )


if __name__ == "__main__":
    main()
