"""Environment speed: PettingZoo env steps/s for N = 1, 2, 3, 4, 8 cars, and batched car-steps/s.

    python benchmarks/env_speed.py            # about a minute
    python benchmarks/env_speed.py --quick    # a few seconds, for a smoke check

Cars are driven by a trivial lane keeper (a few arithmetic operations on the observation:
steer back to the centre line, hold 2 m/s), so they race at realistic speed instead of
parking against a wall. Two figures per N: the throughput of ``env.step`` alone (the
environment's cost) and of the whole loop including the agents. Baseline: f1tenth_gym,
measured on this machine class at under 900 env steps/s with 2 cars and about 200/s with 4.
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np

from racing_env import BatchedRaces, RaceConfig, RacingParallelEnv

F1TENTH_STEPS_PER_S = {2: 900.0, 4: 200.0}


def lane_keeper(obs: np.ndarray, preview_col: int) -> np.ndarray:
    """Normalised actions (..., 2) from observations (..., D): hold 2 m/s, keep to the centre."""
    n, mu, vx, kappa = obs[..., 1], obs[..., 2], obs[..., 3], obs[..., preview_col]
    a = np.empty(obs.shape[:-1] + (2,), dtype=np.float32)
    a[..., 0] = np.clip(0.8 * (2.0 - vx) + 0.15, -1.0, 1.0)
    a[..., 1] = np.clip((0.062 * kappa - 3.0 * n - 1.5 * mu) / 0.35, -1.0, 1.0)
    return a


def bench_pettingzoo(n_cars: int, steps: int) -> tuple[float, float]:
    """(env.step calls per second, whole-loop steps per second)."""
    env = RacingParallelEnv(n_cars=n_cars, max_cycles=steps + 10, start="grid")
    obs, _ = env.reset(seed=0)
    col = 6 * n_cars
    for _ in range(20):  # warm-up (JIT, caches)
        obs, *_ = env.step({a: lane_keeper(o, col) for a, o in obs.items()})
    env.reset(seed=0)
    t_env = 0.0
    t0 = time.perf_counter()
    for _ in range(steps):
        actions = {a: lane_keeper(o, col) for a, o in obs.items()}
        t1 = time.perf_counter()
        obs, *_ = env.step(actions)
        t_env += time.perf_counter() - t1
    total = time.perf_counter() - t0
    return steps / t_env, steps / total


def bench_batched(n_races: int, n_cars: int, steps: int, threads: int) -> tuple[float, float]:
    """(car-steps per second of BatchedRaces.step, mean RK4 sub-steps)."""
    numba.set_num_threads(threads)
    races = BatchedRaces(
        "default", RaceConfig(n_cars=n_cars, max_cycles=10**6), n_races=n_races, seed=0
    )
    obs = races.reset()
    col = 6 * n_cars
    for _ in range(5):
        obs, *_ = races.step(lane_keeper(obs, col))
    t_step, subs = 0.0, 0.0
    for _ in range(steps):
        a = lane_keeper(obs, col)
        t1 = time.perf_counter()
        obs, *_ = races.step(a)
        t_step += time.perf_counter() - t1
        subs += races.substeps.mean()
    return n_races * n_cars * steps / t_step, subs / steps


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short runs (smoke check)")
    args = ap.parse_args(argv)
    steps = 500 if args.quick else 5000
    print(f"PettingZoo ParallelEnv, default track, {steps} steps, lane-keeping agents, 1 thread")
    print(f"{'cars':>4} {'env.step/s':>11} {'loop steps/s':>13} {'vs f1tenth_gym':>15}")
    numba.set_num_threads(1)
    for n in (1, 2, 3, 4, 8):
        env_rate, loop_rate = bench_pettingzoo(n, steps)
        ratio = f"{env_rate / F1TENTH_STEPS_PER_S[n]:.0f}x" if n in F1TENTH_STEPS_PER_S else "-"
        print(f"{n:>4} {env_rate:>11.0f} {loop_rate:>13.0f} {ratio:>15}")
    n_races = 256 if args.quick else 2048
    bsteps = 20 if args.quick else 100
    print(f"\nBatchedRaces, {n_races} races x 3 cars, {bsteps} steps")
    print(f"{'threads':>7} {'car-steps/s':>12} {'mean RK4 sub-steps':>19}")
    for threads in sorted({1, numba.config.NUMBA_NUM_THREADS}):
        rate, subs = bench_batched(n_races, 3, bsteps, threads)
        print(f"{threads:>7} {rate:>12.0f} {subs:>19.2f}")


if __name__ == "__main__":
    main()
