"""``alpha-racer reproduce``: every table and figure of the paper (or of the extended policy
space) into one folder."""

from __future__ import annotations

from pathlib import Path

from experiments.cli.analysis import analyze_config
from experiments.cli.options import (
    ANALYZE_OPTIONS,
    CLASS_OPTIONS,
    IMPORT_OPTION,
    PARALLEL_OPTIONS,
    RESUME_HELP,
    add_options,
    pool_from,
)

REPRODUCE_OUT = {"paper": "results", "extended": "results/extended"}
"""``alpha-racer reproduce``'s default output folder per policy space (``--space``)."""


def _reproduce_ego(args) -> str:
    """The ego of the reproduced Table 1: ``alpha`` (model=auto, the paper's shipped models)
    in the paper's space; in another, ``alpha:space=<space>`` (its shipped model) or, with
    ``--model``, that model."""
    if args.space == "paper":
        return "alpha"
    ego = f"alpha:space={args.space}"
    return ego if args.model is None else f"{ego},model={args.model}"


def _reproduce_analyze_config(args):
    """The analyses' config: the options given, ``--steps``, and in the extended space the
    shipped extended model unless ``--model`` names another."""
    from dataclasses import replace

    cfg = replace(analyze_config(args), steps=args.steps)
    if args.space != "paper" and args.model is None:
        cfg = replace(cfg, model=args.space)  # the shipped model of the space (AUTO_MODELS)
    return cfg


def _control_note(track: str, entry: dict, space: str) -> str:
    """The comparison's sentence on where the best fixed theta came from."""
    from agents.best_theta import PAPER, control_command

    theta = ", ".join(f"{k} {v:.4g}" for k, v in entry["theta"].items())
    of = "" if space == PAPER else f" of the {space} policy space"
    command = "alpha-racer control" if space == PAPER else control_command(track, space)
    return (
        f"The best fixed theta{of} on `{track}` ({theta}) was chosen by `{command}` "
        f"from {entry['selection']['file']} (sha256 {entry['selection']['sha256'][:12]}, env "
        f"`{entry['env']}`)."
    )


def _reproduce_strategy(args, ego: str, control: str, track: str, out: Path, pool):
    """The strategy benchmark of ``ego`` against ``control`` on ``track`` into
    ``out/strategy`` (``--strategy-races`` races per bench, ``--strategy-steps`` steps);
    returns its ``strategy.md``, None when ``--strategy-races`` is 0."""
    from experiments.evaluation.strategy import StrategyConfig, strategy

    if not args.strategy_races:
        return None
    cfg = StrategyConfig(
        ego=ego,
        control=control,
        tracks=(track,),
        races=args.strategy_races,
        steps=args.strategy_steps,
    )
    strategy(cfg, out / "strategy", pool)
    return out / "strategy" / "strategy.md"


#: the strategy suite's races and steps per vehicle class (``--strategy-races``, ``--strategy-steps``
#: unset): at full size 60 s races (a 20 s race ends before Monza's first braking zone) and
#: fewer of them (a full-size race costs about 14 s of a core against the 1:43 car's 1 s)
STRATEGY_DEFAULTS = {"orca": (99, 200), "fullsize": (24, 600)}
#: Table 1's races per case per vehicle class (``--races`` unset)
TABLE1_RACES = {"orca": 99, "fullsize": 24}


def _class_defaults(args) -> None:
    """Fill the unset ``--races``, ``--strategy-races`` and ``--strategy-steps`` with the
    class's."""
    if args.races is None:
        args.races = TABLE1_RACES[args.vehicle_class]
    races, steps = STRATEGY_DEFAULTS[args.vehicle_class]
    if args.strategy_races is None:
        args.strategy_races = races
    if args.strategy_steps is None:
        args.strategy_steps = steps


def _cmd_reproduce(args) -> int:
    """Every table and figure: the paper table, the same races with the best fixed theta (the
    control, selected first if the best-theta table lacks the track) and the extra fixed ego,
    their comparison, then the analyses (each resumable). With ``--space extended`` the same
    on the extended policy space (ego, control, analyses and policy map), plus the strategy
    benchmark of the ego against the control."""
    import json

    _class_defaults(args)
    if args.alpha_options and args.vehicle_class != "fullsize":
        raise SystemExit(
            f"--alpha-options {args.alpha_options!r} is for --vehicle-class fullsize (the "
            f"paper's reproduction races the paper's agent)"
        )
    if args.vehicle_class == "fullsize":  # the full-size world's suites, not the paper's
        from experiments.cli.reproduce_fullsize import reproduce_fullsize

        readme = reproduce_fullsize(args, pool_from(args))
        print(readme.read_text())
        print(f"wrote {readme} and the folders beside it")
        return 0

    from experiments.analysis.nash import analyze
    from experiments.evaluation.control import ControlConfig, best_fixed_spec, ensure_best_thetas
    from experiments.evaluation.paper_table import PAPER_CASES, comparison_markdown, paper_table
    from experiments.infra.artifacts import slug, write_text

    space = args.space
    out = Path(args.out or REPRODUCE_OUT[space])
    track = "default"  # the paper table's track
    # the control: the same races with the best fixed theta on the track as ego, selected
    # first (resumable, into out/control) if the best-theta table lacks the track
    ctl = ControlConfig(
        thetas=args.control_thetas,
        races=args.control_races,
        steps=args.steps,
        space=space,
        refine=args.control_refine,
    )
    pool = pool_from(args)
    entry = ensure_best_thetas([track], ctl, out / "control", pool)[track]
    ego = _reproduce_ego(args)
    paper_table(
        out / "paper_table", ego=ego, races=args.races, steps=args.steps, pool=pool, space=space
    )
    tables = [out / "paper_table" / "paper_table.md"]
    compared = {"alpha": out / "paper_table"}
    control = out / "paper_table_control"
    best_fixed = best_fixed_spec(space)
    paper_table(control, ego=best_fixed, races=args.races, steps=args.steps, pool=pool, space=space)
    tables.append(control / "paper_table.md")
    compared["best fixed"] = control
    if args.control_ego != "none":  # an extra row: the same races with another fixed ego
        extra = out / f"paper_table_{slug(args.control_ego)}_ego"
        paper_table(
            extra, ego=args.control_ego, races=args.races, steps=args.steps, pool=pool, space=space
        )
        tables.append(extra / "paper_table.md")
        compared[args.control_ego] = extra
    comparison = write_text(
        out / "comparison.md",
        comparison_markdown(
            {
                label: json.loads((d / "paper_table.json").read_text())
                for label, d in compared.items()
            },
            _control_note(track, entry, space),
        ),
    )
    tables.insert(1, comparison)
    if (out / "control" / "summary.md").exists():  # the selection, if it ran here
        tables.insert(2, out / "control" / "summary.md")

    cases = ["IV"] + [c for c in PAPER_CASES if c != "IV"]  # the paper's overtake is vs IBR
    analyze(
        _reproduce_analyze_config(args),
        out / "analysis",
        bench_dirs=[out / "paper_table" / f"case_{c}" for c in cases],
        pool=pool,
    )
    parts = tables + [out / "analysis" / "summary.md"]
    if space != "paper":  # what the space's maneuvers add: the strategy benchmark
        md = _reproduce_strategy(args, ego, best_fixed, track, out, pool)
        parts += [md] if md else []
    if args.policy_thetas:  # the policy space the potential maximises over
        from experiments.evaluation.policy_map import PolicyMapConfig, policy_map

        policy_map(
            PolicyMapConfig(thetas=args.policy_thetas, steps=args.steps, space=space),
            out / "policy_map",
            pool,
        )
        parts.append(out / "policy_map" / "summary.md")
    text = "\n".join(p.read_text() for p in parts)
    (out / "README.md").write_text(text)
    print(text)
    more = [out / "strategy"] if space != "paper" and args.strategy_races else []
    more += [out / "policy_map"] if args.policy_thetas else []
    print(
        f"wrote {out / 'README.md'}, {out / 'paper_table'}, {control}, {comparison}, "
        f"{out / 'analysis'}" + "".join(f" and {m}" for m in more)
    )
    return 0


def add_reproduce(command) -> None:
    """``alpha-racer reproduce``."""
    from agents.theta import SPACES
    from experiments.analysis.nash import AnalyzeConfig
    from experiments.cli.reproduce_fullsize import FULLSIZE_OUT, FULLSIZE_TRACKS
    from experiments.evaluation.control import ControlConfig
    from experiments.evaluation.policy_map import PolicyMapConfig

    rp = command(
        "reproduce",
        _cmd_reproduce,
        "every table and figure of the paper into one folder: "
        "bench --paper-table, the same races with the best fixed theta "
        "(the control), then analyze, then the policy map (resumable); "
        "--space extended: the same on the extended policy space, plus the strategy benchmark; "
        "--vehicle-class fullsize: the full-size world's control, strategy suite, room and "
        "pass ladder",
    )
    add_options(
        rp,
        AnalyzeConfig,
        (
            "--space",
            "policy space of the ego, the control and the analyses: paper (the paper's "
            "Table 1 and figures), or extended (ego alpha:space=extended, the shipped "
            "extended model or --model; control mpc:space=extended,theta=best; plus the "
            "strategy benchmark)",
            {"choices": sorted(SPACES), "default": "paper"},
        ),
        (
            "--out",
            RESUME_HELP
            + " (default "
            + ", ".join(f"{v} for --space {k}" for k, v in REPRODUCE_OUT.items())
            + f", {FULLSIZE_OUT.format(space='SPACE')} for --vehicle-class fullsize)",
            {"default": None},
        ),
        (
            "--races",
            "races per paper case (default: 99; 24 with --vehicle-class fullsize, 0 skips "
            "its Table 1)",
            {"type": int, "default": None},
        ),
        ("--steps", "steps per race (and per analysis race)", {"default": 500}),
        (
            "--control-ego",
            "an extra row besides the control (the five cases with the best fixed "
            "theta, mpc:theta=best or mpc:space=extended,theta=best): the five cases with this ego (mpc: the "
            "fixed-theta MPC at its default zeta 0.9); none skips it",
            {"default": "mpc"},
        ),
        (
            "--control-thetas",
            "if the best-theta table lacks the track: thetas of the control "
            "selection (alpha-racer control, into OUT/control, --steps steps)",
            {"default": ControlConfig.thetas},
        ),
        (
            "--control-races",
            "if the best-theta table lacks the track: playoff races per candidate",
            {"default": ControlConfig.races},
        ),
        (
            "--control-refine",
            "if the best-theta table lacks the track: rounds of the control's compass search",
            {"default": ControlConfig.refine},
        ),
        (
            "--policy-thetas",
            "thetas of the policy map (policy-map's default tracks, both modes, "
            "--steps steps); 0 skips it",
            {"default": PolicyMapConfig.thetas},
        ),
        (
            "--strategy-races",
            "--space extended: races per bench of the strategy benchmark (alpha-racer "
            "strategy, every scenario, on default; into OUT/strategy); 0 skips it "
            "(default: 99; 24 with --vehicle-class fullsize, where 0 is not allowed)",
            {"type": int, "default": None},
        ),
        (
            "--strategy-steps",
            "--space extended or --vehicle-class fullsize: steps of 0.1 s per strategy race "
            "(default: 200; 600 with --vehicle-class fullsize)",
            {"type": int, "default": None},
        ),
        *CLASS_OPTIONS,
        (
            "--fullsize-tracks",
            "--vehicle-class fullsize: the circuits of the strategy suite, the first the "
            "one the model was trained on (and the ladder's)",
            {"nargs": "+", "default": list(FULLSIZE_TRACKS)},
        ),
        (
            "--alpha-options",
            "--vehicle-class fullsize: options added to the alpha ego's spec, e.g. "
            "anchor=best,others=estimate (the potential's choice among the oracle's "
            "candidates, the others' thetas read from their play); default none",
            {"default": None},
        ),
        (
            "--room-races",
            "--vehicle-class fullsize: the oracle's races per bench and circuit (the first "
            "of the suite's equal and defend races); 0 skips the room",
            {"type": int, "default": 12},
        ),
        (
            "--ladder-races",
            "--vehicle-class fullsize: races per rung of the pass ladder; 0 skips it",
            {"type": int, "default": 16},
        ),
        IMPORT_OPTION,
        *ANALYZE_OPTIONS,
        *PARALLEL_OPTIONS,
        default_in_help=True,
    )
