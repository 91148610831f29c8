"""The learning commands: ``selfplay`` (PPO agents by iterated self-play) and ``ranker`` (a
ranker of a rollout oracle's candidates, from its kept choices)."""

from __future__ import annotations

from pathlib import Path

from experiments.cli.options import (
    CLASS_OPTIONS,
    RESUME_HELP,
    add_options,
    config_from,
)

# options named otherwise than the config fields they set: option name -> field
_SELFPLAY_FIELDS = {
    "cars": "n_cars",
    "envs": "n_envs",
    "epochs": "n_epochs",
    "lr": "learning_rate",
    "race_steps": "max_cycles",
}


def _cmd_selfplay(args) -> int:
    from experiments.learning.config import SelfPlayConfig
    from experiments.learning.selfplay import selfplay

    cfg = config_from(
        SelfPlayConfig, args, _SELFPLAY_FIELDS, mpc_reference=not args.no_mpc_reference
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


def add_selfplay(command) -> None:
    """``alpha-racer selfplay``."""
    from experiments.learning.config import SelfPlayConfig

    sp = command("selfplay", _cmd_selfplay, "train PPO agents by iterated self-play (resumable)")
    sp.add_argument("--out", default="runs/selfplay", help=RESUME_HELP)
    add_options(
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
        (
            "--track",
            "track spec (as for race; built at the class's scale); with --vehicle-class "
            "fullsize, default means tumftm:Monza",
        ),
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
        *CLASS_OPTIONS,
        renamed=_SELFPLAY_FIELDS,
    )
    sp.add_argument("--no-mpc-reference", action="store_true", help="skip measuring the MPC alone")
    sp.add_argument(
        "--max-turns",
        type=int,
        default=None,
        help="stop after this many turns (resumable; default: all)",
    )


def _cmd_ranker(args) -> int:
    from experiments.learning.ranker import RankerConfig, train_ranker

    cfg = RankerConfig(
        hidden=args.hidden, layers=args.layers, epochs=args.epochs, holdout=args.holdout
    )
    f = train_ranker(args.folders, args.out, cfg)
    v = f["validation"]
    g = v["gain_m"]
    print(
        f"{f['races']['train']} training and {f['races']['validation']} validation races, "
        f"{v['choices']} validation choices of {len(f['candidates'])} candidates"
    )
    print(
        f"validation gain over the base per choice [m]: ranker {g['ranker']:+.2f}, oracle "
        f"{g['oracle']:+.2f}, best fixed candidate (#{v['best_fixed_candidate']}) "
        f"{g['best_fixed_candidate']:+.2f}; R^2 {v['r2']}"
    )
    print(f"-> {args.out} (race it as ranked:model={args.out})")
    return 0


def add_ranker(command) -> None:
    """``alpha-racer ranker``."""
    rk = command(
        "ranker",
        _cmd_ranker,
        "train a ranker of a rollout oracle's candidates on the choices kept by alpha-racer "
        "room (value targets from paired rollouts; race it as ranked:model=OUT)",
    )
    rk.add_argument("folders", nargs="+", help="room folders (SUITE/room/<setting>) of one setting")
    rk.add_argument("--out", required=True, help="the ranker.npz to write (and OUT.json)")
    rk.add_argument("--hidden", type=int, default=64, help="units per hidden layer")
    rk.add_argument("--layers", type=int, default=2, help="hidden layers")
    rk.add_argument("--epochs", type=int, default=600, help="full-batch epochs")
    rk.add_argument(
        "--holdout", type=int, default=4, help="every N-th race held out for validation"
    )
