"""The ``alpha-racer`` command line: ``race``, ``agents``, ``tracks``, ``raceline``, ``fuzz``,
``collect``, ``train``, ``selfplay``, ``bench``, ``league``, ``strategy``, ``analyze``,
``reproduce``, ``general-report``, ``policy-map``, ``control``."""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from pathlib import Path

from racing_env.extras import MissingExtraError

DEFAULT_AGENTS = ["alpha", "ibr", "ibr"]  # the paper's case IV: alpha against two IBR cars
LEAGUE_AGENTS = ("alpha", "mpc", "ibr", "ppo", "raceline")  # every shipped agent
# options named otherwise than the config fields they set: option name -> field
_SELFPLAY_FIELDS = {
    "cars": "n_cars",
    "envs": "n_envs",
    "epochs": "n_epochs",
    "lr": "learning_rate",
    "race_steps": "max_cycles",
}
_BENCH_FIELDS = {"cars": "n_cars"}


def _config(cls, args, renamed: dict | None = None, **values):
    """The config dataclass ``cls`` from the parsed options ``args``: each field that an option
    of the same name sets, or of the name ``renamed`` maps to the field (a list as a tuple;
    None, an option not given, leaves the field's default), and ``values`` for the fields set
    otherwise."""
    values = {field: getattr(args, name) for name, field in (renamed or {}).items()} | values
    given = {
        f.name: getattr(args, f.name)
        for f in dataclasses.fields(cls)
        if f.name not in values and getattr(args, f.name, None) is not None
    }
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in given.items()}, **values)


def _pool(args):
    """The drivers' :class:`~experiments.infra.parallel.Pool` of ``--workers``, ``--backend`` and
    ``--address``."""
    from experiments.infra.parallel import Pool

    return Pool(args.workers, args.backend, args.address)


def _cmd_race(args) -> int:
    from experiments.evaluation.race import (
        check_animation_format,
        run_race,
        start_order,
        write_outputs,
    )

    if not args.no_animation:
        check_animation_format(args.format)  # before the race, not after it
    result, frames = run_race(
        args.agents,
        track=args.track,
        seed=args.seed,
        max_cycles=args.steps,
        start=args.start,
        laps=args.laps,
        render=not args.no_animation,
        order=start_order(args.regions, len(args.agents), args.start),
    )
    print(result.table())
    paths = write_outputs(result, frames, Path(args.out), animation=args.format)
    for kind, p in paths.items():
        print(f"{kind}: {p}")
    return 0


def _cmd_agents(args) -> int:
    from agents import agent_names, agent_parameters
    from agents.base import REQUIRED, get_factory

    for name in agent_names():
        try:
            params, open_kwargs = agent_parameters(name)
            doc = " ".join(
                (getattr(get_factory(name), "__doc__", None) or "").strip().split("\n\n")[0].split()
            )
            doc = doc.split(". ")[0].rstrip(".")
        except ValueError as exc:  # a broken plugin: say so, list the others
            print(f"{name}: {exc}")
            continue
        print(f"{name}: {doc}" if doc else name)
        for p in params:
            default = "(required)" if p.default is REQUIRED else f"= {p.default!r}"
            bounds = f"  in [{p.bounds[0]:g}, {p.bounds[1]:g}]" if p.bounds else ""
            note = f"  ({p.note})" if p.note else ""
            print(f"    {p.name} {default}{bounds}{note}")
        if open_kwargs:
            print("    ... and further keywords")
        if not params and not open_kwargs:
            print("    (no parameters)")
    return 0


def _cmd_tracks(args) -> int:
    from racing_env.tracks import make_track, track_names

    for name in track_names():
        if args.details:
            t = make_track(name)
            print(f"{name:<28} {t.length:8.2f} m  width {t.width.min():.3f}..{t.width.max():.3f} m")
        else:
            print(name)
    print("random:SEED                  (procedural, any integer seed)")
    return 0


def _cmd_raceline(args) -> int:
    from racing_env.raceline import RacelineConfig, get_raceline, plot_raceline
    from racing_env.tracks import make_track

    track = make_track(args.track, scale=args.scale)
    rl = get_raceline(track, config=RacelineConfig(objective=args.objective))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = track.name.replace(":", "_")
    rl.to_csv(out / f"{stem}_raceline.csv")
    plot_raceline(track, rl, out / f"{stem}_raceline.png")
    print(
        f"{track!r}\nracing line: {len(rl.s)} points, length {rl.length:.2f} m, "
        f"speed {rl.vx.min():.2f}..{rl.vx.max():.2f} m/s, lap time estimate {rl.lap_time:.2f} s "
        f"(mu = {rl.mu_nominal}), {rl.iterations} QP iterations, {rl.compute_time:.2f} s"
        + (f", shortest-path weight {rl.length_weight:.3g}" if args.objective == "lap_time" else "")
    )
    print(f"wrote {out / f'{stem}_raceline.csv'} and {out / f'{stem}_raceline.png'}")
    return 0


def _cmd_fuzz(args) -> int:
    from experiments.evaluation.fuzz import run_fuzz

    report = run_fuzz(
        steps=args.steps, n_races=args.races, n_cars=args.cars, track=args.track, seed=args.seed
    )
    print(report.text())
    return 0 if report.ok else 1


def _cmd_collect(args) -> int:
    from experiments.potential.collect import CollectConfig, collect
    from experiments.potential.family import FamilyConfig, collect_family, parse_cars

    cars = parse_cars(args.cars)
    if args.tracks is None and len(cars) == 1:  # one track, one field size: as always
        cfg = _config(
            CollectConfig,
            args,
            n_cars=cars[0],
            track=args.track or "default",
            races_per_shard=args.shard_size or 25,
        )
        summary = collect(cfg, args.out, _pool(args))
    else:
        if args.track is not None and args.tracks is not None:
            raise ValueError(
                f"give either --track ({args.track!r}) or --tracks "
                f"({' '.join(args.tracks)}), not both"
            )
        cfg = _config(
            FamilyConfig,
            args,
            tracks=tuple(args.tracks or [args.track or "default"]),
            cars=cars,
            races_per_shard=args.shard_size or 4,
        )
        summary = collect_family(cfg, args.out, _pool(args))
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
        _config(TrainConfig, args),
        command="alpha-racer " + " ".join(args.argv),
        space=args.space,
    )
    print(f"model: {Path(args.out) / 'model.npz'}")
    return 0


def _cmd_selfplay(args) -> int:
    from experiments.learning.selfplay import SelfPlayConfig, selfplay

    cfg = _config(SelfPlayConfig, args, _SELFPLAY_FIELDS, mpc_reference=not args.no_mpc_reference)
    s = selfplay(cfg, args.out, max_turns=args.max_turns)
    print(
        f"{s['turns']}/{cfg.turns} turns, {s['total_steps']} env steps in {s['train_seconds']:.0f} s "
        f"of training ({s['steps_per_s']} steps/s) -> {s['out']}"
    )
    if s["best"]:
        b = s["best"]
        print(
            f"best: car {b['car']} alone {b['distance_m']:.1f} m in {cfg.max_cycles / 10:.0f} s"
            + (
                f" ({100 * b['distance_vs_mpc']:.0f}% of the MPC's "
                f"{s['mpc_reference']['distance_m']:.1f} m)"
                if b.get("distance_vs_mpc")
                else ""
            )
            + f", off track {100 * b['off_track_frac']:.1f}% of steps -> {Path(s['out']) / 'best.zip'}"
        )
    return 0


def _cmd_bench(args) -> int:
    from experiments.evaluation.bench import BenchConfig, bench, paper_table
    from experiments.infra.artifacts import slug

    if args.space is not None and not args.paper_table:
        raise ValueError(f"--space {args.space} chooses the opponents of --paper-table; add it")
    if args.paper_table:
        if args.cars != 3:
            raise ValueError(f"--paper-table is the paper's 3-car protocol; got --cars {args.cars}")
        out = args.out or "results/paper_table"
        t = paper_table(
            out,
            ego=args.ego,
            races=99 if args.races is None else args.races,
            steps=args.steps,
            track=args.track,
            seed=args.seed,
            cases=args.cases,
            pool=_pool(args),
            space=args.space or "paper",
        )
        print((Path(out) / "paper_table.md").read_text())
        print(
            f"wrote {Path(out) / 'paper_table.md'} and {Path(out) / 'paper_table.json'} "
            f"({t['wall_seconds_this_run'] / 60:.1f} min)"
        )
        return 0
    races = args.races if args.races is not None else (99 if args.cars == 3 else 33 * args.cars)
    cfg = _config(BenchConfig, args, _BENCH_FIELDS, races=races)
    field = "" if args.cars == 3 else f"_{args.cars}cars"
    out = Path(args.out or f"results/bench/{slug(args.ego)}_vs_{slug(args.opponents)}{field}")
    bench(cfg, out, _pool(args))
    print((out / "summary.md").read_text())
    print(f"wrote {out / 'summary.md'}, {out / 'summary.json'} and {out / 'races.jsonl'}")
    return 0


def _cmd_league(args) -> int:
    from experiments.evaluation.league import LeagueConfig, league

    out = Path(args.out)
    board = league(_config(LeagueConfig, args), out, _pool(args), imports=args.imports)
    print((out / "leaderboard.md").read_text())
    print(
        f"{board['new_races']} new races; wrote {out / 'leaderboard.md'}, "
        f"{out / 'leaderboard.json'}, {out / 'races.jsonl'}, {out / 'ratings.png'} and "
        f"{out / 'pairwise.png'}"
    )
    return 0


def _cmd_strategy(args) -> int:
    from experiments.evaluation.strategy import StrategyConfig, strategy

    out = Path(args.out)
    t = strategy(_config(StrategyConfig, args), out, _pool(args))
    print((out / "strategy.md").read_text())
    print(f"{t['new_races']} new races; wrote {out / 'strategy.md'} and {out / 'strategy.json'}")
    return 0


def _analyze_config(args):
    from experiments.analysis.nash import AnalyzeConfig

    return _config(AnalyzeConfig, args)


def _cmd_analyze(args) -> int:
    from experiments.analysis.nash import analyze

    out = Path(args.out)
    analyze(
        _analyze_config(args),
        out,
        bench_dirs=args.bench or (),
        force=args.force,
        pool=_pool(args),
    )
    print((out / "summary.md").read_text())
    print(f"wrote figures and JSON into {out}")
    return 0


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

    cfg = replace(_analyze_config(args), steps=args.steps)
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


def _cmd_reproduce(args) -> int:
    """Every table and figure: the paper table, the same races with the best fixed theta (the
    control, selected first if the best-theta table lacks the track) and the extra fixed ego,
    their comparison, then the analyses (each resumable). With ``--space extended`` the same
    on the extended policy space (ego, control, analyses and policy map), plus the strategy
    benchmark of the ego against the control."""
    import json

    from experiments.analysis.nash import analyze
    from experiments.evaluation.bench import PAPER_CASES, comparison_markdown, paper_table
    from experiments.evaluation.control import ControlConfig, best_fixed_spec, ensure_best_thetas
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
    pool = _pool(args)
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


def _cmd_general_report(args) -> int:
    from experiments.analysis.general import GeneralReportConfig, general_report

    out = Path(args.out)
    general_report(
        _config(GeneralReportConfig, args, tracks=tuple(args.tracks or ())),
        out,
        _pool(args),
        command="alpha-racer " + " ".join(args.argv),
        control_dir=args.control_out,
    )
    print((out / "summary.md").read_text())
    print(f"wrote {out / 'summary.md'} and {out / 'summary.json'}")
    return 0


def _cmd_policy_map(args) -> int:
    from experiments.evaluation.policy_map import PolicyMapConfig, policy_map

    out = Path(args.out)
    s = policy_map(_config(PolicyMapConfig, args), out, _pool(args))
    print((out / "summary.md").read_text())
    print(
        f"{s['new_rows']} new rows; wrote {out / 'summary.md'}, {out / 'summary.json'}, "
        f"{out / 'rows.jsonl'} and heat maps into {out}"
    )
    return 0


def _cmd_control(args) -> int:
    from experiments.evaluation.control import ControlConfig, default_out, select_best_thetas
    from experiments.potential.family import expand_tracks

    cfg = _config(ControlConfig, args)
    out = Path(args.out or default_out(cfg.space))
    s = select_best_thetas(
        cfg,
        expand_tracks(args.tracks),
        out,
        install_table=not args.no_install,
        table=args.table,
        pool=_pool(args),
    )
    print((out / "summary.md").read_text())
    from agents.best_theta import table_path

    print(
        f"{s['new_map_runs']} new map runs and {s['new_races']} new playoff races in "
        f"{s['wall_seconds_this_run'] / 60:.1f} min; wrote {out / 'summary.md'} and "
        f"<track>/selection.json"
        + ("" if args.no_install else f"; installed into {args.table or table_path()}")
    )
    return 0


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, except where the default is None or empty
    (the help then says what applies)."""

    def _get_help_string(self, action):
        if action.default is None or action.default == []:
            return action.help
        return super()._get_help_string(action)


def _add_options(
    p, config, *rows, renamed: dict | None = None, default_in_help: bool = False
) -> None:
    """Add the options ``rows`` to ``p``, in order: each ``(flag, help)`` or ``(flag, help,
    keywords)`` (further keywords of ``add_argument``).

    An option sets the field of the config dataclass ``config`` named like its flag
    (``--gap-races``: ``gap_races``, or as ``renamed`` maps that name) and defaults to that
    field's default (a tuple as a list, as ``nargs`` gives it), unless the keywords give a
    ``default``. With ``default_in_help`` the option's default is None instead (the config's
    applies) and ``{default}`` in the help stands for the field's. Unless the keywords say
    otherwise, the type is the default's when that is a number."""
    for flag, help, *more in rows:
        kw = dict(*more)
        name = flag[2:].replace("-", "_")
        field = (renamed or {}).get(name, name)
        if "default" in kw:
            value = kw["default"]
        else:
            value = getattr(config, field)
            help = help.format(default=_words(value) if isinstance(value, tuple) else value)
            kw["default"] = None if default_in_help else _listed(value)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            kw.setdefault("type", type(value))
        p.add_argument(flag, help=help, **kw)


def _listed(value):
    return list(value) if isinstance(value, tuple) else value


_SWITCH = {"action": "store_true", "default": False}  # an option that is off unless given

# the process pool's options, the agent modules' and the analyses' (each a table of rows of
# _add_options)
_PARALLEL_OPTIONS = (
    (
        "--workers",
        "worker processes (Ray CPUs with --backend ray); 1 runs in this process",
        {"default": os.cpu_count() or 1},
    ),
    (
        "--backend",
        "local process pool or a Ray cluster (pip install alpha-racer[ray])",
        {"choices": ["local", "ray"], "default": "local"},
    ),
    (
        "--address",
        "Ray cluster address (e.g. auto or ray://host:10001); default: start a local Ray",
        {"default": None},
    ),
)
_IMPORT_OPTION = (
    "--import",
    "import MODULE (a module name, or a .py file) before the agent specs are "
    "read, so that the agents it registers can race; repeatable",
    {"dest": "imports", "action": "append", "default": [], "metavar": "MODULE"},
)
_ANALYZE_OPTIONS = (  # of experiments.analysis.nash.AnalyzeConfig, with default_in_help
    ("--model", "alpha-potential model: shipped name or path (default: {default})"),
    ("--heldout-races", "fresh races for the gap (default {default})"),
    ("--gap-pairs", "deviations for the gap (default {default})"),
    ("--regret-states", "race states for the regret (default {default})"),
    ("--regret-horizon", "rollout steps before V (default {default})"),
    ("--cem-iterations", "CEM iterations of the regret search (default {default})"),
    ("--cem-samples", "candidates per CEM iteration (default {default})"),
    ("--slice-points", "values per parameter in Figure 3 (default {default})"),
)


def _version() -> str:
    """The installed distribution's version, else (a source tree) the package's."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("alpha-racer")
    except PackageNotFoundError:
        from experiments import __version__

        return __version__


_TRACK_HELP = "default, oval, random:SEED, tumftm:NAME or a TUMFTM .csv path"
_RESUME_HELP = "output folder; run again to resume"


def build_parser() -> argparse.ArgumentParser:
    # the options' defaults are read from the config dataclasses (one place for each default;
    # tests/test_cli_defaults.py checks them)
    from agents.theta import SPACES
    from experiments.analysis.general import GeneralReportConfig
    from experiments.analysis.nash import AnalyzeConfig
    from experiments.evaluation.bench import BenchConfig
    from experiments.evaluation.control import ControlConfig
    from experiments.evaluation.league import LeagueConfig
    from experiments.evaluation.policy_map import DEFAULT_TRACKS, MODES, PolicyMapConfig
    from experiments.evaluation.strategy import SCENARIOS, StrategyConfig
    from experiments.learning.selfplay import SelfPlayConfig
    from experiments.potential.collect import (
        PACE_SPREAD,
        PACE_SPREADS,
        PACES,
        START_REGIONS,
        CollectConfig,
    )
    from experiments.potential.nets import OBJECTIVES, TrainConfig

    p = argparse.ArgumentParser(
        prog="alpha-racer", description=__doc__, formatter_class=_HelpFormatter
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    def command(name, fn, help, description=None):
        """A subcommand ``name`` that runs ``fn(args)``."""
        parser = sub.add_parser(
            name, help=help, description=description or help, formatter_class=_HelpFormatter
        )
        parser.set_defaults(fn=fn)
        return parser

    r = command("race", _cmd_race, "race agents head to head, print the result, write an animation")
    _add_options(
        r,
        None,
        (
            "--agents",
            "one agent spec per car: an agent name (alpha-racer agents lists them) "
            "with optional parameters, e.g. raceline:grip=0.75",
            {"nargs": "+", "default": DEFAULT_AGENTS},
        ),
        ("--track", _TRACK_HELP, {"default": "default"}),
        ("--seed", "seed of the start positions and the agents", {"default": 0}),
        ("--steps", "control periods of 0.1 s", {"default": 500}),
        (
            "--laps",
            "end when the first car completes this many laps (default: run all steps)",
            {"type": int, "default": None},
        ),
        (
            "--start",
            "start positions: the paper's start regions, a grid, or random",
            {"choices": ["regions", "grid", "random"], "default": "regions"},
        ),
        (
            "--regions",
            "with --start regions: each car's start region, in the order of --agents "
            "(R1 the front-most), e.g. R2 R1 R3 (default: an order drawn from the seed)",
            {"nargs": "+", "default": None},
        ),
        ("--out", "output folder", {"default": "results/race"}),
        (
            "--format",
            "animation format (mp4 needs ffmpeg)",
            {"choices": ["gif", "mp4"], "default": "gif"},
        ),
        ("--no-animation", "write no animation (faster)", _SWITCH),
        _IMPORT_OPTION,
    )

    ag = command("agents", _cmd_agents, "list every agent with its parameters, defaults and bounds")
    _add_options(ag, None, _IMPORT_OPTION)

    t = command("tracks", _cmd_tracks, "list the available tracks")
    t.add_argument("--details", action="store_true", help="build each track and print its size")

    rl = command(
        "raceline",
        _cmd_raceline,
        "compute a track's racing line (minimum curvature, or shortest lap)",
    )
    rl.add_argument("--track", default="default", help=_TRACK_HELP)
    rl.add_argument(
        "--scale", type=float, default=None, help="length scale for TUMFTM data (default 1/43)"
    )
    rl.add_argument(
        "--objective",
        choices=("curvature", "lap_time"),
        default="curvature",
        help="curvature: the paper's minimum-curvature line (default); lap_time: "
        "curvature plus a shortest-path term, weighed for the shortest lap "
        "estimate",
    )
    rl.add_argument("--out", default="results/raceline", help="output folder for the CSV and PNG")

    f = command(
        "fuzz",
        _cmd_fuzz,
        "random-action fuzz of the simulator: no NaN, no exception, states in bounds",
    )
    f.add_argument(
        "--steps",
        type=int,
        default=1_000_000,
        help="race steps (each advances every car of one race)",
    )
    f.add_argument("--races", type=int, default=256, help="races stepped at once")
    f.add_argument("--cars", type=int, default=3, help="cars per race")
    f.add_argument("--track", default="default", help="track spec (as for race)")
    f.add_argument("--seed", type=int, default=0, help="seed of the random actions and starts")

    c = command(
        "collect",
        _cmd_collect,
        "simulate races of MPC cars with random theta (resumable shards)",
        "simulate races of MPC cars with random theta (resumable shards); with --tracks "
        "or several --cars, a family collection over tracks and field sizes (one track "
        "and one field size per shard) for the general alpha-potential",
    )
    _add_options(
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
        ("--track", "track spec (as for race; default: default)", {"default": None}),
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
            "long, 0.1 m apart: more passing and blocking)",
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
        ("--out", _RESUME_HELP, {"default": "data/races"}),
        *_PARALLEL_OPTIONS,
    )

    tr = command(
        "train", _cmd_train, "fit the value and alpha-potential networks on collected races"
    )
    tr.add_argument(
        "--data", default="data/races", help="a directory written by `alpha-racer collect`"
    )
    tr.add_argument("--out", default="models/alpha", help="output directory (resumes if it exists)")
    _add_options(
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

    sp = command("selfplay", _cmd_selfplay, "train PPO agents by iterated self-play (resumable)")
    sp.add_argument("--out", default="runs/selfplay", help=_RESUME_HELP)
    _add_options(
        sp,
        SelfPlayConfig,
        ("--cars", "cars per race"),
        ("--cycles", "self-play cycles (each car learns once per cycle)"),
        ("--steps-per-turn", "env steps per learning turn"),
        ("--envs", "parallel races"),
        ("--batch-size", "PPO minibatch size"),
        ("--epochs", "PPO epochs per rollout"),
        ("--lr", "PPO learning rate"),
        ("--gamma", "discount factor"),
        ("--n-steps", "rollout length per env"),
        ("--track", "track spec (as for race)"),
        ("--race-steps", "steps of 0.1 s per race (episode)"),
        ("--seed", "seed of the envs and the policies"),
        (
            "--vec-env",
            "vectorised env: our batched one, or SB3's DummyVecEnv/SubprocVecEnv",
            {"choices": ["batched", "dummy", "subproc"]},
        ),
        (
            "--warmup-opponent",
            "who drives a car before its first turn",
            {"choices": ["raceline", "initial"]},
        ),
        (
            "--init",
            "a car's policy before its first turn: random (plain self-play) or "
            "behaviour-cloned from the raceline follower",
            {"choices": ["random", "bc"]},
        ),
        ("--bc-steps", "expert samples for --init bc"),
        ("--checkpoint-every", "rollouts between in-turn checkpoints"),
        ("--eval-races", "solo evaluation races after each turn"),
        renamed=_SELFPLAY_FIELDS,
    )
    sp.add_argument("--no-mpc-reference", action="store_true", help="skip measuring the MPC alone")
    sp.add_argument(
        "--max-turns",
        type=int,
        default=None,
        help="stop after this many turns (resumable; default: all)",
    )

    b = command(
        "bench",
        _cmd_bench,
        "head-to-head benchmark: the ego against two opponents of one kind from "
        "the paper's start regions (resumable)",
        "head-to-head benchmark: the ego against two opponents of one kind from the "
        "paper's start regions, or against N - 1 from N regions with --cars N (resumable)",
    )
    _add_options(
        b,
        BenchConfig,
        ("--ego", "the ego's agent spec"),
        ("--opponents", "agent spec of every opponent O1, O2, ..."),
        (
            "--cars",
            "cars per race (2..8): N start regions, the ego from each equally often, "
            "the opponents in the other regions front to back",
        ),
        ("--paper-table", "run the paper's five cases (Table 1) and write paper_table.md", _SWITCH),
        (
            "--cases",
            "with --paper-table: a subset of I II III IV V (default: all)",
            {"nargs": "+", "default": None},
        ),
        (
            "--space",
            "with --paper-table: the policy space of cases I-III's learned opponents (paper: "
            "the paper's models; extended: the extended space's models of the same kinds)",
            {"choices": ["paper", "extended"], "default": None},
        ),
        (
            "--races",
            f"races per benchmark, a multiple of --cars (default {BenchConfig.races} with "
            f"3 cars: {BenchConfig.races // 3} per region; {BenchConfig.races // 3} N "
            "with N cars)",
            {"type": int, "default": None},
        ),
        ("--steps", "steps of 0.1 s per race (500 = 50 s)"),
        ("--track", "track spec (as for race)"),
        ("--seed", "seed of the races' start orders and agents"),
        (
            "--out",
            "output folder (default results/bench/EGO_vs_OPPONENTS, or "
            "results/paper_table with --paper-table); run again to resume",
            {"default": None},
        ),
        _IMPORT_OPTION,
        *_PARALLEL_OPTIONS,
        renamed=_BENCH_FIELDS,
    )

    lg = command(
        "league",
        _cmd_league,
        "round-robin league of any agents: every group of --cars agents on "
        "every track from rotated start regions, rated with openskill "
        "(Plackett-Luce) into a leaderboard (resumable)",
    )
    _add_options(
        lg,
        LeagueConfig,
        (
            "--agents",
            "distinct agent specs, each one player of the rating (as for race; "
            "e.g. alpha:model=gamma0.98, mpc:zeta=1.0)",
            {"nargs": "+", "default": list(LEAGUE_AGENTS)},
        ),
        ("--tracks", "track specs (as for race)", {"nargs": "+"}),
        ("--cars", "cars per race, 2..8; at most the number of agents"),
        ("--rounds", "times the whole schedule runs, each with new seeds"),
        ("--steps", "steps of 0.1 s per race (500 = 50 s)"),
        ("--seed", "seed of the group sample, the start positions and the agents"),
        (
            "--max-groups",
            "groups per round: every --cars-subset of the agents when there are at "
            "most this many, else a balanced sample of at most this many (whole blocks "
            "in which every agent races equally often; at least one)",
        ),
        ("--out", _RESUME_HELP, {"default": "results/league"}),
        _IMPORT_OPTION,
        *_PARALLEL_OPTIONS,
    )

    sg = command(
        "strategy",
        _cmd_strategy,
        "strategy benchmark: scenarios that isolate maneuvers (pass slower "
        "cars, equal pace, defend against faster cars, the paper's Table-1 "
        "opponents) for the ego and a control ego in the same seats and "
        "races (resumable)",
    )
    _add_options(
        sg,
        StrategyConfig,
        ("--ego", "the ego's agent spec"),
        (
            "--control",
            "the control ego's agent spec, raced in the same seats and races; "
            "also the opponents of equal and defend",
        ),
        ("--tracks", "track specs", {"nargs": "+"}),
        (
            "--scenarios",
            "scenarios to run (table1 is three benches: ibr, ppo, alpha opponents)",
            {"nargs": "+", "choices": list(SCENARIOS)},
        ),
        ("--races", "races per bench"),
        (
            "--steps",
            "steps of 0.1 s per race (the default fits the full suite in 45 min on 2 cores)",
        ),
        ("--zeta-max", "defend: the ego's zeta ceiling (the same for ego and control)"),
        (
            "--pass-opponents",
            "pass: the agent spec of the two slower cars that do not yield "
            "(e.g. raceline:grip=0.9 for followers slower in the corners only)",
        ),
        ("--seed", "seed of the races' start positions and agents"),
        ("--out", _RESUME_HELP, {"default": "results/strategy"}),
        *_PARALLEL_OPTIONS,
    )

    a = command(
        "analyze",
        _cmd_analyze,
        "Nash analyses of an alpha-potential model: approximation gap, Nash "
        "regret by simulation, potential slices, figures",
    )
    _add_options(
        a,
        AnalyzeConfig,
        ("--out", _RESUME_HELP, {"default": "results/analysis"}),
        (
            "--bench",
            "benchmark folders to take the overtake animation from (default: none)",
            {"nargs": "*", "default": None},
        ),
        ("--force", "redo parts whose outputs exist", _SWITCH),
        *_ANALYZE_OPTIONS,
        *_PARALLEL_OPTIONS,
        default_in_help=True,
    )

    rp = command(
        "reproduce",
        _cmd_reproduce,
        "every table and figure of the paper into one folder: "
        "bench --paper-table, the same races with the best fixed theta "
        "(the control), then analyze, then the policy map (resumable); "
        "--space extended: the same on the extended policy space, plus the strategy benchmark",
    )
    _add_options(
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
            _RESUME_HELP
            + " (default "
            + ", ".join(f"{v} for --space {k}" for k, v in REPRODUCE_OUT.items())
            + ")",
            {"default": None},
        ),
        ("--races", "races per paper case", {"default": 99}),
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
            "strategy, every scenario, on default; into OUT/strategy); 0 skips it",
            {"default": StrategyConfig.races},
        ),
        (
            "--strategy-steps",
            "--space extended: steps of 0.1 s per strategy race",
            {"default": StrategyConfig.steps},
        ),
        _IMPORT_OPTION,
        *_ANALYZE_OPTIONS,
        *_PARALLEL_OPTIONS,
        default_in_help=True,
    )

    gr = command(
        "general-report",
        _cmd_general_report,
        "the general alpha-potential on held-out tracks: "
        "approximation gap for N cars, races in the N-car protocol "
        "beside the best fixed theta on each track (the control), "
        "and against the single-track default model on default "
        "(resumable)",
    )
    _add_options(
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
            {"default": _commas(GeneralReportConfig.gap_cars)},
        ),
        ("--gap-races", "fresh races per field size for the gap"),
        ("--gap-pairs", "unilateral deviations per field size"),
        (
            "--bench-cars",
            "field sizes of the N-car races",
            {"default": _commas(GeneralReportConfig.bench_cars)},
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
        ("--out", _RESUME_HELP, {"default": "results/general"}),
        *_PARALLEL_OPTIONS,
    )

    ct = command(
        "control",
        _cmd_control,
        "choose the best fixed theta per track by a rule from measurements "
        "(policy map, top candidates, seeded playoff) and install it for "
        "mpc:theta=best, or mpc:space=extended,theta=best with --space extended (resumable)",
    )
    _add_options(
        ct,
        ControlConfig,
        (
            "--tracks",
            "track specs (random:A-B ranges allowed)",
            {"nargs": "+", "default": ["default"]},
        ),
        ("--thetas", "Sobol thetas of each track's policy map (solo and race)"),
        (
            "--candidates",
            "K: thetas taken to the playoff by region-adjusted race progress "
            "(plus the best solo theta)",
        ),
        (
            "--races",
            "playoff races per candidate, a multiple of 3 (every start region equally often)",
        ),
        ("--steps", "steps of 0.1 s per run (map and playoff)"),
        (
            "--refine",
            "rounds of the compass search from the playoff's winner: each parameter moved "
            "to the box's faces (then half as far), raced in the playoff's races; 0 for none",
        ),
        ("--opponents", "agent spec of the two other cars (map race mode and playoff)"),
        (
            "--seed",
            "seed of the Sobol sample, the map's starts and the playoff races "
            "(not 0, the benchmarks' seed)",
        ),
        (
            "--space",
            "policy space whose box is searched (extended adds b, the weight of the "
            "lap-time line; its winner is raced by mpc:space=extended,theta=best)",
            {"choices": sorted(SPACES)},
        ),
        (
            "--out",
            _RESUME_HELP
            + " (default results/control, results/control_extended for --space extended)",
            {"default": None},
        ),
        ("--no-install", "only measure: leave the best-theta table unchanged", _SWITCH),
        (
            "--table",
            "best-theta table to install into (default: the package's "
            "agents/models/best_fixed_theta.json, or $ALPHA_RACER_BEST_THETA_TABLE)",
            {"default": None},
        ),
        *_PARALLEL_OPTIONS,
    )

    pm = command(
        "policy-map",
        _cmd_policy_map,
        "sweep the MPC policy space (q, zeta, s1, s2, s3): Sobol thetas, "
        "solo and 3-car runs, summary and heat maps (resumable)",
    )
    _add_options(
        pm,
        PolicyMapConfig,
        ("--thetas", "Sobol points of the theta box (a power of two keeps the sequence balanced)"),
        ("--tracks", "track specs", {"nargs": "+", "default": list(DEFAULT_TRACKS)}),
        (
            "--modes",
            "solo: the theta car alone from the grid; race: against two "
            "--opponents cars from the start regions",
            {"nargs": "+", "choices": list(MODES), "default": list(MODES)},
        ),
        ("--opponents", "agent spec of the two opponents of the race mode"),
        (
            "--space",
            "policy space whose box is mapped (extended adds b, the weight of the lap-time line)",
            {"choices": sorted(SPACES)},
        ),
        ("--steps", "steps of 0.1 s per run"),
        ("--seed", "Sobol scrambling and start seed"),
        *_PARALLEL_OPTIONS,
        ("--out", _RESUME_HELP, {"default": "results/policy_map"}),
    )
    return p


def _words(values) -> str:
    return " ".join(str(v) for v in values)


def _commas(values) -> str:
    return ",".join(str(v) for v in values)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        if getattr(args, "imports", None):
            from agents import import_agent_modules

            import_agent_modules(args.imports)
        return args.fn(args)
    except (ValueError, MissingExtraError) as exc:
        print(f"alpha-racer {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
