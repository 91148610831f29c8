"""Environment speed: PettingZoo env steps/s for N = 1, 2, 3, 4, 8 cars, and batched car-steps/s;
the full-size class (Monza, wake on) next to the ORCA class in the same run.

    python benchmarks/env_speed.py            # about a minute
    python benchmarks/env_speed.py --quick    # a few seconds, for a smoke check

Cars are driven by a trivial lane keeper (a few arithmetic operations on the observation:
steer back to the centre line, hold 2 m/s), so they race at realistic speed instead of
parking against a wall. Two figures per N: the throughput of ``env.step`` alone (the
environment's cost) and of the whole loop including the agents. Baseline: f1tenth_gym,
measured on this machine class at under 900 env steps/s with 2 cars and about 200/s with 4.
The full-size cars (``vehicle_class="fullsize"``: Monza at full scale, the wake on) are driven
by the same lane keeper at their scale (up to 40 m/s, braking for the previewed corners). It
cannot drive Monza's first chicane (8.6 m radius), so both classes race 25 s episodes from a
standing start in that table (at Monza: the start, the main straight at 40 m/s, the braking
for the chicane); the ratio is ORCA env.step/s over full-size env.step/s (goal: at most 1.5).
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


def lane_keeper_fullsize(obs: np.ndarray, preview_col: int, preview_ds: float) -> np.ndarray:
    """The lane keeper at full size: up to 40 m/s, at most 0.7 g in the previewed corners
    (braking at 0.6 g towards each), steering feed-forward on the 3 m wheelbase, lateral gain
    over the width ratio."""
    n, mu, vx = obs[..., 1], obs[..., 2], obs[..., 3]
    kappa = obs[..., preview_col]
    prev = np.abs(obs[..., preview_col:])
    dist = preview_ds * np.arange(prev.shape[-1])
    corner = 0.7 * 9.81 / np.maximum(prev, 1e-6)  # v^2 in each previewed corner
    target = np.minimum(40.0, np.sqrt((corner + 2.0 * 0.6 * 9.81 * dist).min(axis=-1)))
    a = np.empty(obs.shape[:-1] + (2,), dtype=np.float32)
    a[..., 0] = np.clip(0.3 * (target - vx), -1.0, 1.0)
    a[..., 1] = np.clip((3.0 * kappa - 0.09 * n - 1.5 * mu) / 0.35, -1.0, 1.0)
    return a


def bench_pettingzoo(
    n_cars: int, steps: int, vehicle_class: str = "orca", episode: int | None = None
) -> tuple[float, float, float]:
    """(env.step calls per second, whole-loop steps per second, mean RK4 sub-steps); with
    ``episode``, the race restarts (untimed) every that many steps."""
    env = RacingParallelEnv(
        n_cars=n_cars, max_cycles=steps + 10, start="grid", vehicle_class=vehicle_class
    )
    if vehicle_class == "orca":
        keeper = lane_keeper
    else:
        ds = env.config.preview_ds
        keeper = lambda o, c: lane_keeper_fullsize(o, c, ds)  # noqa: E731
    obs, _ = env.reset(seed=0)
    col = 6 * n_cars
    for _ in range(20):  # warm-up (JIT, caches)
        obs, *_ = env.step({a: keeper(o, col) for a, o in obs.items()})
    obs, _ = env.reset(seed=0)
    t_env, subs = 0.0, 0.0
    t0 = time.perf_counter()
    for k in range(steps):
        if episode and k and k % episode == 0:
            t1 = time.perf_counter()
            obs, _ = env.reset(seed=k)
            t0 += time.perf_counter() - t1
        actions = {a: keeper(o, col) for a, o in obs.items()}
        t1 = time.perf_counter()
        obs, *_ = env.step(actions)
        t_env += time.perf_counter() - t1
        subs += env.core.substeps.mean()
    total = time.perf_counter() - t0
    return steps / t_env, steps / total, subs / steps


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
        env_rate, loop_rate, _ = bench_pettingzoo(n, steps)
        ratio = f"{env_rate / F1TENTH_STEPS_PER_S[n]:.0f}x" if n in F1TENTH_STEPS_PER_S else "-"
        print(f"{n:>4} {env_rate:>11.0f} {loop_rate:>13.0f} {ratio:>15}")
    print(
        f"\nFull-size class (Monza, wake 1) against ORCA (default track), {steps} steps, "
        f"25 s episodes"
    )
    print(
        f"{'cars':>4} {'ORCA env.step/s':>16} {'full-size':>10} {'ORCA/full-size':>15} "
        f"{'RK4 sub-steps (ORCA, full)':>27}"
    )
    for n in (1, 3, 8):
        orca, _, sub_o = bench_pettingzoo(n, steps, episode=250)
        full, _, sub_f = bench_pettingzoo(n, steps, vehicle_class="fullsize", episode=250)
        print(
            f"{n:>4} {orca:>16.0f} {full:>10.0f} {orca / full:>15.2f} {sub_o:>16.2f} {sub_f:>10.2f}"
        )
    n_races = 256 if args.quick else 2048
    bsteps = 20 if args.quick else 100
    print(f"\nBatchedRaces, {n_races} races x 3 cars, {bsteps} steps")
    print(f"{'threads':>7} {'car-steps/s':>12} {'mean RK4 sub-steps':>19}")
    for threads in sorted({1, numba.config.NUMBA_NUM_THREADS}):
        rate, subs = bench_batched(n_races, 3, bsteps, threads)
        print(f"{threads:>7} {rate:>12.0f} {subs:>19.2f}")


if __name__ == "__main__":
    main()
