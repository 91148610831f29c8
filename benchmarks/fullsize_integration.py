"""Integration error of the full-size car inside one 0.1 s control period.

For each manoeuvre a reference trajectory is integrated with RK4 at ``h = 0.1 ms`` (1000
sub-steps per period). From every reference state at a period start, one period is integrated
with the sub-step rule under test and compared with the reference's next state: the largest
such one-period error per state component is reported (and the error at the end of the
manoeuvre when the rule integrates the whole of it on its own).

    python benchmarks/fullsize_integration.py            # the table of the notes
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from racing_env.vehicles.fullsize import (
    FullSizeParams,
    _stiffness_nb,
    n_substeps_fullsize,
    rk4_fullsize,
)

DT = 0.1
REF_SUB = 1000


@dataclass(frozen=True)
class Manoeuvre:
    name: str
    x0: tuple
    d: float
    delta: float
    kappa: float
    seconds: float


def manoeuvres() -> list[Manoeuvre]:
    """The representative manoeuvres (the corner's throttle and steering were found by a scan:
    about 1 g at 45-50 m/s; more throttle there spins the car)."""
    g = 9.81
    return [
        Manoeuvre("acceleration from rest", (0, 0, 0, 0, 0, 0), 1.0, 0.0, 0.0, 10.0),
        Manoeuvre("braking from 80 m/s", (0, 0, 0, 80.0, 0, 0), -1.0, 0.0, 0.0, 8.0),
        Manoeuvre("1 g corner from 50 m/s", (0, 0, 0, 50.0, 0, 0), 0.3, 0.02, g / 50**2, 5.0),
        Manoeuvre("standing start, steering 0.1", (0, 0, 0, 0, 0, 0), 0.5, 0.1, 0.0, 5.0),
        Manoeuvre(
            "standing start, full throttle, steering 0.2 (spins)",
            (0, 0, 0, 0, 0, 0),
            1.0,
            0.2,
            0.0,
            5.0,
        ),
        Manoeuvre("step steer at 80 m/s", (0, 0, 0, 80.0, 0, 0), 0.0, 0.05, 0.0, 3.0),
    ]


def rule_substeps(vx: float, p: np.ndarray, rule: str) -> int:
    """Sub-steps of a named rule: ``"chosen"`` (n_substeps_fullsize), ``"stable"`` (the ORCA
    rule: stability only, at least 2) or ``"fixed:K"``."""
    if rule == "chosen":
        return int(n_substeps_fullsize(vx, p, DT, 1.0, 100))
    if rule == "stable":
        lam = _stiffness_nb(vx, p)
        return min(max(int(math.ceil(DT * lam / 2.5)), 2), 100)
    if rule.startswith("fixed:"):
        return int(rule.split(":")[1])
    raise ValueError(f"unknown rule {rule!r}")


def errors(man: Manoeuvre, rule: str, params: FullSizeParams | None = None) -> dict:
    """Largest one-period errors (s, n, vx, vy, omega) and the end error of a free run."""
    p = (params or FullSizeParams()).pack()
    periods = int(round(man.seconds / DT))
    ref = np.empty((periods + 1, 6))
    ref[0] = man.x0
    for k in range(periods):
        x = ref[k].copy()
        rk4_fullsize(x, man.d, man.delta, man.kappa, p, DT, REF_SUB)
        ref[k + 1] = x
    local = np.zeros(6)
    free = np.array(man.x0, dtype=float)
    n_max = 0
    for k in range(periods):
        x = ref[k].copy()
        n = rule_substeps(x[3], p, rule)
        n_max = max(n_max, n)
        rk4_fullsize(x, man.d, man.delta, man.kappa, p, DT, n)
        local = np.maximum(local, np.abs(x - ref[k + 1]))
        rk4_fullsize(free, man.d, man.delta, man.kappa, p, DT, rule_substeps(free[3], p, rule))
    return {
        "local": local,
        "end": np.abs(free - ref[-1]),
        "n_max": n_max,
        "end_state": ref[-1],
    }


def table(rules=("stable", "chosen")) -> str:
    rows = [
        "| manoeuvre | rule | sub-steps (max) | vx [m/s] | vy [m/s] | omega [rad/s] | s, n [m] "
        "| end of run: vx, s [m/s, m] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for man in manoeuvres():
        for rule in rules:
            e = errors(man, rule)
            loc, end = e["local"], e["end"]
            rows.append(
                f"| {man.name} | {rule} | {e['n_max']} | {loc[3]:.1e} | {loc[4]:.1e} | "
                f"{loc[5]:.1e} | {max(loc[0], loc[1]):.1e} | {end[3]:.1e}, {end[0]:.1e} |"
            )
    return "\n".join(rows)


if __name__ == "__main__":
    for man in manoeuvres():
        e = errors(man, "chosen")
        s = e["end_state"]
        print(
            f"{man.name}: end vx {s[3]:.2f} m/s, vy {s[4]:.3f}, omega {s[5]:.3f}, "
            f"a_y {s[3] * s[5] / 9.81:.2f} g"
        )
    print(table())
