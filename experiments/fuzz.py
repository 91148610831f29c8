"""Random-action fuzz of the simulator (``alpha-racer fuzz``).

Drives batches of races with random actions, held for a random number of steps (so full
throttle at full lock happens as well as jitter), from every start mode, and with random
restarts. After every step it checks that no state is NaN or infinite and that every state
stays inside the documented envelope (:meth:`BatchedRaces.state_bounds`). Any exception or
violation ends the run with a report naming the race, car, step and state.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from racing_env import BatchedRaces, RaceConfig, StartConfig


@dataclass
class FuzzReport:
    steps: int = 0                 # race steps done (each advances every car of one race)
    car_steps: int = 0
    seconds: float = 0.0
    problems: list[str] = field(default_factory=list)
    maxima: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.problems

    def text(self) -> str:
        lines = [f"fuzz: {self.steps} race steps ({self.car_steps} car-steps) in {self.seconds:.1f} s: "
                 + ("OK, no NaN, no exception, all states within bounds" if self.ok else "FAILED")]
        lines += [f"  extreme |{k}|: {v:.4g}" for k, v in self.maxima.items()]
        lines += [f"  problem: {p}" for p in self.problems[:20]]
        return "\n".join(lines)


def run_fuzz(steps: int = 1_000_000, n_races: int = 256, n_cars: int = 3, track: str = "default",
             seed: int = 0, hold_max: int = 20, progress_bar: bool = True) -> FuzzReport:
    """Fuzz ``steps`` race steps in batches of ``n_races``; see the module docstring."""
    if steps < 1 or n_races < 1:
        raise ValueError(f"steps and races must be positive, got {steps}, {n_races}")
    rng = np.random.default_rng(seed)
    races = BatchedRaces(track, RaceConfig(n_cars=n_cars, max_cycles=500), n_races=n_races, seed=seed)
    lo, hi = races.state_bounds()
    modes = ["regions", "grid", "random"]
    for b in range(n_races):
        races.reset(races=[b], start=StartConfig(mode=modes[b % 3], speed=float(rng.uniform(0, 3))))
    action = rng.uniform(-1, 1, (n_races, n_cars, 2))
    hold = rng.integers(1, hold_max, (n_races, n_cars))
    names = ["s", "n", "mu", "vx", "vy", "omega"]
    extreme = np.zeros(6)
    report = FuzzReport()
    t0 = time.perf_counter()
    with tqdm(total=steps, desc="fuzz", unit="step", unit_scale=True, delay=2.0,
              disable=not progress_bar) as bar:
        while report.steps < steps:
            hold -= 1
            redraw = hold <= 0
            if redraw.any():
                k = int(redraw.sum())
                fresh = rng.uniform(-1, 1, (k, 2))
                saturate = rng.random((k, 2)) < 0.3
                fresh[saturate] = np.sign(fresh[saturate])
                action[redraw] = fresh
                hold[redraw] = rng.integers(1, hold_max, k)
            try:
                races.step(action)
            except Exception as exc:  # report, do not crash the fuzz
                report.problems.append(f"exception at step {report.steps}: {exc!r}")
                break
            st = races.state
            bad = ~np.isfinite(st) | (st < lo) | (st > hi)
            if bad.any():
                b, i, j = np.argwhere(bad)[0]
                report.problems.append(f"race {b} car {i} step {races.t[b]}: {names[j]} = {st[b, i, j]} "
                                       f"outside [{lo[j]}, {hi[j]}]; state {st[b, i].tolist()}")
                break
            extreme = np.maximum(extreme, np.abs(st).max(axis=(0, 1)))
            done = races.truncated()
            if done.any():
                for b in np.flatnonzero(done):
                    races.reset(races=[b], start=StartConfig(mode=modes[int(rng.integers(3))],
                                                             speed=float(rng.uniform(0, 3))))
            report.steps += n_races
            bar.update(n_races)
    report.car_steps = report.steps * n_cars
    report.seconds = time.perf_counter() - t0
    report.maxima = {n: float(v) for n, v in zip(names[1:], extreme[1:])}
    return report
