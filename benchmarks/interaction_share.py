"""How much interaction a collection holds: the share of steps with a car within 1 m behind or
beside another (:func:`experiments.evaluation.metrics.interaction_share`), and the passes, for the first
races of ``alpha-racer collect`` in each policy space, start geometry and pace draw.

    python benchmarks/interaction_share.py               # 30 races per setting
    python benchmarks/interaction_share.py --races 8     # a smoke check
    python benchmarks/interaction_share.py --data data/fullsize_monza   # a stored collection

With ``--data`` it reads a stored collection instead, of any class: the gap is 1 m at 1:43,
scaled by the car's length ratio for another class (39.2 m, 8.3 car lengths, at full size).

Settings: the paper's collection (``--space paper --start paper``), close starts
(``--start close``), the extended space (``--space extended``), both, and both with the
cars' paces drawn close together (``--pace close``). The same race indices and seed for every
setting (the draws then differ only by what the setting changes).
"""

from __future__ import annotations

import argparse
import warnings
from concurrent.futures import ProcessPoolExecutor

import numpy as np

SETTINGS = (
    ("paper", "paper", "box"),
    ("paper", "close", "box"),
    ("extended", "paper", "box"),
    ("extended", "close", "box"),
    ("paper", "close", "close"),
    ("extended", "close", "close"),
    ("extended", "close", "spread"),
    ("extended", "close", "overtake"),
)


def one_race(args):
    from experiments.evaluation.metrics import interaction_share, race_metrics
    from experiments.potential.collect import CollectConfig, simulate_race

    space, start, pace, seed, i, races = args
    warnings.simplefilter("ignore")
    config = CollectConfig(races=races, space=space, start=start, pace=pace, seed=seed)
    race = simulate_race(config, i)
    return interaction_share(race["states"]), sum(race_metrics(race["states"])["passes"])


def stored_share(data_dir) -> None:
    """Print the interaction share of every race of a stored collection (its class's gap)."""
    from experiments.evaluation.metrics import BEHIND_GAP_M, interaction_share
    from experiments.potential.collect import collection_class, load_races
    from racing_env.scaling import size_ratios

    data = load_races(data_dir)
    vehicle_class, wake = collection_class(data["config"])
    gap = BEHIND_GAP_M * size_ratios(vehicle_class)[0]
    share = np.array([interaction_share(st, gap) for st in data["states"]])
    half = 1.96 * share.std(ddof=1) / np.sqrt(len(share))
    print(
        f"{data_dir}: class {vehicle_class}, wake {wake:g}, {len(share)} races; share of steps "
        f"with a car within {gap:.1f} m behind or beside another: {share.mean():.3f} +- "
        f"{half:.3f} (95% CI)"
    )


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--races", type=int, default=30, help="races per setting")
    p.add_argument("--seed", type=int, default=0, help="collection seed")
    p.add_argument("--workers", type=int, default=2, help="worker processes")
    p.add_argument(
        "--settings",
        nargs="+",
        default=None,
        metavar="SPACE/START/PACE",
        help="only these settings, e.g. extended/close/close (default: all)",
    )
    p.add_argument("--data", default=None, help="a stored collection folder to measure instead")
    args = p.parse_args(argv)
    if args.data:
        stored_share(args.data)
        return
    settings = SETTINGS
    if args.settings:
        settings = [tuple(x.split("/")) for x in args.settings]
        bad = [x for x in settings if x not in SETTINGS]
        if bad:
            p.error(f"--settings: {bad} not among {['/'.join(x) for x in SETTINGS]}")
    print(f"{'space':9s} {'start':6s} {'pace':6s} share of steps with a car within 1 m   passes")
    for space, start, pace in settings:
        jobs = [(space, start, pace, args.seed, i, args.races) for i in range(args.races)]
        with ProcessPoolExecutor(args.workers) as ex:
            res = list(ex.map(one_race, jobs))
        share = np.array([r[0] for r in res])
        passes = np.array([r[1] for r in res])
        half = 1.96 * share.std(ddof=1) / np.sqrt(len(share)) if len(share) > 1 else float("nan")
        print(
            f"{space:9s} {start:6s} {pace:6s} {share.mean():.3f} +- {half:.3f} (95% CI, {len(share)} races)"
            f"      {passes.mean():.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
