"""Decision time against field size: every shipped agent driving every car of N = 2, 3, 5, 8.

    python benchmarks/field_size.py                  # 300 steps per (agent, N)
    python benchmarks/field_size.py --quick          # 40 steps, a smoke check
    python benchmarks/field_size.py --agents mpc ibr --cars 3 8 --steps 100

For each agent (``alpha``, ``mpc``, ``ibr``, ``ppo``, ``raceline`` by default) and each N,
one race on the default track from the start regions R1..RN (car i in R(i+1); N = 8 spans
7.4 m of the 38.9 m track) in which all N cars are driven by that agent. Before it, an
untimed race of 5 steps with the same N builds what the agent compiles or caches (numba,
CasADi, the racing line, the model), so the figures are those of a running race. Per
(agent, N) it prints the wall time of one ``act()`` call [ms] over all cars' decisions
(median, p99, max), the process CPU time per decision (median: the cost on an unshared
core), the share of decisions over the 100 ms control period (each car deciding on its own
core, as on a real car), and the health of the race: NaN actions (replaced by a zero action
so that the race goes on), non-finite states, off-track car-steps and the cars that left the
track, contact car-steps, fallbacks summed over the agents' ``stats``, and an exception
(type and message; the race then ends). Native thread pools are pinned to one thread, as in
the experiments' workers. The machine's load average is printed: other work on it inflates
every wall-clock figure, not the CPU times as much.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np

AGENTS = ("alpha", "mpc", "ibr", "ppo", "raceline")
FIELDS = (2, 3, 5, 8)
CONTROL_PERIOD_MS = 100.0
WARMUP_STEPS = 5


def field_race(spec: str, n: int, steps: int, seed: int = 0) -> dict:
    """Race ``n`` cars all driven by agent ``spec`` for ``steps`` steps; returns per-decision
    wall and CPU times [ms] (arrays over cars and steps) and the race's health counts."""
    from agents import make_agent_spec
    from racing_env import RacingParallelEnv

    out = {"wall_ms": [], "cpu_ms": [], "nan_actions": 0, "error": None, "steps": 0}
    env = None
    try:
        env = RacingParallelEnv(track="default", n_cars=n, max_cycles=steps, start="regions")
        agents = [make_agent_spec(spec) for _ in range(n)]
        obs, _ = env.reset(seed=seed, options={"order": list(range(n))})
        for k, (agent, aid) in enumerate(zip(agents, env.possible_agents)):
            agent.reset(env.track, aid, seed + 1000 * (k + 1))
        while env.agents:
            actions = {}
            for agent, aid in zip(agents, env.possible_agents):
                w0, c0 = time.perf_counter(), time.process_time()
                action = np.asarray(agent.act(obs[aid]), dtype=np.float32)
                out["wall_ms"].append(1e3 * (time.perf_counter() - w0))
                out["cpu_ms"].append(1e3 * (time.process_time() - c0))
                if action.shape != (2,) or not np.isfinite(action).all():
                    out["nan_actions"] += 1
                    action = np.zeros(2, dtype=np.float32)
                actions[aid] = action
            obs, _, _, _, _ = env.step(actions)
            out["steps"] += 1
        out["fallbacks"] = sum(
            int((getattr(a, "stats", {}) or {}).get("fallbacks", 0)) for a in agents
        )
    except Exception as exc:  # reported in the table, not raised: the others go on
        out["error"] = f"{type(exc).__name__}: {exc}"
    if env is not None and env.core.state is not None:
        core = env.core
        out["finite_states"] = bool(np.isfinite(core.state[0]).all())
        out["off_track_steps"] = int(core.offtracks[0].sum())
        out["cars_off_track"] = int((core.offtracks[0] > 0).sum())
        out["contact_steps"] = int(core.contacts[0].sum())
    out["wall_ms"], out["cpu_ms"] = np.array(out["wall_ms"]), np.array(out["cpu_ms"])
    return out


def _row(spec: str, n: int, r: dict) -> str:
    w, c = r["wall_ms"], r["cpu_ms"]
    times = (
        f"{np.median(w):8.3f} {np.percentile(w, 99):8.3f} {w.max():8.3f} "
        f"{np.median(c):8.3f} {100 * np.mean(w > CONTROL_PERIOD_MS):6.1f}%"
        if w.size
        else f"{'-':>8} {'-':>8} {'-':>8} {'-':>8} {'-':>7}"
    )
    if not r["steps"]:  # no step was taken: nothing to say about the race
        health = f"{'-':>4} {'-':>6} {'-':>11} {'-':>7} {'-':>5}"
    else:
        health = (
            f"{r['nan_actions']:>4} {'yes' if r.get('finite_states') else 'NO':>6} "
            f"{r.get('off_track_steps', '-'):>6}/{r.get('cars_off_track', '-'):<4} "
            f"{r.get('contact_steps', '-'):>7} {r.get('fallbacks', '-'):>5}"
        )
    line = f"{spec:<10} {n:>2} {r['steps']:>5} {w.size:>6} {times} {health}"
    return line + (f"  {r['error']}" if r["error"] else "")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="40 steps per race instead of 300")
    ap.add_argument("--steps", type=int, default=None, help="steps per race (overrides --quick)")
    ap.add_argument("--agents", nargs="+", default=list(AGENTS), help="agent specs to measure")
    ap.add_argument("--cars", nargs="+", type=int, default=list(FIELDS), help="field sizes N")
    ap.add_argument("--seed", type=int, default=0, help="seed of the start positions and agents")
    args = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    from agents.threads import pin_threads

    pin_threads(1)
    steps = args.steps or (40 if args.quick else 300)

    print(
        f"Decision time per act() against field size: default track, start regions, every "
        f"car driven by the agent, {steps} steps per race; one native thread per library"
    )
    print(
        f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores "
        f"(wall-clock figures grow with the load)"
    )
    print(
        f"\n{'agent':<10} {'N':>2} {'steps':>5} {'acts':>6} {'med ms':>8} {'p99 ms':>8} "
        f"{'max ms':>8} {'cpu med':>8} {'>100ms':>7} {'NaN':>4} {'finite':>6} "
        f"{'offtrk/cars':>11} {'contact':>7} {'fallb':>5}"
    )
    t0 = time.perf_counter()
    for spec in args.agents:
        for n in args.cars:
            warm = field_race(spec, n, WARMUP_STEPS, args.seed + 1)
            if warm["error"]:  # it would fail again: report it once
                print(_row(spec, n, warm) + "  (in the warm-up race)", flush=True)
                continue
            print(_row(spec, n, field_race(spec, n, steps, args.seed)), flush=True)
    print(
        f"\nwall time {time.perf_counter() - t0:.0f} s; columns: acts = timed act() calls "
        f"(N x steps); cpu med = median process CPU time per act(); >100ms = share of acts "
        f"over the {CONTROL_PERIOD_MS:.0f} ms control period; NaN = non-finite actions; "
        f"offtrk/cars = off-track car-steps / cars that left the track; contact = contact "
        f"car-steps; fallb = fallbacks summed over the cars"
    )


if __name__ == "__main__":
    main()
