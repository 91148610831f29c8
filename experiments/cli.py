"""The ``alpha-racer`` command line: ``race``, ``agents``, ``tracks``, ``raceline``, ``fuzz``,
``collect``, ``train``, ``selfplay``, ``bench``, ``league``, ``strategy``, ``analyze``,
``reproduce``, ``general-report``, ``policy-map``, ``control``."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from racing_env.extras import MissingExtraError

DEFAULT_AGENTS = ["alpha", "ibr", "ibr"]  # the paper's case IV: alpha against two IBR cars
LEAGUE_AGENTS = ("alpha", "mpc", "ibr", "ppo", "raceline")  # every shipped agent


def _cmd_race(args) -> int:
    from .race import check_animation_format, run_race, write_outputs

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
    from .fuzz import run_fuzz

    report = run_fuzz(
        steps=args.steps, n_races=args.races, n_cars=args.cars, track=args.track, seed=args.seed
    )
    print(report.text())
    return 0 if report.ok else 1


def _cmd_collect(args) -> int:
    from .collect import CollectConfig, collect
    from .family import FamilyConfig, collect_family, parse_cars

    cars = parse_cars(args.cars)
    kw = dict(workers=args.workers, backend=args.backend, address=args.address)
    if args.tracks is None and len(cars) == 1:  # one track, one field size: as always
        cfg = CollectConfig(
            races=args.races,
            n_cars=cars[0],
            steps=args.steps,
            track=args.track or "default",
            seed=args.seed,
            races_per_shard=args.shard_size or 25,
            space=args.space,
            start=args.start,
        )
        summary = collect(cfg, args.out, **kw)
    else:
        if args.track is not None and args.tracks is not None:
            raise ValueError(
                f"give either --track ({args.track!r}) or --tracks "
                f"({' '.join(args.tracks)}), not both"
            )
        if (args.space, args.start) != ("paper", "paper"):
            raise ValueError(
                f"--space {args.space} / --start {args.start} are options of a "
                f"one-track collection; a family collection races the paper's"
            )
        cfg = FamilyConfig(
            races=args.races,
            tracks=tuple(args.tracks or [args.track or "default"]),
            cars=cars,
            steps=args.steps,
            seed=args.seed,
            races_per_shard=args.shard_size or 4,
        )
        summary = collect_family(cfg, args.out, **kw)
    print(
        f"{summary['simulated']} races simulated ({summary['resumed']} already there) in "
        f"{summary['seconds']:.1f} s, {summary['races_per_s']:.3f} races/s -> {summary['out']}"
    )
    return 0


def _cmd_train(args) -> int:
    from .train import TrainConfig, train

    kw = {
        k: getattr(args, k)
        for k in (
            "gamma",
            "value_epochs",
            "potential_steps",
            "potential_batch",
            "objective",
            "val_fraction",
            "rollout_pairs",
            "rollout_steps",
            "seed",
            "threads",
        )
        if getattr(args, k) is not None
    }
    if args.value_hidden:
        kw["value_hidden"] = tuple(args.value_hidden)
    if args.potential_hidden:
        kw["potential_hidden"] = tuple(args.potential_hidden)
    train(
        args.data,
        args.out,
        TrainConfig(**kw),
        command="alpha-racer " + " ".join(args.argv),
        space=args.space,
    )
    print(f"model: {Path(args.out) / 'model.npz'}")
    return 0


def _cmd_selfplay(args) -> int:
    from .selfplay import SelfPlayConfig, selfplay

    cfg = SelfPlayConfig(
        n_cars=args.cars,
        cycles=args.cycles,
        steps_per_turn=args.steps_per_turn,
        n_envs=args.envs,
        batch_size=args.batch_size,
        n_epochs=args.epochs,
        learning_rate=args.lr,
        gamma=args.gamma,
        n_steps=args.n_steps,
        track=args.track,
        max_cycles=args.race_steps,
        seed=args.seed,
        vec_env=args.vec_env,
        warmup_opponent=args.warmup_opponent,
        checkpoint_every=args.checkpoint_every,
        eval_races=args.eval_races,
        mpc_reference=not args.no_mpc_reference,
        init=args.init,
        bc_steps=args.bc_steps,
    )
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
    from .artifacts import slug
    from .bench import BenchConfig, bench, paper_table

    kw = dict(workers=args.workers, backend=args.backend, address=args.address)
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
            **kw,
        )
        print((Path(out) / "paper_table.md").read_text())
        print(
            f"wrote {Path(out) / 'paper_table.md'} and {Path(out) / 'paper_table.json'} "
            f"({t['wall_seconds_this_run'] / 60:.1f} min)"
        )
        return 0
    races = args.races if args.races is not None else (99 if args.cars == 3 else 33 * args.cars)
    cfg = BenchConfig(
        ego=args.ego,
        opponents=args.opponents,
        races=races,
        steps=args.steps,
        track=args.track,
        seed=args.seed,
        n_cars=args.cars,
    )
    field = "" if args.cars == 3 else f"_{args.cars}cars"
    out = Path(args.out or f"results/bench/{slug(args.ego)}_vs_{slug(args.opponents)}{field}")
    bench(cfg, out, **kw)
    print((out / "summary.md").read_text())
    print(f"wrote {out / 'summary.md'}, {out / 'summary.json'} and {out / 'races.jsonl'}")
    return 0


def _cmd_league(args) -> int:
    from .league import LeagueConfig, league

    cfg = LeagueConfig(
        agents=tuple(args.agents),
        tracks=tuple(args.tracks),
        cars=args.cars,
        rounds=args.rounds,
        steps=args.steps,
        seed=args.seed,
        max_groups=args.max_groups,
    )
    out = Path(args.out)
    board = league(
        cfg,
        out,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        imports=args.imports,
    )
    print((out / "leaderboard.md").read_text())
    print(
        f"{board['new_races']} new races; wrote {out / 'leaderboard.md'}, "
        f"{out / 'leaderboard.json'}, {out / 'races.jsonl'}, {out / 'ratings.png'} and "
        f"{out / 'pairwise.png'}"
    )
    return 0


def _cmd_strategy(args) -> int:
    from .strategy import StrategyConfig, strategy

    cfg = StrategyConfig(
        ego=args.ego,
        control=args.control,
        tracks=tuple(args.tracks),
        scenarios=tuple(args.scenarios),
        races=args.races,
        steps=args.steps,
        seed=args.seed,
        zeta_max=args.zeta_max,
        pass_opponents=args.pass_opponents,
    )
    out = Path(args.out)
    t = strategy(cfg, out, workers=args.workers, backend=args.backend, address=args.address)
    print((out / "strategy.md").read_text())
    print(f"{t['new_races']} new races; wrote {out / 'strategy.md'} and {out / 'strategy.json'}")
    return 0


def _analyze_config(args):
    from .analyze import AnalyzeConfig

    kw = {
        k: getattr(args, k)
        for k in (
            "model",
            "heldout_races",
            "gap_pairs",
            "regret_states",
            "regret_horizon",
            "cem_iterations",
            "cem_samples",
            "slice_points",
        )
        if getattr(args, k, None) is not None
    }
    return AnalyzeConfig(**kw)


def _cmd_analyze(args) -> int:
    from .analyze import analyze

    out = Path(args.out)
    analyze(
        _analyze_config(args),
        out,
        bench_dirs=args.bench or (),
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        force=args.force,
    )
    print((out / "summary.md").read_text())
    print(f"wrote figures and JSON into {out}")
    return 0


def _cmd_reproduce(args) -> int:
    """Every table and figure: the paper table, the same races with the best fixed theta (the
    control, selected first if the best-theta table lacks the track) and the extra fixed ego,
    their comparison, then the analyses (each resumable)."""
    import json

    from .analyze import analyze
    from .artifacts import slug, write_text
    from .bench import PAPER_CASES, comparison_markdown, paper_table
    from .control import BEST_FIXED_SPEC, ControlConfig, ensure_best_thetas

    out = Path(args.out)
    kw = dict(workers=args.workers, backend=args.backend, address=args.address)
    track = "default"  # the paper table's track
    # the control: the same races with the best fixed theta on the track as ego, selected
    # first (resumable, into out/control) if the best-theta table lacks the track
    ctl = ControlConfig(thetas=args.control_thetas, races=args.control_races, steps=args.steps)
    entry = ensure_best_thetas([track], ctl, out / "control", **kw)[track]
    paper_table(out / "paper_table", races=args.races, steps=args.steps, **kw)
    tables = [out / "paper_table" / "paper_table.md"]
    compared = {"alpha": out / "paper_table"}
    control = out / "paper_table_control"
    paper_table(control, ego=BEST_FIXED_SPEC, races=args.races, steps=args.steps, **kw)
    tables.append(control / "paper_table.md")
    compared["best fixed"] = control
    if args.control_ego != "none":  # an extra row: the same races with another fixed ego
        extra = out / f"paper_table_{slug(args.control_ego)}_ego"
        paper_table(extra, ego=args.control_ego, races=args.races, steps=args.steps, **kw)
        tables.append(extra / "paper_table.md")
        compared[args.control_ego] = extra
    theta = ", ".join(f"{k} {v:.4g}" for k, v in entry["theta"].items())
    note = (
        f"The best fixed theta on `{track}` ({theta}) was chosen by `alpha-racer control` "
        f"from {entry['selection']['file']} (sha256 {entry['selection']['sha256'][:12]}, env "
        f"`{entry['env']}`)."
    )
    comparison = write_text(
        out / "comparison.md",
        comparison_markdown(
            {
                label: json.loads((d / "paper_table.json").read_text())
                for label, d in compared.items()
            },
            note,
        ),
    )
    tables.insert(1, comparison)
    if (out / "control" / "summary.md").exists():  # the selection, if it ran here
        tables.insert(2, out / "control" / "summary.md")
    from dataclasses import replace

    cases = ["IV"] + [c for c in PAPER_CASES if c != "IV"]  # the paper's overtake is vs IBR
    analyze(
        replace(_analyze_config(args), steps=args.steps),
        out / "analysis",
        bench_dirs=[out / "paper_table" / f"case_{c}" for c in cases],
        **kw,
    )
    parts = tables + [out / "analysis" / "summary.md"]
    if args.policy_thetas:  # the policy space the potential maximises over
        from .policy_map import PolicyMapConfig, policy_map

        policy_map(
            PolicyMapConfig(thetas=args.policy_thetas, steps=args.steps), out / "policy_map", **kw
        )
        parts.append(out / "policy_map" / "summary.md")
    text = "\n".join(p.read_text() for p in parts)
    (out / "README.md").write_text(text)
    print(text)
    print(
        f"wrote {out / 'README.md'}, {out / 'paper_table'}, {control}, {comparison}, "
        f"{out / 'analysis'}" + (f" and {out / 'policy_map'}" if args.policy_thetas else "")
    )
    return 0


def _cmd_general_report(args) -> int:
    from .general import GeneralReportConfig, general_report

    cfg = GeneralReportConfig(
        model=args.model,
        tracks=tuple(args.tracks or ()),
        gap_cars=args.gap_cars,
        gap_races=args.gap_races,
        gap_pairs=args.gap_pairs,
        bench_cars=args.bench_cars,
        bench_rounds=args.bench_rounds,
        default_races=args.default_races,
        steps=args.steps,
        seed=args.seed,
        control_thetas=args.control_thetas,
        control_races=args.control_races,
    )
    out = Path(args.out)
    general_report(
        cfg,
        out,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        command="alpha-racer " + " ".join(args.argv),
        control_dir=args.control_out,
    )
    print((out / "summary.md").read_text())
    print(f"wrote {out / 'summary.md'} and {out / 'summary.json'}")
    return 0


def _cmd_policy_map(args) -> int:
    from .policy_map import PolicyMapConfig, policy_map

    cfg = PolicyMapConfig(
        thetas=args.thetas,
        tracks=tuple(args.tracks),
        modes=tuple(args.modes),
        steps=args.steps,
        seed=args.seed,
        opponents=args.opponents,
        space=args.space,
    )
    out = Path(args.out)
    s = policy_map(cfg, out, workers=args.workers, backend=args.backend, address=args.address)
    print((out / "summary.md").read_text())
    print(
        f"{s['new_rows']} new rows; wrote {out / 'summary.md'}, {out / 'summary.json'}, "
        f"{out / 'rows.jsonl'} and heat maps into {out}"
    )
    return 0


def _cmd_control(args) -> int:
    from .control import ControlConfig, select_best_thetas
    from .family import expand_tracks

    cfg = ControlConfig(
        thetas=args.thetas,
        candidates=args.candidates,
        races=args.races,
        steps=args.steps,
        opponents=args.opponents,
        seed=args.seed,
    )
    out = Path(args.out)
    s = select_best_thetas(
        cfg,
        expand_tracks(args.tracks),
        out,
        workers=args.workers,
        backend=args.backend,
        address=args.address,
        install_table=not args.no_install,
        table=args.table,
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


def _add_parallel_args(p) -> None:
    p.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="worker processes (Ray CPUs with --backend ray); 1 runs in this process",
    )
    p.add_argument(
        "--backend",
        choices=["local", "ray"],
        default="local",
        help="local process pool or a Ray cluster (pip install alpha-racer[ray])",
    )
    p.add_argument(
        "--address",
        default=None,
        help="Ray cluster address (e.g. auto or ray://host:10001); default: start a local Ray",
    )


def _add_import_arg(p) -> None:
    p.add_argument(
        "--import",
        dest="imports",
        action="append",
        default=[],
        metavar="MODULE",
        help="import MODULE (a module name, or a .py file) before the agent specs are "
        "read, so that the agents it registers can race; repeatable",
    )


def _version() -> str:
    """The installed distribution's version, else (a source tree) the package's."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("alpha-racer")
    except PackageNotFoundError:
        from . import __version__

        return __version__


def build_parser() -> argparse.ArgumentParser:
    # the options' defaults are read from the config dataclasses (one place for each default;
    # tests/test_cli_defaults.py checks them)
    from agents.theta import SPACES

    from .bench import BenchConfig
    from .collect import START_REGIONS
    from .control import ControlConfig
    from .general import GeneralReportConfig
    from .league import LeagueConfig
    from .nets import TrainConfig
    from .policy_map import PolicyMapConfig
    from .selfplay import SelfPlayConfig

    p = argparse.ArgumentParser(
        prog="alpha-racer", description=__doc__, formatter_class=_HelpFormatter
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    def command(name, help, description=None):
        return sub.add_parser(
            name, help=help, description=description or help, formatter_class=_HelpFormatter
        )

    r = command("race", "race agents head to head, print the result, write an animation")
    r.add_argument(
        "--agents",
        nargs="+",
        default=DEFAULT_AGENTS,
        help="one agent spec per car: an agent name (alpha-racer agents lists them) "
        "with optional parameters, e.g. raceline:grip=0.75",
    )
    r.add_argument(
        "--track",
        default="default",
        help="default, oval, random:SEED, tumftm:NAME or a TUMFTM .csv path",
    )
    r.add_argument("--seed", type=int, default=0, help="seed of the start positions and the agents")
    r.add_argument("--steps", type=int, default=500, help="control periods of 0.1 s")
    r.add_argument(
        "--laps",
        type=int,
        default=None,
        help="end when the first car completes this many laps (default: run all steps)",
    )
    r.add_argument(
        "--start",
        choices=["regions", "grid", "random"],
        default="regions",
        help="start positions: the paper's start regions, a grid, or random",
    )
    r.add_argument("--out", default="results/race", help="output folder")
    r.add_argument(
        "--format",
        choices=["gif", "mp4"],
        default="gif",
        help="animation format (mp4 needs ffmpeg)",
    )
    r.add_argument("--no-animation", action="store_true", help="write no animation (faster)")
    _add_import_arg(r)
    r.set_defaults(fn=_cmd_race)

    ag = command("agents", "list every agent with its parameters, defaults and bounds")
    _add_import_arg(ag)
    ag.set_defaults(fn=_cmd_agents)

    t = command("tracks", "list the available tracks")
    t.add_argument("--details", action="store_true", help="build each track and print its size")
    t.set_defaults(fn=_cmd_tracks)

    rl = command("raceline", "compute a track's racing line (minimum curvature, or shortest lap)")
    rl.add_argument(
        "--track",
        default="default",
        help="default, oval, random:SEED, tumftm:NAME or a TUMFTM .csv path",
    )
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
    rl.set_defaults(fn=_cmd_raceline)

    f = command(
        "fuzz", "random-action fuzz of the simulator: no NaN, no exception, states in bounds"
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
    f.set_defaults(fn=_cmd_fuzz)

    c = command(
        "collect",
        "simulate races of MPC cars with random theta (resumable shards)",
        "simulate races of MPC cars with random theta (resumable shards); with --tracks "
        "or several --cars, a family collection over tracks and field sizes (one track "
        "and one field size per shard) for the general alpha-potential",
    )
    c.add_argument("--races", type=int, default=4000, help="races to simulate")
    c.add_argument(
        "--cars",
        default="3",
        help="cars per race: a number, or field sizes for a family collection as a "
        "range 2-6 or a list 2,3,5 (each in 2..8)",
    )
    c.add_argument("--steps", type=int, default=500, help="steps of 0.1 s per race")
    c.add_argument("--track", default=None, help="track spec (as for race; default: default)")
    c.add_argument(
        "--tracks",
        nargs="+",
        default=None,
        metavar="TRACK",
        help="a family collection over these track specs; random:A-B stands for "
        "random:A .. random:B, e.g. --tracks default oval random:0-299 "
        "tumftm:Monza",
    )
    c.add_argument("--seed", type=int, default=0, help="seed of the thetas and start positions")
    c.add_argument(
        "--space",
        choices=sorted(SPACES),
        default="paper",
        help="policy space the thetas are drawn from (extended: the paper's five "
        "and b, the lap-time line's weight)",
    )
    c.add_argument(
        "--start",
        choices=sorted(START_REGIONS),
        default="paper",
        help="start regions: the paper's (0.4 m long, 0.6 m apart) or close (0.2 m "
        "long, 0.1 m apart: more passing and blocking)",
    )
    c.add_argument(
        "--shard-size",
        type=int,
        default=None,
        help="races per shard file (default 25; 4 for a family collection, so that "
        "its shards spread over many tracks)",
    )
    c.add_argument("--out", default="data/races", help="output folder; run again to resume")
    _add_parallel_args(c)
    c.set_defaults(fn=_cmd_collect)

    tr = command("train", "fit the value and alpha-potential networks on collected races")
    tr.add_argument(
        "--data", default="data/races", help="a directory written by `alpha-racer collect`"
    )
    tr.add_argument("--out", default="models/alpha", help="output directory (resumes if it exists)")
    tr.add_argument(
        "--gamma", type=float, default=None, help=f"discount factor (default {TrainConfig.gamma})"
    )
    tr.add_argument(
        "--value-epochs",
        type=int,
        default=None,
        help=f"epochs of value-network training (default {TrainConfig.value_epochs})",
    )
    tr.add_argument(
        "--potential-steps",
        type=int,
        default=None,
        help=f"optimiser steps of the potential network (default {TrainConfig.potential_steps})",
    )
    tr.add_argument(
        "--potential-batch",
        type=int,
        default=None,
        help="unilateral deviations per optimiser step of the potential network "
        f"(default {TrainConfig.potential_batch})",
    )
    tr.add_argument(
        "--value-hidden",
        type=int,
        nargs="+",
        default=None,
        help="hidden layer widths of the value networks (default "
        f"{_words(TrainConfig.value_hidden)})",
    )
    tr.add_argument(
        "--potential-hidden",
        type=int,
        nargs="+",
        default=None,
        help="hidden layer widths of the potential network (default "
        f"{_words(TrainConfig.potential_hidden)})",
    )
    tr.add_argument(
        "--objective",
        choices=["mse", "smoothmax", "tail"],
        default=None,
        help="potential loss: mse, or the paper's min-max as a smooth maximum or a "
        f"tail average (default {TrainConfig.objective})",
    )
    tr.add_argument(
        "--val-fraction",
        type=float,
        default=None,
        help=f"races held out (default {TrainConfig.val_fraction})",
    )  # noqa: E501
    tr.add_argument(
        "--rollout-pairs",
        type=int,
        default=None,
        help=f"paired-rollout checks on held-out states (default "
        f"{TrainConfig.rollout_pairs}; 0 skips)",
    )
    tr.add_argument(
        "--rollout-steps",
        type=int,
        default=None,
        help=f"steps of each paired rollout (default {TrainConfig.rollout_steps})",
    )
    tr.add_argument(
        "--seed",
        type=int,
        default=None,
        help=f"seed of the split and the training (default {TrainConfig.seed})",
    )  # noqa: E501
    tr.add_argument(
        "--threads",
        type=int,
        default=None,
        help=f"torch threads and rollout workers (default {TrainConfig.threads})",
    )
    tr.add_argument(
        "--space",
        choices=sorted(SPACES),
        default=None,
        help="policy space the collection must be of (default: the collection's, "
        "from its manifest; a mismatch is an error naming both)",
    )
    tr.set_defaults(fn=_cmd_train)

    S = SelfPlayConfig
    sp = command("selfplay", "train PPO agents by iterated self-play (resumable)")
    sp.add_argument("--out", default="runs/selfplay", help="output folder; run again to resume")
    sp.add_argument("--cars", type=int, default=S.n_cars, help="cars per race")
    sp.add_argument(
        "--cycles",
        type=int,
        default=S.cycles,
        help="self-play cycles (each car learns once per cycle)",
    )
    sp.add_argument(
        "--steps-per-turn", type=int, default=S.steps_per_turn, help="env steps per learning turn"
    )
    sp.add_argument("--envs", type=int, default=S.n_envs, help="parallel races")
    sp.add_argument("--batch-size", type=int, default=S.batch_size, help="PPO minibatch size")
    sp.add_argument("--epochs", type=int, default=S.n_epochs, help="PPO epochs per rollout")
    sp.add_argument("--lr", type=float, default=S.learning_rate, help="PPO learning rate")
    sp.add_argument("--gamma", type=float, default=S.gamma, help="discount factor")
    sp.add_argument("--n-steps", type=int, default=S.n_steps, help="rollout length per env")
    sp.add_argument("--track", default=S.track, help="track spec (as for race)")
    sp.add_argument(
        "--race-steps", type=int, default=S.max_cycles, help="steps of 0.1 s per race (episode)"
    )
    sp.add_argument("--seed", type=int, default=S.seed, help="seed of the envs and the policies")
    sp.add_argument(
        "--vec-env",
        choices=["batched", "dummy", "subproc"],
        default=S.vec_env,
        help="vectorised env: our batched one, or SB3's DummyVecEnv/SubprocVecEnv",
    )
    sp.add_argument(
        "--warmup-opponent",
        choices=["raceline", "initial"],
        default=S.warmup_opponent,
        help="who drives a car before its first turn",
    )
    sp.add_argument(
        "--init",
        choices=["random", "bc"],
        default=S.init,
        help="a car's policy before its first turn: random (plain self-play) or "
        "behaviour-cloned from the raceline follower",
    )
    sp.add_argument("--bc-steps", type=int, default=S.bc_steps, help="expert samples for --init bc")
    sp.add_argument(
        "--checkpoint-every",
        type=int,
        default=S.checkpoint_every,
        help="rollouts between in-turn checkpoints",
    )  # noqa: E501
    sp.add_argument(
        "--eval-races", type=int, default=S.eval_races, help="solo evaluation races after each turn"
    )
    sp.add_argument("--no-mpc-reference", action="store_true", help="skip measuring the MPC alone")
    sp.add_argument(
        "--max-turns",
        type=int,
        default=None,
        help="stop after this many turns (resumable; default: all)",
    )
    sp.set_defaults(fn=_cmd_selfplay)

    b = command(
        "bench",
        "head-to-head benchmark: the ego against two opponents of one kind from "
        "the paper's start regions (resumable)",
        "head-to-head benchmark: the ego against two opponents of one kind from the "
        "paper's start regions, or against N - 1 from N regions with --cars N (resumable)",
    )
    b.add_argument("--ego", default=BenchConfig.ego, help="the ego's agent spec")
    b.add_argument(
        "--opponents",
        default=BenchConfig.opponents,
        help="agent spec of every opponent O1, O2, ...",
    )
    b.add_argument(
        "--cars",
        type=int,
        default=BenchConfig.n_cars,
        help="cars per race (2..8): N start regions, the ego from each equally often, "
        "the opponents in the other regions front to back",
    )
    b.add_argument(
        "--paper-table",
        action="store_true",
        help="run the paper's five cases (Table 1) and write paper_table.md",
    )
    b.add_argument(
        "--cases",
        nargs="+",
        default=None,
        help="with --paper-table: a subset of I II III IV V (default: all)",
    )
    b.add_argument(
        "--races",
        type=int,
        default=None,
        help=f"races per benchmark, a multiple of --cars (default {BenchConfig.races} with "
        f"3 cars: {BenchConfig.races // 3} per region; {BenchConfig.races // 3} N "
        "with N cars)",
    )
    b.add_argument(
        "--steps", type=int, default=BenchConfig.steps, help="steps of 0.1 s per race (500 = 50 s)"
    )
    b.add_argument("--track", default=BenchConfig.track, help="track spec (as for race)")
    b.add_argument(
        "--seed",
        type=int,
        default=BenchConfig.seed,
        help="seed of the races' start orders and agents",
    )
    b.add_argument(
        "--out",
        default=None,
        help="output folder (default results/bench/EGO_vs_OPPONENTS, or "
        "results/paper_table with --paper-table); run again to resume",
    )
    _add_import_arg(b)
    _add_parallel_args(b)
    b.set_defaults(fn=_cmd_bench)

    lg = command(
        "league",
        "round-robin league of any agents: every group of --cars agents on "
        "every track from rotated start regions, rated with openskill "
        "(Plackett-Luce) into a leaderboard (resumable)",
    )
    lg.add_argument(
        "--agents",
        nargs="+",
        default=list(LEAGUE_AGENTS),
        help="distinct agent specs, each one player of the rating (as for race; "
        "e.g. alpha:model=gamma0.98, mpc:zeta=1.0)",
    )
    lg.add_argument(
        "--tracks", nargs="+", default=list(LeagueConfig.tracks), help="track specs (as for race)"
    )
    lg.add_argument(
        "--cars",
        type=int,
        default=LeagueConfig.cars,
        help="cars per race, 2..8; at most the number of agents",
    )
    lg.add_argument(
        "--rounds",
        type=int,
        default=LeagueConfig.rounds,
        help="times the whole schedule runs, each with new seeds",
    )
    lg.add_argument(
        "--steps", type=int, default=LeagueConfig.steps, help="steps of 0.1 s per race (500 = 50 s)"
    )
    lg.add_argument(
        "--seed",
        type=int,
        default=LeagueConfig.seed,
        help="seed of the group sample, the start positions and the agents",
    )
    lg.add_argument(
        "--max-groups",
        type=int,
        default=LeagueConfig.max_groups,
        help="groups per round: every --cars-subset of the agents when there are at "
        "most this many, else a balanced sample of at most this many (whole blocks "
        "in which every agent races equally often; at least one)",
    )
    lg.add_argument("--out", default="results/league", help="output folder; run again to resume")
    _add_import_arg(lg)
    _add_parallel_args(lg)
    lg.set_defaults(fn=_cmd_league)

    from .strategy import SCENARIOS, config_defaults

    d = config_defaults()
    sg = command(
        "strategy",
        "strategy benchmark: scenarios that isolate maneuvers (pass slower "
        "cars, equal pace, defend against faster cars, the paper's Table-1 "
        "opponents) for the ego and a control ego in the same seats and "
        "races (resumable)",
    )
    sg.add_argument("--ego", default=d["ego"], help="the ego's agent spec")
    sg.add_argument(
        "--control",
        default=d["control"],
        help="the control ego's agent spec, raced in the same seats and races; "
        "also the opponents of equal and defend",
    )
    sg.add_argument("--tracks", nargs="+", default=list(d["tracks"]), help="track specs")
    sg.add_argument(
        "--scenarios",
        nargs="+",
        choices=list(SCENARIOS),
        default=list(SCENARIOS),
        help="scenarios to run (table1 is three benches: ibr, ppo, alpha opponents)",
    )
    sg.add_argument("--races", type=int, default=d["races"], help="races per bench")
    sg.add_argument(
        "--steps",
        type=int,
        default=d["steps"],
        help="steps of 0.1 s per race (the default fits the full suite in 45 min on 2 cores)",
    )
    sg.add_argument(
        "--zeta-max",
        type=float,
        default=d["zeta_max"],
        help="defend: the ego's zeta ceiling (the same for ego and control)",
    )
    sg.add_argument(
        "--pass-opponents",
        default=d["pass_opponents"],
        help="pass: the agent spec of the two slower cars that do not yield "
        "(e.g. raceline:grip=0.9 for followers slower in the corners only)",
    )
    sg.add_argument(
        "--seed", type=int, default=d["seed"], help="seed of the races' start positions and agents"
    )
    sg.add_argument("--out", default="results/strategy", help="output folder; run again to resume")
    _add_parallel_args(sg)
    sg.set_defaults(fn=_cmd_strategy)

    a = command(
        "analyze",
        "Nash analyses of an alpha-potential model: approximation gap, Nash "
        "regret by simulation, potential slices, figures",
    )
    a.add_argument("--out", default="results/analysis", help="output folder; run again to resume")
    a.add_argument(
        "--bench",
        nargs="*",
        default=None,
        help="benchmark folders to take the overtake animation from (default: none)",
    )
    a.add_argument("--force", action="store_true", help="redo parts whose outputs exist")
    _add_analyze_args(a)
    _add_parallel_args(a)
    a.set_defaults(fn=_cmd_analyze)

    rp = command(
        "reproduce",
        "every table and figure of the paper into one folder: "
        "bench --paper-table, the same races with the best fixed theta "
        "(the control), then analyze, then the policy map (resumable)",
    )
    rp.add_argument("--out", default="results", help="output folder; run again to resume")
    rp.add_argument("--races", type=int, default=99, help="races per paper case")
    rp.add_argument("--steps", type=int, default=500, help="steps per race (and per analysis race)")
    rp.add_argument(
        "--control-ego",
        default="mpc",
        help="an extra row besides the control (the five cases with the best fixed "
        "theta, mpc:theta=best): the five cases with this ego (mpc: the "
        "fixed-theta MPC at its default zeta 0.9); none skips it",
    )
    rp.add_argument(
        "--control-thetas",
        type=int,
        default=ControlConfig.thetas,
        help="if the best-theta table lacks the track: thetas of the control "
        "selection (alpha-racer control, into OUT/control, --steps steps)",
    )
    rp.add_argument(
        "--control-races",
        type=int,
        default=ControlConfig.races,
        help="if the best-theta table lacks the track: playoff races per candidate",
    )
    rp.add_argument(
        "--policy-thetas",
        type=int,
        default=PolicyMapConfig.thetas,
        help="thetas of the policy map (policy-map's default tracks, both modes, "
        "--steps steps); 0 skips it",
    )
    _add_import_arg(rp)
    _add_analyze_args(rp)
    _add_parallel_args(rp)
    rp.set_defaults(fn=_cmd_reproduce)

    gr = command(
        "general-report",
        "the general alpha-potential on held-out tracks: "
        "approximation gap for N cars, races in the N-car protocol "
        "beside the best fixed theta on each track (the control), "
        "and against the single-track default model on default "
        "(resumable)",
    )
    gr.add_argument(
        "--model",
        default=GeneralReportConfig.model,
        help="a general model: shipped name or path to a model.npz",
    )
    gr.add_argument(
        "--tracks",
        nargs="+",
        default=None,
        metavar="TRACK",
        help="held-out track specs (random:A-B ranges allowed); default "
        "random:10000-10019 and the TUMFTM circuits (if the folder exists) "
        "that the model was not trained on",
    )
    gr.add_argument(
        "--gap-cars",
        default=_commas(GeneralReportConfig.gap_cars),
        help="field sizes of the approximation gap",
    )  # noqa: E501
    gr.add_argument(
        "--gap-races",
        type=int,
        default=GeneralReportConfig.gap_races,
        help="fresh races per field size for the gap",
    )
    gr.add_argument(
        "--gap-pairs",
        type=int,
        default=GeneralReportConfig.gap_pairs,
        help="unilateral deviations per field size",
    )
    gr.add_argument(
        "--bench-cars",
        default=_commas(GeneralReportConfig.bench_cars),
        help="field sizes of the N-car races",
    )  # noqa: E501
    gr.add_argument(
        "--bench-rounds",
        type=int,
        default=GeneralReportConfig.bench_rounds,
        help="rounds of N races (the ego from each region once) per track and N",
    )
    gr.add_argument(
        "--default-races",
        type=int,
        default=GeneralReportConfig.default_races,
        help="races against the default model on default (0 skips them)",
    )
    gr.add_argument(
        "--steps", type=int, default=GeneralReportConfig.steps, help="steps of 0.1 s per race"
    )
    gr.add_argument(
        "--seed",
        type=int,
        default=GeneralReportConfig.seed,
        help="seed of the races and deviations",
    )
    gr.add_argument(
        "--control-thetas",
        type=int,
        default=ControlConfig.thetas,
        help="thetas of the selection of the best fixed theta (the control) on "
        "each held-out track the best-theta table lacks",
    )
    gr.add_argument(
        "--control-races",
        type=int,
        default=ControlConfig.races,
        help="playoff races per candidate of that selection",
    )
    gr.add_argument(
        "--control-out",
        default=None,
        help="folder of that selection (default OUT/control); run again to resume",
    )
    gr.add_argument("--out", default="results/general", help="output folder; run again to resume")
    _add_parallel_args(gr)
    gr.set_defaults(fn=_cmd_general_report)

    ct = command(
        "control",
        "choose the best fixed theta per track by a rule from measurements "
        "(policy map, top candidates, seeded playoff) and install it for "
        "mpc:theta=best (resumable)",
    )
    ct.add_argument(
        "--tracks", nargs="+", default=["default"], help="track specs (random:A-B ranges allowed)"
    )
    ct.add_argument(
        "--thetas",
        type=int,
        default=ControlConfig.thetas,
        help="Sobol thetas of each track's policy map (solo and race)",
    )
    ct.add_argument(
        "--candidates",
        type=int,
        default=ControlConfig.candidates,
        help="K: thetas taken to the playoff by region-adjusted race progress "
        "(plus the best solo theta)",
    )
    ct.add_argument(
        "--races",
        type=int,
        default=ControlConfig.races,
        help="playoff races per candidate, a multiple of 3 (every start region equally often)",
    )
    ct.add_argument(
        "--steps",
        type=int,
        default=ControlConfig.steps,
        help="steps of 0.1 s per run (map and playoff)",
    )
    ct.add_argument(
        "--opponents",
        default=ControlConfig.opponents,
        help="agent spec of the two other cars (map race mode and playoff)",
    )
    ct.add_argument(
        "--seed",
        type=int,
        default=ControlConfig.seed,
        help="seed of the Sobol sample, the map's starts and the playoff races "
        "(not 0, the benchmarks' seed)",
    )
    ct.add_argument("--out", default="results/control", help="output folder; run again to resume")
    ct.add_argument(
        "--no-install",
        action="store_true",
        help="only measure: leave the best-theta table unchanged",
    )
    ct.add_argument(
        "--table",
        default=None,
        help="best-theta table to install into (default: the package's "
        "agents/models/best_fixed_theta.json, or $ALPHA_RACER_BEST_THETA_TABLE)",
    )
    _add_parallel_args(ct)
    ct.set_defaults(fn=_cmd_control)

    from .policy_map import DEFAULT_TRACKS, MODES

    pm = command(
        "policy-map",
        "sweep the MPC policy space (q, zeta, s1, s2, s3): Sobol thetas, "
        "solo and 3-car runs, summary and heat maps (resumable)",
    )
    pm.add_argument(
        "--thetas",
        type=int,
        default=PolicyMapConfig.thetas,
        help="Sobol points of the theta box (a power of two keeps the sequence balanced)",
    )
    pm.add_argument("--tracks", nargs="+", default=list(DEFAULT_TRACKS), help="track specs")
    pm.add_argument(
        "--modes",
        nargs="+",
        choices=list(MODES),
        default=list(MODES),
        help="solo: the theta car alone from the grid; race: against two "
        "--opponents cars from the start regions",
    )
    pm.add_argument(
        "--opponents",
        default=PolicyMapConfig.opponents,
        help="agent spec of the two opponents of the race mode",
    )
    pm.add_argument(
        "--space",
        choices=sorted(SPACES),
        default=PolicyMapConfig.space,
        help="policy space whose box is mapped (extended adds b, the weight of the lap-time line)",
    )
    pm.add_argument(
        "--steps", type=int, default=PolicyMapConfig.steps, help="steps of 0.1 s per run"
    )
    pm.add_argument(
        "--seed", type=int, default=PolicyMapConfig.seed, help="Sobol scrambling and start seed"
    )
    _add_parallel_args(pm)
    pm.add_argument(
        "--out", default="results/policy_map", help="output folder; run again to resume"
    )
    pm.set_defaults(fn=_cmd_policy_map)
    return p


def _words(values) -> str:
    return " ".join(str(v) for v in values)


def _commas(values) -> str:
    return ",".join(str(v) for v in values)


def _add_analyze_args(p) -> None:
    from .analyze import AnalyzeConfig as A

    p.add_argument(
        "--model",
        default=None,
        help=f"alpha-potential model: shipped name or path (default: {A.model})",
    )
    for flag, what in (
        ("--heldout-races", "fresh races for the gap"),
        ("--gap-pairs", "deviations for the gap"),
        ("--regret-states", "race states for the regret"),
        ("--regret-horizon", "rollout steps before V"),
        ("--cem-iterations", "CEM iterations of the regret search"),
        ("--cem-samples", "candidates per CEM iteration"),
        ("--slice-points", "values per parameter in Figure 3"),
    ):
        default = getattr(A, flag[2:].replace("-", "_"))
        p.add_argument(flag, type=int, default=None, help=f"{what} (default {default})")


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
