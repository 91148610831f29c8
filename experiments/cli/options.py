"""The command line's shared pieces: the help formatter, the option tables (each a table
of rows of :func:`add_options`) and the config built from the parsed options."""

from __future__ import annotations

import argparse
import dataclasses
import os


def config_from(cls, args, renamed: dict | None = None, **values):
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


def pool_from(args):
    """The drivers' :class:`~experiments.infra.parallel.Pool` of ``--workers``, ``--backend`` and
    ``--address``."""
    from experiments.infra.parallel import Pool

    return Pool(args.workers, args.backend, args.address)


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help ends with its default, except where the default is None or empty
    (the help then says what applies)."""

    def _get_help_string(self, action):
        if action.default is None or action.default == []:
            return action.help
        return super()._get_help_string(action)


def add_options(
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
            help = help.format(default=words(value) if isinstance(value, tuple) else value)
            kw["default"] = None if default_in_help else listed(value)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            kw.setdefault("type", type(value))
        p.add_argument(flag, help=help, **kw)


def listed(value):
    return list(value) if isinstance(value, tuple) else value


SWITCH = {"action": "store_true", "default": False}  # an option that is off unless given

# the process pool's options, the agent modules' and the analyses' (each a table of rows of
# _add_options)
PARALLEL_OPTIONS = (
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
# the world of the races: the vehicle class and the wake's strength (rows of add_options)
CLASS_OPTIONS = (
    (
        "--vehicle-class",
        "the cars and circuits: orca, the paper's 1:43 cars; fullsize, full-size single-seaters "
        "on full-scale circuits (use a tumftm: track)",
        {"choices": ["orca", "fullsize"], "default": "orca"},
    ),
    (
        "--wake",
        "the wake's strength (tow and dirty air behind another car): 0 off, 1 the published "
        "figures (default: None, the class's: 0 for orca, 1 for fullsize)",
        {"type": float, "default": None, "metavar": "STRENGTH"},
    ),
)
IMPORT_OPTION = (
    "--import",
    "import MODULE (a module name, or a .py file) before the agent specs are "
    "read, so that the agents it registers can race; repeatable",
    {"dest": "imports", "action": "append", "default": [], "metavar": "MODULE"},
)
ANALYZE_OPTIONS = (  # of experiments.analysis.nash.AnalyzeConfig, with default_in_help
    ("--model", "alpha-potential model: shipped name or path (default: {default})"),
    ("--heldout-races", "fresh races for the gap (default {default})"),
    ("--gap-pairs", "deviations for the gap (default {default})"),
    ("--regret-states", "race states for the regret (default {default})"),
    ("--regret-horizon", "rollout steps before V (default {default})"),
    ("--cem-iterations", "CEM iterations of the regret search (default {default})"),
    ("--cem-samples", "candidates per CEM iteration (default {default})"),
    ("--slice-points", "values per parameter in Figure 3 (default {default})"),
)


def version() -> str:
    """The installed distribution's version, else (a source tree) the package's."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("alpha-racer")
    except PackageNotFoundError:
        from experiments import __version__

        return __version__


TRACK_HELP = "default, oval, random:SEED, tumftm:NAME or a TUMFTM .csv path"
RESUME_HELP = "output folder; run again to resume"


def words(values) -> str:
    return " ".join(str(v) for v in values)


def commas(values) -> str:
    return ",".join(str(v) for v in values)
