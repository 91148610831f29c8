"""The table of best fixed thetas per track that ``mpc:theta=best`` races.

``alpha-racer control`` (:mod:`experiments.control`) chooses, per track, the fixed theta
``(q, zeta, s1, s2, s3)`` that races best by a rule from measurements (a policy map, then a
playoff) and writes it here. This module only reads the table (agents never import
experiments). The table is a JSON file::

    {"schema_version": 1,
     "tracks": {"default": {"track": "default", "name": "default", "fingerprint": "...",
                            "env": "alpha_racer_v1", "theta": {"q": ..., "zeta": ..., ...},
                            "package_version": "...", "selection": {...}}, ...}}

keyed by track spec. An entry matches a :class:`racing_env.Track` by the geometry's
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


def read_table(path: str | os.PathLike | None = None) -> dict:
    """The table at ``path`` (default :func:`table_path`); an empty table if the file does not
    exist. ``ValueError`` naming the file for a file that is not a table of this schema."""
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
    ):
        raise ValueError(
            f"best-theta table {path} is not a table of schema version "
            f"{SCHEMA_VERSION} (got schema_version "
            f"{table.get('schema_version') if isinstance(table, dict) else None!r})"
        )
    for spec, entry in table["tracks"].items():
        missing = [k for k in ENTRY_KEYS if k not in entry]
        if missing:
            raise ValueError(f"best-theta table {path}: entry {spec!r} lacks {', '.join(missing)}")
    return table


def _command(spec: str) -> str:
    return f"alpha-racer control --tracks {spec}"


def lookup(track: str | Track, path: str | os.PathLike | None = None) -> dict:
    """The table entry for ``track`` (a :class:`racing_env.Track` or a track spec), matched by
    the geometry's fingerprint. ``ValueError`` naming the track, the table and the command that
    adds it when there is no entry, when the entry's geometry differs, or when the entry was
    chosen on another env version."""
    from racing_env.tracks import make_track

    spec = track if isinstance(track, str) else track.name
    track = make_track(track)
    path = Path(path) if path is not None else table_path()
    entries = read_table(path)["tracks"]
    fp = track.fingerprint()
    found = [(s, e) for s, e in entries.items() if e["fingerprint"] == fp]
    if not found:
        same = [s for s, e in entries.items() if s == spec or e["name"] == track.name]
        if same:
            raise ValueError(
                f"the best fixed theta of track {spec!r} in {path} was chosen on "
                f"another geometry (fingerprint {entries[same[0]]['fingerprint']}, "
                f"this track's {fp}); run `{_command(same[0])}` to choose it again"
            )
        raise ValueError(
            f"no best fixed theta for track {spec!r} in {path} (it has: "
            f"{', '.join(sorted(entries)) or 'no tracks'}); run `{_command(spec)}` "
            f"to choose and install it"
        )
    key, entry = found[0]
    current = env_name()
    if entry["env"] != current:
        raise ValueError(
            f"the best fixed theta of track {key!r} in {path} was chosen on env "
            f"{entry['env']!r}, this is {current!r}; run `{_command(key)}` to "
            f"choose it again"
        )
    return entry


def best_theta(track: str | Track, path: str | os.PathLike | None = None) -> Theta:
    """The :class:`agents.reference.Theta` of ``track``'s entry (see :func:`lookup`)."""
    from .reference import THETA_NAMES, Theta

    entry = lookup(track, path)
    return Theta(**{k: float(entry["theta"][k]) for k in THETA_NAMES})
