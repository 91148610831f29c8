"""The commands that race agents and measure them: ``bench``, ``league``, ``strategy``,
``ladder``, ``control`` (the best fixed theta per track) and ``policy-map``."""

from __future__ import annotations

from pathlib import Path

from experiments.cli.options import (
    CLASS_OPTIONS,
    IMPORT_OPTION,
    PARALLEL_OPTIONS,
    RESUME_HELP,
    SWITCH,
    add_options,
    config_from,
    pool_from,
)

LEAGUE_AGENTS = ("alpha", "mpc", "ibr", "ppo", "raceline")  # every shipped agent
_BENCH_FIELDS = {"cars": "n_cars"}


def _cmd_bench(args) -> int:
    from experiments.evaluation.bench import bench
    from experiments.evaluation.bench_config import BenchConfig
    from experiments.evaluation.paper_table import paper_table
    from experiments.infra.artifacts import slug

    if args.space is not None and not args.paper_table:
        raise ValueError(f"--space {args.space} chooses the opponents of --paper-table; add it")
    if args.paper_table:
        if args.cars != 3:
            raise ValueError(f"--paper-table is the paper's 3-car protocol; got --cars {args.cars}")
        fullsize = args.vehicle_class == "fullsize"
        if args.wake is not None and not fullsize:
            raise ValueError("--paper-table --wake is for --vehicle-class fullsize")
        track = args.track
        if fullsize and track == "default":  # the class's circuit: its models' own
            track = "tumftm:Monza"
        out = args.out or ("results/paper_table_fullsize" if fullsize else "results/paper_table")
        t = paper_table(
            out,
            ego=args.ego,
            races=99 if args.races is None else args.races,
            steps=args.steps,
            track=track,
            seed=args.seed,
            cases=args.cases,
            pool=pool_from(args),
            space=args.space or "paper",
            vehicle_class=args.vehicle_class,
            wake=args.wake,
        )
        print((Path(out) / "paper_table.md").read_text())
        print(
            f"wrote {Path(out) / 'paper_table.md'} and {Path(out) / 'paper_table.json'} "
            f"({t['wall_seconds_this_run'] / 60:.1f} min)"
        )
        return 0
    races = args.races if args.races is not None else (99 if args.cars == 3 else 33 * args.cars)
    cfg = config_from(BenchConfig, args, _BENCH_FIELDS, races=races)
    field = "" if args.cars == 3 else f"_{args.cars}cars"
    out = Path(args.out or f"results/bench/{slug(args.ego)}_vs_{slug(args.opponents)}{field}")
    bench(cfg, out, pool_from(args))
    print((out / "summary.md").read_text())
    print(f"wrote {out / 'summary.md'}, {out / 'summary.json'} and {out / 'races.jsonl'}")
    return 0


def _cmd_league(args) -> int:
    from experiments.evaluation.league import league
    from experiments.evaluation.league_schedule import LeagueConfig

    out = Path(args.out)
    board = league(config_from(LeagueConfig, args), out, pool_from(args), imports=args.imports)
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
    t = strategy(config_from(StrategyConfig, args), out, pool_from(args), beside=args.beside)
    print((out / "strategy.md").read_text())
    print(f"{t['new_races']} new races; wrote {out / 'strategy.md'} and {out / 'strategy.json'}")
    return 0


def _cmd_ladder(args) -> int:
    from experiments.evaluation.ladder import LadderConfig, ladder

    out = Path(args.out)
    t = ladder(config_from(LadderConfig, args), out, pool_from(args))
    print((out / "ladder.md").read_text())
    print(f"{t['new_races']} new races; wrote {out / 'ladder.md'} and {out / 'ladder.json'}")
    return 0


def _cmd_room(args) -> int:
    from experiments.evaluation.room import RoomConfig, room

    t = room(args.suite, config_from(RoomConfig, args), pool_from(args))
    out = Path(t["folder"])
    print((out / "room.md").read_text())
    print(f"{t['new_races']} new oracle races; wrote {out / 'room.md'} and {out / 'room.json'}")
    return 0


def _cmd_policy_map(args) -> int:
    from experiments.evaluation.policy_map import PolicyMapConfig, policy_map

    out = Path(args.out)
    s = policy_map(config_from(PolicyMapConfig, args), out, pool_from(args))
    print((out / "summary.md").read_text())
    print(
        f"{s['new_rows']} new rows; wrote {out / 'summary.md'}, {out / 'summary.json'}, "
        f"{out / 'rows.jsonl'} and heat maps into {out}"
    )
    return 0


def _cmd_control(args) -> int:
    from experiments.evaluation.control import ControlConfig, default_out, select_best_thetas
    from experiments.potential.family import expand_tracks

    cfg = config_from(ControlConfig, args)
    out = Path(args.out or default_out(cfg.space, cfg.vehicle_class))
    s = select_best_thetas(
        cfg,
        expand_tracks(args.tracks),
        out,
        install_table=not args.no_install,
        table=args.table,
        pool=pool_from(args),
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


def add_bench(command) -> None:
    """``alpha-racer bench``."""
    from experiments.evaluation.bench_config import BenchConfig

    b = command(
        "bench",
        _cmd_bench,
        "head-to-head benchmark: the ego against two opponents of one kind from "
        "the paper's start regions (resumable)",
        "head-to-head benchmark: the ego against two opponents of one kind from the "
        "paper's start regions, or against N - 1 from N regions with --cars N (resumable)",
    )
    add_options(
        b,
        BenchConfig,
        ("--ego", "the ego's agent spec"),
        ("--opponents", "agent spec of every opponent O1, O2, ..."),
        (
            "--cars",
            "cars per race (2..8): N start regions, the ego from each equally often, "
            "the opponents in the other regions front to back",
        ),
        ("--paper-table", "run the paper's five cases (Table 1) and write paper_table.md", SWITCH),
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
        *CLASS_OPTIONS,
        (
            "--out",
            "output folder (default results/bench/EGO_vs_OPPONENTS, or "
            "results/paper_table with --paper-table); run again to resume",
            {"default": None},
        ),
        IMPORT_OPTION,
        *PARALLEL_OPTIONS,
        renamed=_BENCH_FIELDS,
    )


def add_league(command) -> None:
    """``alpha-racer league``."""
    from experiments.evaluation.league_schedule import LeagueConfig

    lg = command(
        "league",
        _cmd_league,
        "round-robin league of any agents: every group of --cars agents on "
        "every track from rotated start regions, rated with openskill "
        "(Plackett-Luce) into a leaderboard (resumable)",
    )
    add_options(
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
        ("--out", RESUME_HELP, {"default": "results/league"}),
        IMPORT_OPTION,
        *PARALLEL_OPTIONS,
    )


def add_strategy(command) -> None:
    """``alpha-racer strategy``."""
    from experiments.evaluation.strategy import SCENARIOS, StrategyConfig

    sg = command(
        "strategy",
        _cmd_strategy,
        "strategy benchmark: scenarios that isolate maneuvers (pass slower "
        "cars, equal pace, defend against faster cars, the paper's Table-1 "
        "opponents) for the ego and a control ego in the same seats and "
        "races (resumable)",
    )
    add_options(
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
        (
            "--zeta-max",
            "defend: the ego's zeta ceiling (the same for ego and control; default: None, "
            "the class's: 0.94 for orca, 0.88 for fullsize)",
            {"type": float, "default": None},
        ),
        (
            "--pass-opponents",
            "pass: the agent spec of the two slower cars that do not yield "
            "(e.g. raceline:grip=0.9 for followers slower in the corners only)",
        ),
        ("--seed", "seed of the races' start positions and agents"),
        *CLASS_OPTIONS,
        (
            "--beside",
            "with --vehicle-class fullsize: folders of the same suite with another --wake, "
            "whose pass reports are shown beside this one's",
            {"nargs": "+", "default": [], "metavar": "DIR"},
        ),
        ("--out", RESUME_HELP, {"default": "results/strategy"}),
        *PARALLEL_OPTIONS,
    )


def add_ladder(command) -> None:
    """``alpha-racer ladder``."""
    from experiments.evaluation.ladder import KNOB_RANGES, LADDER_REGIONS, TOLERANCE, LadderConfig

    ld = command(
        "ladder",
        _cmd_ladder,
        "pass ladder: each ego from R2 behind two followers that do not yield, whose solo "
        "pace is set to each rung's fraction of the ego's own; the highest rung at which "
        "the ego wins at least half of its races from R2 (resumable)",
    )
    add_options(
        ld,
        LadderConfig,
        ("--egos", "the egos' agent specs, each raced up its own ladder", {"nargs": "+"}),
        ("--tracks", "track specs", {"nargs": "+"}),
        (
            "--rungs",
            "the followers' solo pace as fractions of the ego's, each in (0, 1.5], distinct "
            f"(calibrated to within {100 * TOLERANCE:g}%% by the followers' --knob)",
            {"nargs": "+", "type": float},
        ),
        ("--races", "races per rung and start region"),
        (
            "--regions",
            "the ego's start regions, in turn (R2 must be one: the ladder is defined from R2)",
            {"nargs": "+", "choices": list(LADDER_REGIONS)},
        ),
        ("--steps", "steps of 0.1 s per race (and per solo race of the calibration)"),
        ("--seed", "seed of the races' start positions and agents, the same on every rung"),
        (
            "--followers",
            "agent spec of the two cars ahead that do not yield; it must take the --knob "
            "and not set it (the ladder sets it per rung)",
        ),
        (
            "--pace-of",
            "an agent spec whose solo pace is the unit of every ego's rungs, needed for an ego "
            "that cannot race alone, such as a 3-car alpha model (default None: each ego's own)",
        ),
        (
            "--knob",
            "the followers' parameter the ladder sets per rung: speed_scale (a raceline "
            "follower's speed target over its line's profile) or zeta (an mpc follower's)",
            {"choices": list(KNOB_RANGES)},
        ),
        *CLASS_OPTIONS,
        ("--out", RESUME_HELP, {"default": "results/ladder"}),
        *PARALLEL_OPTIONS,
    )


def add_room(command) -> None:
    """``alpha-racer room``."""
    from agents.theta import MOVES
    from experiments.evaluation.room import ROOM_BENCHES, RoomConfig

    rm = command(
        "room",
        _cmd_room,
        "the room of a finished strategy suite: a rollout oracle, choosing its theta every "
        "few periods by simulating each candidate from the race's exact state, in the seats "
        "of the suite's races, beside its ego and control (resumable; expensive)",
    )
    rm.add_argument("suite", help="a finished alpha-racer strategy folder")
    add_options(
        rm,
        RoomConfig,
        (
            "--base",
            "the suite's agent (an mpc spec) whose theta the candidates start from",
            {"choices": ["control", "ego"]},
        ),
        ("--moves", f"one-parameter moves of the base among the candidates, of {' '.join(MOVES)}"),
        ("--lookahead", "seconds each candidate is simulated for"),
        ("--every", "control periods between the oracle's choices"),
        ("--benches", "benches of the suite", {"nargs": "+", "choices": list(ROOM_BENCHES)}),
        ("--races", "the first N races of each bench (default all)", {"type": int}),
        (
            "--model",
            "drive the other cars in the rollouts by a model instead of their own agents: "
            "'self' (the base's spec) or 'control' (the suite's control); default: their own",
            {"choices": ["self", "control"]},
        ),
        *PARALLEL_OPTIONS,
    )


def add_control(command) -> None:
    """``alpha-racer control``."""
    from agents.theta import SPACES
    from experiments.evaluation.control import ControlConfig

    ct = command(
        "control",
        _cmd_control,
        "choose the best fixed theta per track by a rule from measurements "
        "(policy map, top candidates, seeded playoff) and install it for "
        "mpc:theta=best, or mpc:space=extended,theta=best with --space extended (resumable)",
    )
    add_options(
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
        *CLASS_OPTIONS,
        (
            "--out",
            RESUME_HELP
            + " (default results/control, results/control_extended for --space extended; "
            "with _fullsize added for --vehicle-class fullsize)",
            {"default": None},
        ),
        ("--no-install", "only measure: leave the best-theta table unchanged", SWITCH),
        (
            "--table",
            "best-theta table to install into (default: the package's "
            "agents/models/best_fixed_theta.json, or $ALPHA_RACER_BEST_THETA_TABLE)",
            {"default": None},
        ),
        *PARALLEL_OPTIONS,
    )


def add_policy_map(command) -> None:
    """``alpha-racer policy-map``."""
    from agents.theta import SPACES
    from experiments.evaluation.policy_map import DEFAULT_TRACKS, MODES, PolicyMapConfig

    pm = command(
        "policy-map",
        _cmd_policy_map,
        "sweep the MPC policy space (q, zeta, s1, s2, s3): Sobol thetas, "
        "solo and 3-car runs, summary and heat maps (resumable)",
    )
    add_options(
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
        *CLASS_OPTIONS,
        *PARALLEL_OPTIONS,
        ("--out", RESUME_HELP, {"default": "results/policy_map"}),
    )
