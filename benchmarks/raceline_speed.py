"""How long a racing line takes: the built-in track, Monza at 1:43 and at full scale.

    PYTHONPATH=. python benchmarks/raceline_speed.py
    PYTHONPATH=. python benchmarks/raceline_speed.py --tracks tumftm:Monza@1 tumftm:Spa@1

A track is a :func:`~racing_env.tracks.make_track` name, with ``@SCALE`` for a TUMFTM circuit
at another scale than 1:43 (``tumftm:Monza@1``: full size, 2,895 stations). Computes each
line without the cache (:func:`racing_env.raceline.compute_raceline`) and prints
the wall and CPU time (the CPU time is the figure to compare on a shared machine), the
linearisations, and how each box QP was solved: by the active-set method
alone, or by the interior-point method and the active-set polish (see
:mod:`racing_env.raceline.boxqp`), beside the target. Targets: the built-in track under
10 s and Monza at 1:43 under 15 s (once wall-clock asserts in the tests); Monza at full scale
under 20 s (issue 31: 150-180 s before the interior-point fallback, when the dense DAQP
fallback took about 30 s per QP).
"""

from __future__ import annotations

import argparse
import time

from racing_env.raceline import boxqp, compute_raceline
from racing_env.tracks import make_track

TARGETS = {"default": 10.0, "tumftm:Monza": 15.0, "tumftm:Monza@1": 20.0}
"""Wall-time targets [s] of the racing line (on a machine that is not shared)."""


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--tracks",
        nargs="+",
        default=list(TARGETS),
        help="track names, NAME@SCALE for a TUMFTM circuit at another scale "
        f"(default: {' '.join(TARGETS)})",
    )
    args = ap.parse_args(argv)
    counts = {"qps": 0, "active_set": 0, "interior_point": 0}
    solve = boxqp.BoxQP.solve

    def counted_solve(self, *a, **k):
        counts["qps"] += 1
        return solve(self, *a, **k)

    active_set, interior_point = boxqp.box_qp_active_set, boxqp.box_qp_interior_point
    fallback = [False]

    def counted_active_set(*a, **k):
        x = active_set(*a, **k)
        if not fallback[0]:
            counts["active_set"] += x is not None
        fallback[0] = False
        return x

    def counted_interior_point(*a, **k):
        counts["interior_point"] += 1
        fallback[0] = True  # the next active-set call is its polish
        return interior_point(*a, **k)

    compute_raceline(make_track("oval"))  # warm-up, not timed: numba's compile or cache load
    boxqp.box_qp_active_set, boxqp.box_qp_interior_point = (
        counted_active_set,
        counted_interior_point,
    )
    boxqp.BoxQP.solve = counted_solve
    try:
        for spec in args.tracks:
            name, _, scale = spec.partition("@")
            if scale:
                try:
                    scale = float(scale)
                except ValueError:
                    raise SystemExit(
                        f"bad scale in {spec!r}: expected NAME@SCALE, e.g. tumftm:Monza@1"
                    ) from None
            counts.update(qps=0, active_set=0, interior_point=0)
            t0 = time.perf_counter()
            track = make_track(name, scale=scale or None)
            t1, c1 = time.perf_counter(), time.process_time()
            rl = compute_raceline(track)
            t2, c2 = time.perf_counter(), time.process_time()
            target = TARGETS.get(spec)
            print(
                f"{spec}: {len(track.s_grid)} stations, "
                f"{track.length:.0f} m; track {t1 - t0:.1f} s, racing line {t2 - t1:.1f} s "
                f"(CPU {c2 - c1:.1f} s) "
                f"({rl.iterations} linearisations, converged {rl.converged}; {counts['qps']} QPs: "
                f"{counts['active_set']} by the active-set method, "
                f"{counts['interior_point']} by interior point + polish, the others by "
                f"OSQP / DAQP); "
                f"lap estimate {rl.lap_time:.2f} s" + (f"; target < {target:g} s" if target else "")
            )
    finally:
        boxqp.box_qp_active_set, boxqp.box_qp_interior_point = active_set, interior_point
        boxqp.BoxQP.solve = solve


if __name__ == "__main__":
    main()
