"""The analysis commands: ``analyze`` (the Nash analyses of a model) and ``general-report``
(the general alpha-potential on held-out tracks)."""

from __future__ import annotations

from pathlib import Path

from experiments.cli.options import (
    ANALYZE_OPTIONS,
    PARALLEL_OPTIONS,
    RESUME_HELP,
    SWITCH,
    add_options,
    commas,
    config_from,
    pool_from,
)


def analyze_config(args):
    from experiments.analysis.nash import AnalyzeConfig

    return config_from(AnalyzeConfig, args)


def _cmd_analyze(args) -> int:
    from experiments.analysis.nash import analyze

    out = Path(args.out)
    analyze(
        analyze_config(args),
        out,
        bench_dirs=args.bench or (),
        force=args.force,
        pool=pool_from(args),
    )
    print((out / "summary.md").read_text())
    print(f"wrote figures and JSON into {out}")
    return 0


def _cmd_general_report(args) -> int:
    from experiments.analysis.general import GeneralReportConfig, general_report

    out = Path(args.out)
    general_report(
        config_from(GeneralReportConfig, args, tracks=tuple(args.tracks or ())),
        out,
        pool_from(args),
        command="alpha-racer " + " ".join(args.argv),
        control_dir=args.control_out,
    )
    print((out / "summary.md").read_text())
    print(f"wrote {out / 'summary.md'} and {out / 'summary.json'}")
    return 0


def add_analyze(command) -> None:
    """``alpha-racer analyze``."""
    from experiments.analysis.nash import AnalyzeConfig

    a = command(
        "analyze",
        _cmd_analyze,
        "Nash analyses of an alpha-potential model: approximation gap, Nash "
        "regret by simulation, potential slices, figures",
    )
    add_options(
        a,
        AnalyzeConfig,
        ("--out", RESUME_HELP, {"default": "results/analysis"}),
        (
            "--bench",
            "benchmark folders to take the overtake animation from (default: none)",
            {"nargs": "*", "default": None},
        ),
        ("--force", "redo parts whose outputs exist", SWITCH),
        *ANALYZE_OPTIONS,
        *PARALLEL_OPTIONS,
        default_in_help=True,
    )


def add_general_report(command) -> None:
    """``alpha-racer general-report``."""
    from experiments.analysis.general import GeneralReportConfig

    gr = command(
        "general-report",
        _cmd_general_report,
        "the general alpha-potential on held-out tracks: "
        "approximation gap for N cars, races in the N-car protocol "
        "beside the best fixed theta on each track (the control), "
        "and against the single-track default model on default "
        "(resumable)",
    )
    add_options(
        gr,
        GeneralReportConfig,
        ("--model", "a general model: shipped name or path to a model.npz"),
        (
            "--tracks",
            "held-out track specs (random:A-B ranges allowed); default "
            "random:10000-10019 and the TUMFTM circuits (if the folder exists) "
            "that the model was not trained on",
            {"nargs": "+", "default": None, "metavar": "TRACK"},
        ),
        (
            "--gap-cars",
            "field sizes of the approximation gap",
            {"default": commas(GeneralReportConfig.gap_cars)},
        ),
        ("--gap-races", "fresh races per field size for the gap"),
        ("--gap-pairs", "unilateral deviations per field size"),
        (
            "--bench-cars",
            "field sizes of the N-car races",
            {"default": commas(GeneralReportConfig.bench_cars)},
        ),
        ("--bench-rounds", "rounds of N races (the ego from each region once) per track and N"),
        ("--default-races", "races against the default model on default (0 skips them)"),
        ("--steps", "steps of 0.1 s per race"),
        ("--seed", "seed of the races and deviations"),
        (
            "--control-thetas",
            "thetas of the selection of the best fixed theta (the control) on "
            "each held-out track the best-theta table lacks",
        ),
        ("--control-races", "playoff races per candidate of that selection"),
        (
            "--control-out",
            "folder of that selection (default OUT/control); run again to resume",
            {"default": None},
        ),
        (
            "--control",
            "an agent spec raced as the control ego on every held-out track instead "
            "of the per-track selection (default: the best fixed theta of each track in "
            "the model's policy space)",
            {"default": None, "metavar": "SPEC"},
        ),
        ("--out", RESUME_HELP, {"default": "results/general"}),
        *PARALLEL_OPTIONS,
    )
