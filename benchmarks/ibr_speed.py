"""IBR decision time: 3 cars, 6 rounds, 2 s horizon, against the paper's 0.1 s budget.

    python benchmarks/ibr_speed.py            # a 300-step race, about a minute
    python benchmarks/ibr_speed.py --quick    # a smoke check (60 steps)
    python benchmarks/ibr_speed.py --all-ibr  # every car driven by its own IBR agent
    python benchmarks/ibr_speed.py --all-ibr --split  # and where a decision's time goes

One race on the default track from the paper's start regions: car_0 is the IBR agent
(``agents.ibr.IBRAgent``, defaults: K = 20 stages of 0.1 s, 6 rounds), the other two cars are
MPC agents (theta zeta = 0.9 and 0.85). Prints per-decision wall time of the IBR car (median,
p99, max), per-best-response time, rounds until the plans stopped changing, fallbacks and
restarts, the race outcome, and the ratio of the median to the paper's budget of about 0.1 s
per IBR decision (3 cars, 6 rounds; paper, appendix "IBR hyperparameters"). One core (numba
threads = 1); the machine's load average is printed because other work on the machine
slows every wall-clock number here; the process CPU time per decision is printed beside it.

``--split`` times the parts of the IBR decisions (wall time, summed over the race): the
prediction with its Jacobians (CasADi's generated C, through ``IBR._evaluate``), DAQP's QPs,
the compiled kernels (condensing, the QP's assembly, separation pairs, the merit) and the rest:
the Python around them. It says how much of a decision compiling the glue could save; the
timers add about a microsecond per call.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
import warnings

import numba
import numpy as np

from agents.ibr import IBRAgent
from agents.mpc_agent import MPCAgent
from racing_env import RacingParallelEnv

PAPER_BUDGET_MS = 100.0

SPLIT_PARTS = {
    "prediction (C) and edge bounds": ("IBR", "_evaluate"),
    "QPs (DAQP)": ("daqp", "solve"),
    "condensing": ("module", "condense_states"),
    "QP assembly": ("module", "_assemble"),
    "separation pairs": ("module", "_separation_pairs"),
    "merit": ("module", "_merit"),
}
"""The parts of an IBR decision ``--split`` times: (owner, attribute) of each callable."""


@contextlib.contextmanager
def split_timers():
    """Wrap every callable of :data:`SPLIT_PARTS` (and ``IBR.solve``) in a wall-clock timer
    while the block runs; yields ``{part: seconds}``, filled as the block runs."""
    import daqp

    import agents.ibr_solver as ibr_solver

    owners = {"IBR": ibr_solver.IBR, "daqp": daqp, "module": ibr_solver}
    parts = dict(SPLIT_PARTS, decisions=("IBR", "solve"))
    totals = dict.fromkeys(parts, 0.0)
    saved = []

    def timed(part, fn):
        def wrapper(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                totals[part] += time.perf_counter() - t0

        return wrapper

    for part, (owner, name) in parts.items():
        obj = owners[owner]
        saved.append((obj, name, getattr(obj, name)))
        setattr(obj, name, timed(part, getattr(obj, name)))
    try:
        yield totals
    finally:
        for obj, name, fn in saved:
            setattr(obj, name, fn)


def print_split(totals: dict, decisions: int) -> None:
    """Where the IBR decisions' wall time went: ms per decision and share, by part."""
    whole = totals["decisions"]
    rest = whole - sum(v for k, v in totals.items() if k != "decisions")
    print(f"\nwhere an IBR decision's time goes ({decisions} decisions, wall, ms per decision):")
    for part, sec in [
        *((k, v) for k, v in totals.items() if k != "decisions"),
        ("the rest: Python", rest),
    ]:
        print(f"  {part:32s} {1e3 * sec / decisions:7.3f}  {100 * sec / whole:5.1f}%")


def race(agents, steps: int, seed: int = 0):
    """Drive ``agents`` (one per car) for ``steps`` steps from the start regions; returns
    ``(env, cpu_ms)``: the env at the end and the process CPU time [ms] of every IBR decision."""
    env = RacingParallelEnv(n_cars=len(agents), max_cycles=steps, start="regions")
    obs, _ = env.reset(seed=seed)
    for a, agent_id in zip(agents, env.possible_agents):
        a.reset(env.track, agent_id, seed)
    cpu_ms = []
    while env.agents:
        actions = {}
        for a, i in zip(agents, env.possible_agents):
            c0 = time.process_time()
            actions[i] = a.act(obs[i])
            if isinstance(a, IBRAgent):
                cpu_ms.append(1e3 * (time.process_time() - c0))
        obs, _, _, _, _ = env.step(actions)
    return env, np.array(cpu_ms)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="60 steps instead of 300")
    ap.add_argument("--all-ibr", action="store_true", help="three IBR cars instead of IBR vs 2 MPC")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--steps", type=int, default=None)
    ap.add_argument(
        "--split", action="store_true", help="time the parts of the decisions (see the docstring)"
    )
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    numba.set_num_threads(1)
    steps = args.steps or (60 if args.quick else 300)

    def make():
        if args.all_ibr:
            return [IBRAgent(rounds=args.rounds) for _ in range(3)]
        return [IBRAgent(rounds=args.rounds), MPCAgent(zeta=0.9), MPCAgent(zeta=0.85)]

    race(make(), 20)  # warm-up: JIT, compiled stage function
    agents = make()
    with split_timers() if args.split else contextlib.nullcontext() as totals:
        t0 = time.perf_counter()
        env, cpu = race(agents, steps)
        wall = time.perf_counter() - t0
    ibrs = [a for a in agents if isinstance(a, IBRAgent)]
    ms = np.concatenate([list(a.ibr.stats["decision_ms"]) for a in ibrs])
    br = np.concatenate([list(a.ibr.stats["br_ms"]) for a in ibrs])
    rounds = np.concatenate([list(a.ibr.stats["rounds"]) for a in ibrs])
    st = [a.stats for a in ibrs]
    med, p99 = np.median(ms), np.percentile(ms, 99)
    names = ["ibr" if isinstance(a, IBRAgent) else "mpc" for a in agents]
    print(
        f"IBR: 3 cars ({', '.join(names)}), {args.rounds} rounds, K = {ibrs[0].config.horizon} "
        f"stages of {ibrs[0].config.dt} s, default track, {steps} steps from the start regions"
    )
    print(
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; race wall time {wall:.1f} s"
    )
    print(
        f"decision ms (wall): median {med:.2f}  p99 {p99:.2f}  max {ms.max():.2f}  "
        f"({len(ms)} decisions)"
    )
    print(
        f"decision ms (CPU):  median {np.median(cpu):.2f}  p99 {np.percentile(cpu, 99):.2f}  "
        f"(the cost on an unshared core)"
    )
    print(
        f"best response ms: median {np.median(br):.3f}  p99 {np.percentile(br, 99):.3f}  "
        f"({len(br)} QPs, {len(br) / len(ms):.1f} per decision)"
    )
    print(
        f"rounds: mean {rounds.mean():.2f}, converged within the rounds in "
        f"{100 * (1 - sum(s['unconverged'] for s in st) / len(ms)):.0f}% of decisions; "
        f"fallbacks {sum(s['fallbacks'] for s in st)}, QP failures "
        f"{sum(s['br_failures'] for s in st)}, restarts {sum(s['restarts'] for s in st)}"
    )
    prog = env.core.state[0, :, 0] - env.core.s_line[0]
    print(
        "race: "
        + ", ".join(
            f"car_{i} ({n}) {p:.1f} m, {c} contacts, {o} off-track"
            for i, (n, p, c, o) in enumerate(
                zip(names, prog, env.core.contacts[0], env.core.offtracks[0])
            )
        )
    )
    print(
        f"\nmedian decision {med:.1f} ms = {med / PAPER_BUDGET_MS:.2f} x the paper's "
        f"{PAPER_BUDGET_MS:.0f} ms budget (p99 {p99 / PAPER_BUDGET_MS:.2f} x)"
    )
    if totals is not None:
        print_split(totals, len(ms))


if __name__ == "__main__":
    main()
