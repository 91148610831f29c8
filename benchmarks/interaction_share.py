"""How much interaction a collection holds: the share of steps with a car within 1 m behind or
beside another (:func:`experiments.metrics.interaction_share`), and the passes, for the first
races of ``alpha-racer collect`` in each policy space and start geometry.

    python benchmarks/interaction_share.py               # 30 races per setting
    python benchmarks/interaction_share.py --races 8     # a smoke check

Settings: the paper's collection (``--space paper --start paper``), close starts
(``--start close``), the extended space (``--space extended``) and both. The same race indices
and seed for every setting (the draws then differ only by what the setting changes).
"""

from __future__ import annotations

import argparse
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np

SETTINGS = (("paper", "paper"), ("paper", "close"), ("extended", "paper"), ("extended", "close"))


def one_race(args):
    from experiments.collect import CollectConfig, simulate_race
    from experiments.metrics import interaction_share, race_metrics

    space, start, seed, i, races = args
    warnings.simplefilter("ignore")
    race = simulate_race(CollectConfig(races=races, space=space, start=start, seed=seed), i)
    return interaction_share(race["states"]), sum(race_metrics(race["states"])["passes"])


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--races", type=int, default=30, help="races per setting")
    p.add_argument("--seed", type=int, default=0, help="collection seed")
    p.add_argument("--workers", type=int, default=2, help="worker processes")
    args = p.parse_args(argv)
    print(f"{'space':9s} {'start':6s} share of steps with a car within 1 m   passes per race")
    for space, start in SETTINGS:
        jobs = [(space, start, args.seed, i, args.races) for i in range(args.races)]
        with ProcessPoolExecutor(args.workers) as ex:
            res = list(ex.map(one_race, jobs))
        share = np.array([r[0] for r in res])
        passes = np.array([r[1] for r in res])
        half = 1.96 * share.std(ddof=1) / np.sqrt(len(share)) if len(share) > 1 else float("nan")
        print(
            f"{space:9s} {start:6s} {share.mean():.3f} +- {half:.3f} (95% CI, {len(share)} races)"
            f"      {passes.mean():.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
