"""The MPC's compiled SQP step against the same step in Python (the named baseline).

    python benchmarks/sqp_step.py               # 3 races of the collection, 300 steps each
    python benchmarks/sqp_step.py --races 1 --steps 50

Runs the first races of ``alpha-racer collect`` (:func:`experiments.potential.collect.simulate_race`:
3 MPC cars with thetas drawn from the box, seed 0) twice: with :func:`agents.mpc.sqp_step`,
the numba kernel that calls the compiled predictions itself, and with
:meth:`agents.mpc.MPC._step_python`, the same step in Python (what runs when the prediction
is interpreted). Both use the same fused numba helpers (:func:`trial_step`,
:func:`score_rollout`, :func:`linearised_qp`), so the ratio is what moving the step's loop
and its C calls into one compiled call adds; against the code before those helpers, the
collection A/B in the changelog is the figure. Prints the time per race and per decision of
both, their ratio, and whether the two races' data are identical (they must be: the two do
the same arithmetic). One process, native threads pinned to one.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from experiments.potential.collect import CollectConfig, _agents, simulate_race


def race(config: CollectConfig, index: int, python_step: bool) -> tuple[dict, float]:
    """(the race's data, seconds) of race ``index`` of the collection, every car's MPC taking
    the Python step or the compiled one."""
    for agent in _agents(config.n_cars):
        mpc = agent.mpc
        mpc._step = mpc._step_python if python_step else mpc._compiled_step
    t0 = time.perf_counter()
    data = simulate_race(config, index)
    return data, time.perf_counter() - t0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--races", type=int, default=3)
    ap.add_argument("--steps", type=int, default=300)
    args = ap.parse_args(argv)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    warnings.simplefilter("ignore")
    config = CollectConfig(races=args.races, steps=args.steps)
    simulate_race(CollectConfig(races=1, steps=5), 0)  # build the agents, load the kernels
    times = {False: 0.0, True: 0.0}
    same = True
    for k in range(args.races):
        runs = {}
        for python_step in (False, True):  # alternate, so that load hits both alike
            runs[python_step], seconds = race(config, k, python_step)
            times[python_step] += seconds
        same &= all(np.array_equal(runs[False][key], runs[True][key]) for key in runs[False])
    decisions = args.races * args.steps * config.n_cars
    print(
        f"{args.races} races of the collection ({config.n_cars} MPC cars, {args.steps} steps, "
        f"thetas from the box, seed {config.seed})"
    )
    for python_step, name in (
        (False, "compiled step (sqp_step)"),
        (True, "Python step (baseline)"),
    ):
        print(
            f"  {name:26s} {times[python_step] / args.races:7.3f} s per race, "
            f"{1e3 * times[python_step] / decisions:6.3f} ms per decision"
        )
    print(
        f"  ratio: {times[False] / times[True]:.2f} of the baseline's time "
        f"({times[True] / times[False]:.2f}x faster); races identical: {same}"
    )


if __name__ == "__main__":
    main()
