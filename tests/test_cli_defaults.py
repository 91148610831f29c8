"""A default lives in one place: every command-line option that sets a config dataclass field
defaults to that field's default, or (default None) says that default in its help."""

import argparse
import dataclasses

import pytest

from experiments.analysis.general import GeneralReportConfig
from experiments.analysis.nash import AnalyzeConfig
from experiments.cli import build_parser
from experiments.evaluation.bench_config import BenchConfig
from experiments.evaluation.control import ControlConfig
from experiments.evaluation.ladder import LadderConfig
from experiments.evaluation.league_schedule import LeagueConfig
from experiments.evaluation.policy_map import PolicyMapConfig
from experiments.evaluation.strategy import StrategyConfig
from experiments.learning.config import SelfPlayConfig
from experiments.potential.collect import CollectConfig
from experiments.potential.nets import TrainConfig

# command -> (its config dataclass, {option dest: field} where the names differ)
COMMANDS = {
    "collect": (CollectConfig, {"cars": "n_cars"}),
    "train": (TrainConfig, {}),
    "selfplay": (
        SelfPlayConfig,
        {
            "cars": "n_cars",
            "envs": "n_envs",
            "epochs": "n_epochs",
            "lr": "learning_rate",
            "race_steps": "max_cycles",
        },
    ),
    "bench": (BenchConfig, {"cars": "n_cars"}),
    "league": (LeagueConfig, {}),
    "strategy": (StrategyConfig, {}),
    "ladder": (LadderConfig, {}),
    "analyze": (AnalyzeConfig, {}),
    "general-report": (GeneralReportConfig, {}),
    "control": (ControlConfig, {}),
    "policy-map": (PolicyMapConfig, {}),
}


def _subparsers() -> dict:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices


def _same(option_default, field_default) -> bool:
    if isinstance(option_default, list):
        option_default = tuple(option_default)
    if isinstance(option_default, str) and not isinstance(field_default, str):
        # a comma list or a number given as text ("2,3,5", "3")
        shown = (
            ",".join(map(str, field_default))
            if isinstance(field_default, tuple)
            else str(field_default)
        )
        return option_default == shown
    return option_default == field_default


def _shown(value) -> list[str]:
    text = " ".join(map(str, value)) if isinstance(value, tuple) else str(value)
    return [f"default {text}", f"default: {text}"]


def _options(command):
    cls, renamed = COMMANDS[command]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for action in _subparsers()[command]._actions:
        field = fields.get(renamed.get(action.dest, action.dest))
        if field is None or field.default is dataclasses.MISSING:
            continue
        yield action, field


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_option_defaults_are_the_config_defaults(command):
    checked, wrong = 0, []
    for action, field in _options(command):
        checked += 1
        if action.default is None:  # the config's default applies: the help says it
            if not any(s in (action.help or "") for s in _shown(field.default)):
                wrong.append(
                    f"{action.option_strings[0]}: help {action.help!r} does not say "
                    f"the default {field.default!r} of {field.name}"
                )
        elif not _same(action.default, field.default):
            wrong.append(
                f"{action.option_strings[0]}={action.default!r} but "
                f"{COMMANDS[command][0].__name__}.{field.name}={field.default!r}"
            )
    assert checked >= 3, f"{command}: only {checked} options matched config fields"
    assert wrong == []


def test_every_command_with_a_config_is_checked():
    assert set(COMMANDS) <= set(_subparsers())


def test_a_mismatch_would_be_found(monkeypatch):
    monkeypatch.setattr(SelfPlayConfig, "cycles", 34)  # the class attribute the parser reads
    actions = dict((a.dest, a) for a, _ in _options("selfplay"))
    assert actions["cycles"].default == 34
    assert not _same(33, 34) and _same([1, 2], (1, 2)) and _same("2,3,5", (2, 3, 5))
