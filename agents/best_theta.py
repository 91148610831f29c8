"""The table of best fixed thetas per track and policy space that ``mpc:theta=best`` (and
``mpc:space=extended,theta=best``) races.

``alpha-racer control`` (:mod:`experiments.evaluation.control`) chooses, per track, the fixed theta that
races best by a rule from measurements (a policy map, then a playoff) over the box of one
policy space (:data:`agents.theta.SPACES`: the paper's ``(q, zeta, s1, s2, s3)``, or the
extended space's six with ``b``) and writes it here. This module only reads the table (agents
never import experiments). The table is a JSON file::

    {"schema_version": 1,
     "tracks": {"default": {"track": "default", "name": "default", "fingerprint": "...",
                            "env": "alpha_racer_v1", "theta": {"q": ..., "zeta": ..., ...},
                            "package_version": "...", "selection": {...}}, ...},
     "spaces": {"extended": {"default": {..., "space": "extended",
                                         "theta": {"q": ..., ..., "b": ...}}, ...}}}

``tracks`` holds the paper space's entries, keyed by track spec, exactly as before policy
spaces existed; ``spaces`` (optional) holds the entries of every other space, one mapping of
the same shape per space name, each entry with ``space`` and a theta of that space's
parameters. An absent ``spaces`` (every table written before it) means paper entries only, and
a reader that knows only ``tracks`` still reads the paper entries of a newer table unchanged:
the schema stays version 1, compatible both ways.

An entry matches a :class:`racing_env.Track` by the geometry's
:meth:`~racing_env.Track.fingerprint` (so ``tumftm:Monza`` and its CSV path find the same
entry), and only while the env's ``metadata["name"]`` equals the entry's ``env`` (a theta
chosen under other physics is not the best under these). The table is
:data:`DEFAULT_TABLE` (package data), or the file named by the environment variable
:data:`TABLE_ENV_VAR` when it is set.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from racing_env.track import Track

    from .reference import Theta

SCHEMA_VERSION = 1
DEFAULT_TABLE = Path(__file__).parent / "models" / "best_fixed_theta.json"
"""The shipped table (package data)."""
TABLE_ENV_VAR = "ALPHA_RACER_BEST_THETA_TABLE"
"""Environment variable naming another table file (it is read and written instead of
:data:`DEFAULT_TABLE`; worker processes inherit it)."""
ENTRY_KEYS = ("track", "name", "fingerprint", "env", "theta", "package_version", "selection")


PAPER = "paper"
"""The policy space of the table's ``tracks`` (and of an entry without ``space``)."""


def table_path() -> Path:
    """The table in use: ``$ALPHA_RACER_BEST_THETA_TABLE`` if set, else :data:`DEFAULT_TABLE`."""
    env = os.environ.get(TABLE_ENV_VAR)
    return Path(env) if env else DEFAULT_TABLE


def env_name() -> str:
    """The racing env's version name (``RacingParallelEnv.metadata["name"]``)."""
    from racing_env import RacingParallelEnv

    return RacingParallelEnv.metadata["name"]


def empty_table() -> dict:
    return {"schema_version": SCHEMA_VERSION, "tracks": {}}


def _space_name(space: str) -> str:
    """``space`` checked against :data:`agents.theta.SPACES` (``ValueError`` naming the choices)."""
    from .theta import policy_space

    return policy_space(space).name


def space_entries(table: dict, space: str = PAPER) -> dict:
    """The entries of policy space ``space`` in ``table`` (a :func:`read_table` result) by
    track spec: ``table["tracks"]`` for the paper's space, ``table["spaces"][space]`` (empty
    if absent) for another."""
    if _space_name(space) == PAPER:
        return table["tracks"]
    return table.get("spaces", {}).get(space, {})


def set_space_entries(table: dict, space: str, entries: dict) -> dict:
    """``table`` with the entries of policy space ``space`` replaced by ``entries`` (sorted by
    track spec); returns the table."""
    entries = dict(sorted(entries.items()))
    if _space_name(space) == PAPER:
        table["tracks"] = entries
    else:
        table["spaces"] = dict(sorted({**table.get("spaces", {}), space: entries}.items()))
    return table


def _check_entries(path: Path, space: str, entries) -> None:
    """``ValueError`` naming the file, space and entry for an entry that lacks a field or
    holds another space's theta."""
    from .theta import policy_space

    if not isinstance(entries, dict):
        raise ValueError(
            f"best-theta table {path}: the entries of the {space!r} space are not a mapping"
        )
    names = policy_space(space).names
    for spec, entry in entries.items():
        missing = [k for k in ENTRY_KEYS if k not in entry]
        if missing:
            raise ValueError(
                f"best-theta table {path}: entry {spec!r} ({space!r} space) lacks "
                f"{', '.join(missing)}"
            )
        if entry.get("space", PAPER) != space or sorted(entry["theta"]) != sorted(names):
            raise ValueError(
                f"best-theta table {path}: entry {spec!r} under the {space!r} space holds "
                f"space {entry.get('space', PAPER)!r} and theta {sorted(entry['theta'])}, "
                f"expected {space!r} and {sorted(names)}"
            )


def read_table(path: str | os.PathLike | None = None) -> dict:
    """The table at ``path`` (default :func:`table_path`); an empty table if the file does not
    exist. ``ValueError`` naming the file for a file that is not a table of this schema
    (a missing field, an unknown policy space, or an entry of another space's theta)."""
    from .theta import SPACES

    path = Path(path) if path is not None else table_path()
    if not path.exists():
        return empty_table()
    try:
        table = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"best-theta table {path} is not valid JSON: {exc}") from None
    if (
        not isinstance(table, dict)
        or table.get("schema_version") != SCHEMA_VERSION
        or not isinstance(table.get("tracks"), dict)
        or not isinstance(table.get("spaces", {}), dict)
    ):
        raise ValueError(
            f"best-theta table {path} is not a table of schema version "
            f"{SCHEMA_VERSION} (got schema_version "
            f"{table.get('schema_version') if isinstance(table, dict) else None!r})"
        )
    unknown = sorted(set(table.get("spaces", {})) - (set(SPACES) - {PAPER}))
    if unknown:
        raise ValueError(
            f"best-theta table {path} holds entries of unknown policy space(s) {unknown}; "
            f"its 'spaces' may name {sorted(set(SPACES) - {PAPER})} (the paper's entries "
            f"are its 'tracks')"
        )
    _check_entries(path, PAPER, table["tracks"])
    for space, entries in table.get("spaces", {}).items():
        _check_entries(path, space, entries)
    return table


def control_command(spec: str, space: str = PAPER, vehicle_class: str = "orca") -> str:
    """The command that chooses and installs the best fixed theta of track ``spec`` in policy
    space ``space`` for ``vehicle_class``."""
    flag = "" if space == PAPER else f" --space {space}"
    if vehicle_class != "orca":
        flag += f" --vehicle-class {vehicle_class}"
    return f"alpha-racer control{flag} --tracks {spec}"


def _in_space(space: str) -> str:
    return "" if space == PAPER else f" of the {space!r} policy space"


def lookup(track: str | Track, path: str | os.PathLike | None = None, space: str = PAPER) -> dict:
    """The table entry for ``track`` (a :class:`racing_env.Track` or a track spec) in policy
    space ``space`` (default the paper's), matched by the geometry's fingerprint.
    ``ValueError`` naming the track, the space, the table and the command that adds it when
    there is no entry, when the entry's geometry differs, or when the entry was chosen on
    another env version."""
    from racing_env.tracks import make_track

    space = _space_name(space)
    spec = track if isinstance(track, str) else track.name
    track = make_track(track)
    cls = getattr(track, "vehicle_class", "orca")
    path = Path(path) if path is not None else table_path()
    entries = space_entries(read_table(path), space)
    fp = track.fingerprint()
    found = [(s, e) for s, e in entries.items() if e["fingerprint"] == fp]
    if not found:
        same = [
            s
            for s, e in entries.items()
            if (s == spec or e["name"] == track.name) and e.get("vehicle_class", "orca") == cls
        ]
        if same:
            other = entries[same[0]]
            raise ValueError(
                f"the best fixed theta{_in_space(space)} of track {spec!r} in {path} was "
                f"chosen on another geometry (fingerprint {other['fingerprint']}, this "
                f"track's {fp}); run `{control_command(other['track'], space, cls)}` to "
                f"choose it again"
            )
        raise ValueError(
            f"no best fixed theta{_in_space(space)} for track {spec!r} in {path} (it has"
            f"{'' if space == PAPER else ' in that space'}: "
            f"{', '.join(sorted(entries)) or 'no tracks'}); run "
            f"`{control_command(spec, space, cls)}` to choose and install it"
        )
    key, entry = found[0]
    current = env_name()
    if entry["env"] != current:
        raise ValueError(
            f"the best fixed theta{_in_space(space)} of track {key!r} in {path} was chosen "
            f"on env {entry['env']!r}, this is {current!r}; run "
            f"`{control_command(entry['track'], space, cls)}` to choose it again"
        )
    return entry


def best_theta(
    track: str | Track, path: str | os.PathLike | None = None, space: str = PAPER
) -> Theta:
    """The :class:`agents.reference.Theta` of ``track``'s entry in policy space ``space`` (see
    :func:`lookup`; an extended entry's theta carries its ``b``)."""
    from .reference import Theta
    from .theta import policy_space

    entry = lookup(track, path, space)
    return Theta(**{k: float(entry["theta"][k]) for k in policy_space(space).names})
