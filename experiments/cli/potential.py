"""The alpha-potential's pipeline commands: ``collect`` (races of MPC cars with random theta)
and ``train`` (the value and potential networks)."""

from __future__ import annotations

from pathlib import Path

from experiments.cli.options import (
    CLASS_OPTIONS,
    PARALLEL_OPTIONS,
    RESUME_HELP,
    add_options,
    config_from,
    pool_from,
)


def _cmd_collect(args) -> int:
    from experiments.potential.collect import CollectConfig, collect
    from experiments.potential.family import FamilyConfig, collect_family, parse_cars
    from racing_env.class_config import default_track

    cars = parse_cars(args.cars)
    if args.tracks is None and len(cars) == 1:  # one track, one field size: as always
        cfg = config_from(
            CollectConfig,
            args,
            n_cars=cars[0],
            track=args.track or default_track(args.vehicle_class),
            races_per_shard=args.shard_size or 25,
        )
        summary = collect(cfg, args.out, pool_from(args))
    else:
        if args.vehicle_class != "orca" or args.wake is not None:
            raise ValueError(
                f"a family collection (--tracks or several --cars) races the 1:43 'orca' "
                f"class without a wake; --vehicle-class {args.vehicle_class} --wake "
                f"{args.wake} is for a collection on one track with one field size"
            )
        if args.track is not None and args.tracks is not None:
            raise ValueError(
                f"give either --track ({args.track!r}) or --tracks "
                f"({' '.join(args.tracks)}), not both"
            )
        cfg = config_from(
            FamilyConfig,
            args,
            tracks=tuple(args.tracks or [args.track or "default"]),
            cars=cars,
            races_per_shard=args.shard_size or 4,
        )
        summary = collect_family(cfg, args.out, pool_from(args))
    print(
        f"{summary['simulated']} races simulated ({summary['resumed']} already there) in "
        f"{summary['seconds']:.1f} s, {summary['races_per_s']:.3f} races/s -> {summary['out']}"
    )
    return 0


def _cmd_train(args) -> int:
    from experiments.potential.train import TrainConfig, train

    train(
        args.data,
        args.out,
        config_from(TrainConfig, args),
        command="alpha-racer " + " ".join(args.argv),
        space=args.space,
    )
    print(f"model: {Path(args.out) / 'model.npz'}")
    return 0


def add_collect(command) -> None:
    """``alpha-racer collect``: one collection, or a family over tracks and field sizes."""
    from agents.theta import SPACES
    from experiments.potential.collect import (
        PACE_SPREAD,
        PACE_SPREADS,
        PACES,
        START_REGIONS,
        CollectConfig,
    )

    c = command(
        "collect",
        _cmd_collect,
        "simulate races of MPC cars with random theta (resumable shards)",
        "simulate races of MPC cars with random theta (resumable shards); with --tracks "
        "or several --cars, a family collection over tracks and field sizes (one track "
        "and one field size per shard) for the general alpha-potential",
    )
    add_options(
        c,
        CollectConfig,
        ("--races", "races to simulate"),
        (
            "--cars",
            "cars per race: a number, or field sizes for a family collection as a "
            "range 2-6 or a list 2,3,5 (each in 2..8)",
            {"default": "3"},
        ),
        ("--steps", "steps of 0.1 s per race"),
        (
            "--track",
            "track spec (as for race; default: default, and tumftm:Monza with "
            "--vehicle-class fullsize: the track is built at the class's scale)",
            {"default": None},
        ),
        (
            "--tracks",
            "a family collection over these track specs; random:A-B stands for "
            "random:A .. random:B, e.g. --tracks default oval random:0-299 "
            "tumftm:Monza",
            {"nargs": "+", "default": None, "metavar": "TRACK"},
        ),
        ("--seed", "seed of the thetas and start positions"),
        (
            "--space",
            "policy space the thetas are drawn from (extended: the paper's five "
            "and b, the lap-time line's weight)",
            {"choices": sorted(SPACES)},
        ),
        (
            "--start",
            "start regions: the paper's (0.4 m long, 0.6 m apart) or close (0.2 m "
            "long, 0.1 m apart: more passing and blocking); in 1:43 metres, scaled to the "
            "car's length for --vehicle-class fullsize",
            {"choices": sorted(START_REGIONS)},
        ),
        (
            "--pace",
            "the cars' zeta: each drawn over the box (the paper's), or close: one zeta per "
            f"race over the box and every car's within {PACE_SPREAD:g} of it (the field stays "
            f"together), or spread: within {PACE_SPREADS['spread']:g} (faster cars among "
            "slower ones: more passes), or overtake: spread, the slowest car in front and the "
            "fastest at the back",
            {"choices": list(PACES)},
        ),
        (
            "--shard-size",
            "races per shard file (default 25; 4 for a family collection, so that "
            "its shards spread over many tracks)",
            {"type": int, "default": None},
        ),
        *CLASS_OPTIONS,
        ("--out", RESUME_HELP, {"default": "data/races"}),
        *PARALLEL_OPTIONS,
    )


def add_train(command) -> None:
    """``alpha-racer train``."""
    from agents.theta import SPACES
    from experiments.potential.nets import OBJECTIVES, TrainConfig

    tr = command(
        "train", _cmd_train, "fit the value and alpha-potential networks on collected races"
    )
    tr.add_argument(
        "--data", default="data/races", help="a directory written by `alpha-racer collect`"
    )
    tr.add_argument("--out", default="models/alpha", help="output directory (resumes if it exists)")
    add_options(
        tr,
        TrainConfig,
        ("--gamma", "discount factor (default {default})"),
        ("--value-epochs", "epochs of value-network training (default {default})"),
        ("--potential-steps", "optimiser steps of the potential network (default {default})"),
        (
            "--potential-batch",
            "unilateral deviations per optimiser step of the potential network (default {default})",
        ),
        (
            "--value-hidden",
            "hidden layer widths of the value networks (default {default})",
            {"type": int, "nargs": "+"},
        ),
        (
            "--potential-hidden",
            "hidden layer widths of the potential network (default {default})",
            {"type": int, "nargs": "+"},
        ),
        (
            "--objective",
            "potential loss: mse, or the paper's min-max as a smooth maximum or a "
            "tail average (default {default})",
            {"choices": list(OBJECTIVES)},
        ),
        ("--val-fraction", "races held out (default {default})"),
        (
            "--rollout-pairs",
            "paired-rollout checks on held-out states (default {default}; 0 skips)",
        ),
        ("--rollout-steps", "steps of each paired rollout (default {default})"),
        ("--seed", "seed of the split and the training (default {default})"),
        ("--threads", "torch threads and rollout workers (default {default})"),
        default_in_help=True,
    )
    tr.add_argument(
        "--space",
        choices=sorted(SPACES),
        default=None,
        help="policy space the collection must be of (default: the collection's, "
        "from its manifest; a mismatch is an error naming both)",
    )
