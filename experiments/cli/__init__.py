"""The ``alpha-racer`` command line: ``race``, ``agents``, ``tracks``, ``circuits``, ``raceline``, ``fuzz``,
``collect``, ``train``, ``selfplay``, ``bench``, ``league``, ``strategy``, ``ladder``, ``room``,
``analyze``, ``reproduce``, ``general-report``, ``policy-map``, ``control``."""

from __future__ import annotations

import argparse
import sys

from experiments.cli import analysis, evaluation, learning, potential, racing, reproduce
from experiments.cli.options import HelpFormatter, version
from racing_env.extras import MissingExtraError

# each command's parser, in the order of the help's list (one module per command group; the
# options' defaults are read from the config dataclasses, one place for each default:
# tests/test_cli_defaults.py checks them)
COMMANDS = (
    racing.add_race,
    racing.add_agents,
    racing.add_tracks,
    racing.add_circuits,
    racing.add_raceline,
    racing.add_fuzz,
    potential.add_collect,
    potential.add_train,
    learning.add_selfplay,
    learning.add_ranker,
    evaluation.add_bench,
    evaluation.add_league,
    evaluation.add_strategy,
    evaluation.add_ladder,
    evaluation.add_room,
    analysis.add_analyze,
    reproduce.add_reproduce,
    analysis.add_general_report,
    evaluation.add_control,
    evaluation.add_policy_map,
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="alpha-racer", description=__doc__, formatter_class=HelpFormatter
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {version()}")
    sub = p.add_subparsers(dest="command", required=True)

    def command(name, fn, help, description=None):
        """A subcommand ``name`` that runs ``fn(args)``."""
        parser = sub.add_parser(
            name, help=help, description=description or help, formatter_class=HelpFormatter
        )
        parser.set_defaults(fn=fn)
        return parser

    for add in COMMANDS:
        add(command)
    return p


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
