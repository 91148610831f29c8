"""The commands of one race and the world it runs in: ``race``, ``agents``, ``tracks``,
``raceline``, ``fuzz``."""

from __future__ import annotations

from pathlib import Path

from experiments.cli.options import (
    CLASS_OPTIONS,
    IMPORT_OPTION,
    SWITCH,
    TRACK_HELP,
    add_options,
)

DEFAULT_AGENTS = ["alpha", "ibr", "ibr"]  # the paper's case IV: alpha against two IBR cars


def _cmd_race(args) -> int:
    from agents.mpc import stepwise_solves
    from experiments.evaluation.race import (
        check_animation_format,
        run_race,
        start_order,
        write_outputs,
    )

    if not args.no_animation:
        check_animation_format(args.format)  # before the race, not after it
    # one race: the MPC's solve step by step (the same plans) saves the compiled solve's
    # compile on a cold cache, about 10 s, for 0.2 s of a 500-step race; the block leaves
    # the process's setting as it was (a caller of main() races on in the same process)
    with stepwise_solves():
        result, frames = run_race(
            args.agents,
            track=args.track,
            seed=args.seed,
            max_cycles=args.steps,
            start=args.start,
            laps=args.laps,
            render=not args.no_animation,
            order=start_order(args.regions, len(args.agents), args.start),
            vehicle_class=args.vehicle_class,
            wake=args.wake,
            follow=args.follow,
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


def _cmd_circuits(args) -> int:
    from racing_env.circuits import download

    if args.action == "download":
        return download.run(args)
    from racing_env.tracks import track_names, tumftm_file

    for name in track_names():
        if name.startswith("tumftm:"):
            print(f"{name:<24} {tumftm_file(name.split(':', 1)[1])}")
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


def add_race(command) -> None:
    """``alpha-racer race``."""
    r = command("race", _cmd_race, "race agents head to head, print the result, write an animation")
    add_options(
        r,
        None,
        (
            "--agents",
            "one agent spec per car: an agent name (alpha-racer agents lists them) "
            "with optional parameters, e.g. raceline:grip=0.75",
            {"nargs": "+", "default": DEFAULT_AGENTS},
        ),
        ("--track", TRACK_HELP, {"default": "default"}),
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
        ("--no-animation", "write no animation (faster)", SWITCH),
        *CLASS_OPTIONS,
        (
            "--follow",
            "full size: the car index the animation's view follows (default: the lead car)",
            {"type": int, "default": None},
        ),
        IMPORT_OPTION,
    )


def add_agents(command) -> None:
    """``alpha-racer agents``."""
    ag = command("agents", _cmd_agents, "list every agent with its parameters, defaults and bounds")
    add_options(ag, None, IMPORT_OPTION)


def add_tracks(command) -> None:
    """``alpha-racer tracks``."""
    t = command("tracks", _cmd_tracks, "list the available tracks")
    t.add_argument("--details", action="store_true", help="build each track and print its size")


def add_circuits(command) -> None:
    """``alpha-racer circuits``."""
    from racing_env.circuits import download

    c = command(
        "circuits",
        _cmd_circuits,
        "the real circuits (TUMFTM racetrack-database): where each is found, or download all",
        description="list: every tumftm:NAME circuit and the file it is read from. download: "
        + download.DESCRIPTION,
    )
    c.add_argument("action", choices=("list", "download"), help="list them, or download all")
    download.add_arguments(c)


def add_raceline(command) -> None:
    """``alpha-racer raceline``."""
    rl = command(
        "raceline",
        _cmd_raceline,
        "compute a track's racing line (minimum curvature, or shortest lap)",
    )
    rl.add_argument("--track", default="default", help=TRACK_HELP)
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


def add_fuzz(command) -> None:
    """``alpha-racer fuzz``."""
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
