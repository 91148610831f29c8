"""DAQP called from compiled code (:mod:`agents.mpc.daqp_native`) against its Python binding.

    python benchmarks/daqp_native.py                 # a 3-car race, 40 steps, 15 repeats
    python benchmarks/daqp_native.py --steps 20 --repeats 5 --layer workqueue

Captures every QP the MPC solves in a race of three MPC cars (:class:`agents.mpc_agent.MPCAgent`
at its defaults, the paper's ORCA class) on the default track in
:class:`racing_env.RacingParallelEnv` (start regions, seed 0): the arguments of each
``daqp.solve`` call of :meth:`agents.mpc.MPC._qp`. Then times, over all captured QPs, in
rounds, each in another order, so that load on the machine hits all alike:

* ``daqp.solve``, the Python binding, one call per QP (what the MPC does today);
* :func:`~agents.mpc.daqp_native.solve_qp`, one compiled call per QP, called from a compiled
  loop over the QPs (so no Python between the solves);
* :func:`~agents.mpc.daqp_native.solve_qps`, all captured QPs in one batched call, with 1 and
  with 2 numba threads.

Prints the median time per QP of each over ``--repeats`` rounds and its ratio to
``daqp.solve``'s in the same run, and checks that every native solution equals the binding's
bit for bit (x and exitflag).
"""

from __future__ import annotations

import argparse
import time
import warnings

import numba
import numpy as np

QP = tuple  # (H, f, A, bupper, blower, sense, rho_soft, iter_limit)


def capture_mpc_qps(steps: int = 40, n_cars: int = 3, seed: int = 0) -> list[QP]:
    """The QPs of a ``steps``-step race of ``n_cars`` MPC cars on the default track: for each
    ``daqp.solve`` call of :meth:`agents.mpc.MPC._qp`, copies of ``(H, f, A, bupper, blower,
    sense)`` and its ``rho_soft, iter_limit``."""
    from agents.mpc import MPC
    from agents.mpc_agent import MPCAgent
    from racing_env import RacingParallelEnv

    qps: list[QP] = []
    qp = MPC._qp

    def recording_qp(self, daqp, H, f, Acon, blo, bhi, sense, q):
        class Spy:
            @staticmethod
            def solve(H, f, A, bupper, blower, sense, rho_soft, iter_limit):
                qps.append(
                    tuple(np.array(a) for a in (H, f, A, bupper, blower, sense))
                    + (float(rho_soft), int(iter_limit))
                )
                return daqp.solve(
                    H, f, A, bupper, blower, sense, rho_soft=rho_soft, iter_limit=iter_limit
                )

        return qp(self, Spy, H, f, Acon, blo, bhi, sense, q)

    env = RacingParallelEnv(n_cars=n_cars, max_cycles=steps, start="regions")
    obs, _ = env.reset(seed=seed)
    agents = {a: MPCAgent() for a in env.possible_agents}
    for name, agent in agents.items():
        agent.reset(env.track, agent_id=name)
    MPC._qp = recording_qp  # type: ignore[method-assign]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            while env.agents:
                actions = {a: agents[a].act(obs[a]) for a in env.agents}
                obs, *_ = env.step(actions)
    finally:
        MPC._qp = qp  # type: ignore[method-assign]
    return qps


def pad(qps: list[QP]) -> tuple:
    """``qps`` in :func:`~agents.mpc.daqp_native.solve_qps`' padded layout: ``(H, f, A,
    bupper, blower, sense, n, m, ms, rho_soft, iter_limit)``."""
    B = len(qps)
    n = np.array([q[1].shape[0] for q in qps])
    m = np.array([q[3].shape[0] for q in qps])
    mA = np.array([q[2].shape[0] for q in qps])
    N, M, R = int(n.max()), int(m.max()), int(mA.max())
    H, f, A = np.zeros((B, N, N)), np.zeros((B, N)), np.zeros((B, R, N))
    bu, bl, sense = np.zeros((B, M)), np.zeros((B, M)), np.zeros((B, M), np.int32)
    for b, (Hb, fb, Ab, bub, blb, sb, _, _) in enumerate(qps):
        H[b, : n[b], : n[b]] = Hb
        f[b, : n[b]] = fb
        A[b, : mA[b], : n[b]] = Ab
        bu[b, : m[b]], bl[b, : m[b]], sense[b, : m[b]] = bub, blb, sb
    rho = np.array([q[6] for q in qps])
    limit = np.array([q[7] for q in qps])
    return H, f, A, bu, bl, sense, n, m, m - mA, rho, limit


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=40, help="race steps to capture QPs from")
    ap.add_argument("--repeats", type=int, default=15, help="timed rounds (median reported)")
    ap.add_argument(
        "--layer",
        default="default",
        choices=["default", "workqueue", "omp", "tbb"],
        help="numba's threading layer for solve_qps (default: numba's choice)",
    )
    args = ap.parse_args(argv)
    numba.config.THREADING_LAYER = args.layer  # type: ignore[attr-defined]  # before any prange
    import daqp
    from numba import njit, typed

    from agents.mpc.daqp_native import AVAILABLE, UNAVAILABLE_REASON, solve_qp, solve_qps

    if not AVAILABLE:
        raise SystemExit(f"native DAQP not available: {UNAVAILABLE_REASON}")
    qps = capture_mpc_qps(args.steps)
    batch = pad(qps)
    listed = typed.List(qps)

    @njit(nogil=True)
    def native_loop(qps):
        flags = np.zeros(len(qps), np.int64)
        for i, (H, f, A, bu, bl, sense, rho, limit) in enumerate(qps):
            flags[i] = solve_qp(H, f, A, bu, bl, sense, rho, limit)[1]
        return flags

    def python_loop():
        for H, f, A, bu, bl, sense, rho, limit in qps:
            daqp.solve(H, f, A, bu, bl, sense, rho_soft=rho, iter_limit=limit)

    def batched(threads: int):
        def run():
            numba.set_num_threads(threads)
            solve_qps(*batch)

        return run

    same = True
    x_b, flag_b, _ = solve_qps(*batch)
    for b, (H, f, A, bu, bl, sense, rho, limit) in enumerate(qps):
        x_ref, _, flag_ref, _ = daqp.solve(H, f, A, bu, bl, sense, rho_soft=rho, iter_limit=limit)
        x, flag, _ = solve_qp(H, f, A, bu, bl, sense, rho, limit)
        n = f.shape[0]
        same &= np.array_equal(x, x_ref) and flag == flag_ref
        same &= np.array_equal(x_b[b, :n], x_ref) and flag_b[b] == flag_ref
    native_loop(listed)  # compile
    runs = {
        "daqp.solve (Python binding)": python_loop,
        "solve_qp (compiled loop)": lambda: native_loop(listed),
        "solve_qps, 1 thread": batched(1),
        "solve_qps, 2 threads": batched(2),
    }
    threads = numba.get_num_threads()
    times: dict[str, list[float]] = {k: [] for k in runs}
    names = list(runs)
    for r in range(args.repeats):  # each round in another order: load and spinning threads
        for name in names[r % len(names) :] + names[: r % len(names)]:  # hit all alike
            run = runs[name]
            t0 = time.perf_counter()
            run()
            times[name].append((time.perf_counter() - t0) / len(qps))
    numba.set_num_threads(threads)
    # the fixed cost of a call: a QP of one variable and one row, 1000 times
    tiny_qp = (np.eye(1), np.ones(1), np.ones((1, 1)), np.ones(1), -np.ones(1))
    tiny_qp += (np.zeros(1, np.int32), 1e-6, 100)
    tiny = typed.List([tiny_qp] * 1000)
    native_loop(tiny)
    call: dict[str, list[float]] = {"daqp.solve": [], "solve_qp": []}
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        for _ in range(1000):
            daqp.solve(*tiny_qp[:6], rho_soft=1e-6, iter_limit=100)
        call["daqp.solve"].append((time.perf_counter() - t0) / 1000)
        t0 = time.perf_counter()
        native_loop(tiny)
        call["solve_qp"].append((time.perf_counter() - t0) / 1000)
    sizes = np.array([(q[1].shape[0], q[3].shape[0]) for q in qps])
    flags = np.array([daqp.solve(*q[:6], rho_soft=q[6], iter_limit=q[7])[2] for q in qps])
    print(
        f"{len(qps)} QPs of a {args.steps}-step race of 3 MPC cars (default track): "
        f"n = {sizes[:, 0].min()}..{sizes[:, 0].max()}, m = {sizes[:, 1].min()}.."
        f"{sizes[:, 1].max()}; exitflags {dict(zip(*np.unique(flags, return_counts=True)))}"
    )
    base = float(np.median(times["daqp.solve (Python binding)"]))
    for name, ts in times.items():
        med = float(np.median(ts))
        print(f"  {name:30s} {1e6 * med:8.2f} us per QP   {med / base:5.2f} of daqp.solve's")
    c_py, c_nat = (1e6 * float(np.median(call[k])) for k in ("daqp.solve", "solve_qp"))
    print(f"  a 1-variable QP, time per call: daqp.solve {c_py:.2f} us, solve_qp {c_nat:.2f} us")
    print(f"  native == daqp.solve bit for bit (x, exitflag), single and batched: {same}")
    print(f"  numba threading layer: {numba.threading_layer()}; load average {load()}")


def load() -> str:
    """The machine's 1-minute load average (others' jobs share the cores), or "?"."""
    try:
        import os

        return f"{os.getloadavg()[0]:.1f}"
    except OSError:
        return "?"


if __name__ == "__main__":
    main()
