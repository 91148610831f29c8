"""``alpha-racer reproduce --vehicle-class fullsize``: the full-size world's strategy results
into one folder. Each step is resumable (run the command again after a kill):

1. the class's best fixed theta on every circuit, in the model's policy space (the control:
   ``alpha-racer control --vehicle-class fullsize``, into ``OUT/control``, where the
   best-theta table lacks a circuit);
2. the strategy suite (``pass``, ``equal``, ``defend``) of the full-size alpha against that
   control on the trained circuit and on circuits no model was trained on (``OUT/strategy``);
3. the room (:mod:`experiments.evaluation.room`): the rollout oracle in the seats of the
   suite's ``equal`` and ``defend`` races (``OUT/strategy/room/...``);
4. the pass ladder of alpha and the control on the trained circuit (``OUT/ladder``);
5. the paper's Table 1 in the class's world (``bench --paper-table --vehicle-class
   fullsize``: cases I-III the shipped variants of the class's model, IV ``ibr``, V the
   class's ``ppo``) on the trained circuit with alpha as ego (``OUT/paper_table``) and the
   same races with the control as ego (``OUT/paper_table_control``), and their comparison.
"""

from __future__ import annotations

from pathlib import Path

#: the circuits: the first is the one the shipped full-size models were trained on
FULLSIZE_TRACKS = ("tumftm:Monza", "tumftm:Spielberg", "tumftm:Silverstone")
#: the shipped full-size model of each policy space (``--model`` names another)
FULLSIZE_MODELS = {"extended": "fullsize_monza", "wake": "fullsize_monza_wake"}
FULLSIZE_SCENARIOS = ("pass", "equal", "defend")
FULLSIZE_OUT = "results/fullsize_{space}"
"""The default output folder (``{space}``: the policy space)."""


def fullsize_ego(space: str, model: str | None, options: str | None = None) -> str:
    """The alpha agent of the full-size world: ``model`` or the space's shipped model, with
    ``options`` (``"anchor=best,others=estimate"``) added to its spec; an option the alpha
    agent does not take is a ``SystemExit`` naming it."""
    if model is None:
        if space not in FULLSIZE_MODELS:
            raise SystemExit(
                f"--vehicle-class fullsize --space {space}: no shipped full-size model in that "
                f"space (shipped: {', '.join(f'{s} ({m})' for s, m in FULLSIZE_MODELS.items())}); "
                "name one with --model"
            )
        model = FULLSIZE_MODELS[space]
    spec = f"alpha:model={model}"
    if options:
        from agents.base import make_agent_spec

        spec = f"{spec},{options}"
        try:
            make_agent_spec(spec)  # builds it: a bad option fails here, before any race
        except ValueError as err:
            raise SystemExit(f"--alpha-options {options!r}: {err}") from None
    return spec


def reproduce_fullsize(args, pool) -> Path:
    """Steps 1-4 of the module docstring with ``args`` (``reproduce``'s options); returns the
    ``README.md`` it wrote (the parts joined)."""
    from experiments.evaluation.control import ControlConfig, ensure_best_thetas
    from experiments.evaluation.ladder import LadderConfig, ladder
    from experiments.evaluation.room import RoomConfig, room
    from experiments.evaluation.strategy import StrategyConfig, strategy

    space = args.space
    if space == "paper":
        raise SystemExit(
            "--vehicle-class fullsize races in the extended or the wake policy space: "
            "pass --space extended (or wake, with --model)"
        )
    if not args.strategy_races:
        raise SystemExit(
            f"--strategy-races must be a positive number of races per bench with "
            f"--vehicle-class fullsize (the suite is the point), got {args.strategy_races!r}"
        )
    ego = fullsize_ego(space, args.model, getattr(args, "alpha_options", None))
    out = Path(args.out or FULLSIZE_OUT.format(space=space))
    tracks = tuple(args.fullsize_tracks)
    ctl = ControlConfig(
        thetas=args.control_thetas,
        races=args.control_races,
        steps=args.strategy_steps,
        space=space,
        refine=args.control_refine,
        vehicle_class="fullsize",
        wake=args.wake,
    )
    ensure_best_thetas(tracks, ctl, out / "control", pool)
    control = f"mpc:space={space},theta=best"
    parts: list[Path] = []
    if (out / "control" / "summary.md").exists():  # the selection, if it ran here
        parts.append(out / "control" / "summary.md")
    suite = out / "strategy"
    strategy(
        StrategyConfig(
            ego=ego,
            control=control,
            tracks=tracks,
            scenarios=FULLSIZE_SCENARIOS,
            races=args.strategy_races,
            steps=args.strategy_steps,
            vehicle_class="fullsize",
            wake=args.wake,
        ),
        suite,
        pool,
    )
    parts.append(suite / "strategy.md")
    if args.room_races:
        found = room(suite, RoomConfig(benches=("equal", "defend"), races=args.room_races), pool)
        parts.append(Path(found["folder"]) / "room.md")
    if args.ladder_races:
        ladder(
            LadderConfig(
                egos=(ego, control),
                tracks=tracks[:1],
                races=args.ladder_races,
                steps=args.strategy_steps,
                pace_of=control,  # an alpha model of 3 cars cannot race alone
                vehicle_class="fullsize",
                wake=args.wake,
            ),
            out / "ladder",
            pool,
        )
        parts.append(out / "ladder" / "ladder.md")
    if args.races:
        parts += _table1(args, ego, control, tracks[0], out, pool)
    text = "\n".join(p.read_text() for p in parts)
    readme = out / "README.md"
    readme.write_text(text)
    return readme


def _table1(args, ego: str, control: str, track: str, out: Path, pool) -> list[Path]:
    """Step 5: Table 1 of the class with ``ego`` and with ``control`` as ego (``--races``
    per case, ``--strategy-steps`` steps), and the comparison; returns their Markdown files."""
    import json

    from experiments.evaluation.paper_table import comparison_markdown, paper_table
    from experiments.infra.artifacts import write_text

    dirs = {"alpha": out / "paper_table", "best fixed": out / "paper_table_control"}
    for label, who in (("alpha", ego), ("best fixed", control)):
        paper_table(
            dirs[label],
            ego=who,
            races=args.races,
            steps=args.strategy_steps,
            track=track,
            pool=pool,
            vehicle_class="fullsize",
            wake=args.wake,
        )
    tables = {k: json.loads((d / "paper_table.json").read_text()) for k, d in dirs.items()}
    note = f"The control is the class's best fixed theta on `{track}` (`{control}`)."
    comparison = write_text(out / "comparison.md", comparison_markdown(tables, note))
    return [dirs["alpha"] / "paper_table.md", comparison]
