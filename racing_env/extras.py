"""Optional dependencies. Racing needs none of them; learning (``alpha-racer train`` and
``selfplay``, the ``ppo`` agent, :mod:`racing_env.vec_env`) needs the ``learn`` extra: torch,
stable-baselines3 and tensorboard, installed by ``pip install "alpha-racer[learn]"``.
"""

from __future__ import annotations

import importlib
from types import ModuleType

LEARN = "learn"


class MissingExtraError(ImportError):
    """A module of an optional extra is missing; the message says what to install."""


def require(module: str, purpose: str, extra: str = LEARN) -> ModuleType:
    """``import module`` for ``purpose`` (e.g. ``"the 'ppo' agent"``), or a
    :class:`MissingExtraError` naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(
            f"{purpose} needs {module.split('.')[0]!r}, which cannot be imported ({exc}). It comes with "
            f'the {extra!r} extra: pip install "alpha-racer[{extra}]"'
        ) from exc
