"""Random-action fuzz of the simulator (``alpha-racer fuzz``).

Drives batches of races with random actions, held for a random number of steps (so full
throttle at full lock happens as well as jitter), from every start mode, and with random
restarts. After every step it checks that no state is NaN or infinite, that every state
stays inside the documented envelope (:meth:`BatchedRaces.state_bounds`), and that no car
drove through another (env v2): no two bodies overlap (``|ds| < contact_ds`` and
``|dn| < contact_dn``), and no pair that overlaps laterally at both ends of a step has
swapped places in it. Any exception or violation ends the run with a report naming the
race, car, step and state.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from racing_env import BatchedRaces, RaceConfig, StartConfig


@dataclass
class FuzzReport:
    steps: int = 0  # race steps done (each advances every car of one race)
    car_steps: int = 0
    seconds: float = 0.0
    problems: list[str] = field(default_factory=list)
    maxima: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.problems

    def text(self) -> str:
        lines = [
            f"fuzz: {self.steps} race steps ({self.car_steps} car-steps) in {self.seconds:.1f} s: "
            + (
                "OK, no NaN, no exception, all states within bounds, no car drove through another"
                if self.ok
                else "FAILED"
            )
        ]
        lines += [f"  extreme |{k}|: {v:.4g}" for k, v in self.maxima.items()]
        lines += [f"  problem: {p}" for p in self.problems[:20]]
        return "\n".join(lines)


def drive_through(
    before: np.ndarray, after: np.ndarray, length: float, c_ds: float, c_dn: float
) -> tuple[int, int, int, str] | None:
    """The first (race, car i, car j, what) of ``after`` (B, N, 6) whose bodies overlap, or
    that swapped places since ``before`` while laterally overlapping at both ends of the
    step; None if there is none. Distances along the track are wrapped."""
    s0, s1 = before[..., 0], after[..., 0]
    wrap = lambda d: (d + length / 2) % length - length / 2
    d0 = wrap(s0[:, :, None] - s0[:, None, :])  # (B, N, N) s_i - s_j
    d1 = wrap(s1[:, :, None] - s1[:, None, :])
    dn0 = np.abs(before[..., 1][:, :, None] - before[..., 1][:, None, :])
    dn1 = np.abs(after[..., 1][:, :, None] - after[..., 1][:, None, :])
    tol = 1e-7
    upper = np.triu(np.ones(d0.shape[1:], dtype=bool), 1)[None]
    overlap = upper & (np.abs(d1) < c_ds - tol) & (dn1 < c_dn - tol)
    near = (np.abs(d0) < 1.0) & (np.abs(d1) < 1.0)  # [m] (not half a lap apart)
    swapped = (
        upper & near & (dn0 < c_dn - tol) & (dn1 < c_dn - tol) & (np.sign(d0) * np.sign(d1) < 0)
    )
    for bad, what in (
        (overlap, "bodies overlap"),
        (swapped, "swapped places while overlapping laterally"),
    ):
        if bad.any():
            b, i, j = np.argwhere(bad)[0]
            return int(b), int(i), int(j), what
    return None


def run_fuzz(
    steps: int = 1_000_000,
    n_races: int = 256,
    n_cars: int = 3,
    track: str = "default",
    seed: int = 0,
    hold_max: int = 20,
    progress_bar: bool = True,
) -> FuzzReport:
    """Fuzz ``steps`` race steps in batches of ``n_races``; see the module docstring."""
    if steps < 1 or n_races < 1:
        raise ValueError(f"steps and races must be positive, got {steps}, {n_races}")
    rng = np.random.default_rng(seed)
    races = BatchedRaces(
        track, RaceConfig(n_cars=n_cars, max_cycles=500), n_races=n_races, seed=seed
    )
    lo, hi = races.state_bounds()
    rules = races.config.rules
    modes = ["regions", "grid", "random"]
    for b in range(n_races):
        races.reset(races=[b], start=StartConfig(mode=modes[b % 3], speed=float(rng.uniform(0, 3))))
    action = rng.uniform(-1, 1, (n_races, n_cars, 2))
    hold = rng.integers(1, hold_max, (n_races, n_cars))
    names = ["s", "n", "mu", "vx", "vy", "omega"]
    extreme = np.zeros(6)
    report = FuzzReport()
    t0 = time.perf_counter()
    with tqdm(
        total=steps, desc="fuzz", unit="step", unit_scale=True, delay=2.0, disable=not progress_bar
    ) as bar:
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
            before = races.state.copy()
            try:
                races.step(action)
            except Exception as exc:  # report, do not crash the fuzz
                report.problems.append(f"exception at step {report.steps}: {exc!r}")
                break
            st = races.state
            bad = ~np.isfinite(st) | (st < lo) | (st > hi)
            if bad.any():
                b, i, j = np.argwhere(bad)[0]
                report.problems.append(
                    f"race {b} car {i} step {races.t[b]}: {names[j]} = {st[b, i, j]} "
                    f"outside [{lo[j]}, {hi[j]}]; state {st[b, i].tolist()}"
                )
                break
            through = (
                drive_through(before, st, races.track.length, rules.contact_ds, rules.contact_dn)
                if rules.contact and n_cars > 1
                else None
            )
            if through is not None:
                b, i, j, what = through
                report.problems.append(
                    f"race {b} step {races.t[b]}: cars {i} and {j} {what}; "
                    f"before {before[b, [i, j]].tolist()}, "
                    f"after {st[b, [i, j]].tolist()}"
                )
                break
            extreme = np.maximum(extreme, np.abs(st).max(axis=(0, 1)))
            done = races.truncated()
            if done.any():
                for b in np.flatnonzero(done):
                    races.reset(
                        races=[b],
                        start=StartConfig(
                            mode=modes[int(rng.integers(3))], speed=float(rng.uniform(0, 3))
                        ),
                    )
            report.steps += n_races
            bar.update(n_races)
    report.car_steps = report.steps * n_cars
    report.seconds = time.perf_counter() - t0
    report.maxima = {n: float(v) for n, v in zip(names[1:], extreme[1:])}
    return report
