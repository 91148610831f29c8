"""The learning command: ``selfplay`` (PPO agents by iterated self-play)."""

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
