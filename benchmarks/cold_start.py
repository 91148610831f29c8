"""Cold and warm start of the README race (``alpha-racer race``: alpha against two IBR cars,
500 steps, the animation written), each run in a fresh Python process.

Cold: a fresh, empty ``ALPHA_RACER_CACHE`` (every numba kernel compiled, the MPC's C code
generated and compiled, the racing line computed). Warm: the same cache again. Prints each
run's wall and CPU (user + sys) time and where the time went: import, env construction, the
agents (construction and reset), the first step (the agents' first decisions and the env's
first step), the rest of the race, the outputs (plots and animation) and the interpreter's own
start-up; the time spent in the MPC's C predictions (CasADi's code generation, the C
compiles, loading the libraries) and computing racing lines, whatever phase they fall in; with
``--kernels``, the numba compile time per kernel (cold: its own time, nested kernels' time left
out, top 15 or ``--top``) or the cache load time (warm).

    python benchmarks/cold_start.py                 # 1 cold + 2 warm runs
    python benchmarks/cold_start.py --repeat 2 --kernels
    python benchmarks/cold_start.py -- --no-animation   # arguments after -- go to the race

Timings on a shared machine drift: compare figures measured back to back in one session.
"""

from __future__ import annotations

import time

T_START = time.perf_counter()  # the child's clock starts before any import

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import re  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from collections import defaultdict  # noqa: E402

PHASES = ("interpreter", "import", "env", "agents", "first step", "race", "outputs")


def _child(out: str, race_args: list[str], kernels: bool) -> None:
    """Run the README race in this process, instrumented; print one JSON line of timings."""
    marks: dict[str, float] = {}
    compile_self: dict[str, float] = defaultdict(float)
    loads: dict[str, float] = defaultdict(float)
    if kernels:
        import numba.core.caching as caching
        from numba.core import event

        stack: list[list] = []  # [name, start, time of nested compiles]

        class Compiles(event.Listener):
            def on_start(self, ev):
                d = ev.data["dispatcher"]
                stack.append(
                    [f"{d.py_func.__module__}.{d.py_func.__qualname__}", time.perf_counter(), 0.0]
                )

            def on_end(self, ev):
                name, t0, nested = stack.pop()
                total = time.perf_counter() - t0
                compile_self[name] += total - nested
                if stack:
                    stack[-1][2] += total

        event.register("numba:compile", Compiles())
        load = caching.Cache.load_overload

        def timed_load(self, sig, target_context):
            t0 = time.perf_counter()
            try:
                return load(self, sig, target_context)
            finally:
                loads[self._name] += time.perf_counter() - t0

        caching.Cache.load_overload = timed_load  # type: ignore[method-assign]

    import agents.mpc.prediction as prediction
    import experiments.cli as cli
    import experiments.evaluation.race as race_mod
    import racing_env.raceline.cache as raceline_cache
    from racing_env import RacingParallelEnv

    parts: dict[str, float] = defaultdict(float)  # C predictions, racing lines
    for mod, attr, part in (
        (prediction, "load_predictions", "C predictions"),
        (raceline_cache, "compute_raceline", "racing line"),
    ):
        setattr(mod, attr, _timed(getattr(mod, attr), parts, part))

    marks["import"] = time.perf_counter()
    init, step = RacingParallelEnv.__init__, RacingParallelEnv.step
    make = race_mod.make_agent_spec

    def timed_init(self, *a, **k):
        init(self, *a, **k)
        marks["env"] = time.perf_counter()

    def timed_step(self, *a, **k):
        r = step(self, *a, **k)
        marks.setdefault("first step", time.perf_counter())
        marks["race"] = time.perf_counter()
        return r

    def timed_make(spec):
        agent = make(spec)
        reset = agent.reset

        def timed_reset(*a, **k):
            r = reset(*a, **k)
            marks["agents"] = time.perf_counter()
            return r

        agent.reset = timed_reset
        return agent

    RacingParallelEnv.__init__ = timed_init  # type: ignore[method-assign]
    RacingParallelEnv.step = timed_step  # type: ignore[method-assign]
    race_mod.make_agent_spec = timed_make
    rc = cli.main(["race", "--out", out, *race_args])
    marks["outputs"] = time.perf_counter()
    if rc:
        raise SystemExit(rc)
    prev, phases = T_START, {}
    for name in PHASES[1:]:
        phases[name] = marks[name] - prev
        prev = marks[name]
    print(
        "COLD_START_JSON "
        + json.dumps(
            {
                "phases": phases,
                "parts": dict(parts),
                "compile": dict(compile_self),
                "loads": dict(loads),
            }
        )
    )


def _timed(fn, parts: dict[str, float], part: str):
    """``fn`` adding its wall time to ``parts[part]``."""

    def timed(*a, **k):
        t0 = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            parts[part] += time.perf_counter() - t0

    return timed


def _run(cache: str, out: str, race_args: list[str], kernels: bool) -> dict:
    """One race in a fresh interpreter on the cache folder ``cache``: wall, cpu, phases."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # this tree's packages
    path = os.pathsep.join(x for x in (root, os.environ.get("PYTHONPATH")) if x)
    env = dict(os.environ, ALPHA_RACER_CACHE=cache, PYTHONPATH=path)
    env.pop("NUMBA_CACHE_DIR", None)
    cmd = [sys.executable, __file__, "--child", "--out", out]
    if kernels:
        cmd.append("--kernels")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([*cmd, "--", *race_args], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        sys.exit(f"the race failed:\n{proc.stdout}\n{proc.stderr}")
    line = next(x for x in proc.stdout.splitlines() if x.startswith("COLD_START_JSON "))
    data = json.loads(line.split(" ", 1)[1])
    data["phases"] = {"interpreter": wall - sum(data["phases"].values()), **data["phases"]}
    data["wall"], data["user"] = wall, after.ru_utime - before.ru_utime
    data["sys"] = after.ru_stime - before.ru_stime
    data["result"] = [x for x in proc.stdout.splitlines() if re.match(r"\s*\d+\s+car_\d", x)]
    return data


def _report(label: str, d: dict, kernels: bool, top: int = 15) -> None:
    phases = "  ".join(f"{k} {v:5.1f}" for k, v in d["phases"].items())
    print(
        f"{label:8s} wall {d['wall']:5.1f} s  user {d['user']:5.1f}  sys {d['sys']:4.1f}  | {phases}"
    )
    if d["parts"]:
        parts = ", ".join(f"{k} {v:.1f} s" for k, v in d["parts"].items())
        print(f"         in all phases: {parts}")
    if kernels:
        table = d["compile"] if d["compile"] else d["loads"]
        what = "compile (own time)" if d["compile"] else "cache load"
        total = sum(table.values())
        print(f"         {what}: {total:.1f} s over {len(table)} kernels; top:")
        for name, t in sorted(table.items(), key=lambda kv: -kv[1])[:top]:
            print(f"           {t:6.2f}  {name}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=1, help="cold + warm rounds (default 1)")
    ap.add_argument("--warm", type=int, default=2, help="warm runs per round (default 2)")
    ap.add_argument("--kernels", action="store_true", help="per-kernel compile / load times")
    ap.add_argument("--top", type=int, default=15, help="kernels listed (default 15)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    ap.add_argument("race_args", nargs="*", help="extra arguments of alpha-racer race")
    args = ap.parse_args()
    if args.child:
        _child(args.out, args.race_args, args.kernels)
        return
    rows: dict[str, list[dict]] = {"cold": [], "warm": []}
    for r in range(args.repeat):
        with tempfile.TemporaryDirectory(prefix="alpha-racer-cold-") as tmp:
            cache, out = os.path.join(tmp, "cache"), os.path.join(tmp, "out")
            d = _run(cache, out, args.race_args, args.kernels)
            rows["cold"].append(d)
            _report(f"cold {r + 1}", d, args.kernels, args.top)
            for w in range(args.warm):
                d = _run(cache, out, args.race_args, args.kernels and w == 0)
                rows["warm"].append(d)
                _report(f"warm {r + 1}", d, args.kernels and w == 0, args.top)
    for line in rows["cold"][-1]["result"]:
        print("  " + line.strip())
    for kind, ds in rows.items():
        if ds:
            walls = sorted(d["wall"] for d in ds)
            users = sorted(d["user"] for d in ds)
            print(
                f"{kind}: wall median {walls[len(walls) // 2]:.1f} s (min {walls[0]:.1f}), "
                f"user median {users[len(users) // 2]:.1f} s over {len(ds)} runs"
            )


if __name__ == "__main__":
    main()
