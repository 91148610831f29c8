"""The race and the benchmark from Python: what ``alpha-racer race`` and ``alpha-racer bench``
run, with tiny settings (a 2 s race, a benchmark of 3 races of 2 s).

    python examples/bench_api.py [OUT]        # OUT defaults to results/example
"""

import sys
from pathlib import Path

from experiments.evaluation.bench import bench
from experiments.evaluation.bench_config import BenchConfig
from experiments.evaluation.race import run_race, write_outputs
from experiments.infra.parallel import Pool


def main(out: Path) -> dict:
    # One race: agent specs as on the command line, one per car.
    result, frames = run_race(
        ["mpc:zeta=0.95", "raceline", "raceline:grip=0.7"],
        track="default",
        seed=0,
        max_cycles=20,
        render=True,
        progress_bar=False,
    )
    print(result.table())
    print("winner:", result.agents[result.order[0]], "| progress [m]:", result.progress.round(2))
    paths = write_outputs(result, frames, out / "race", animation="gif")
    print("wrote", ", ".join(str(p) for p in paths.values()))

    # A head-to-head benchmark: the ego against two opponents of one kind, the ego starting
    # from R1, R2, R3 in turn. Resumable: run it again and only missing races run.
    config = BenchConfig(ego="mpc", opponents="raceline", races=3, steps=20, seed=0)
    summary = bench(config, out / "bench", pool=Pool(workers=1, progress_bar=False))
    wins = summary["wins"]
    print(
        f"ego wins {wins['ego']['wins']}/{summary['races']}, O1 {wins['O1']['wins']}, "
        f"O2 {wins['O2']['wins']}; margin {summary['margin_m']['mean']:+.2f} m"
    )
    print((out / "bench" / "summary.md").read_text())
    return summary


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/example"))
