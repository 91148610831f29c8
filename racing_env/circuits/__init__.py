"""Real circuits that ship with the package, and the download of the whole database.

Five circuits of the TUMFTM racetrack-database (LGPL-3.0, see ``LICENSE`` and ``README.md``
in this folder) are package data, unmodified: :data:`SHIPPED`. The other circuits of the
database come with :func:`racing_env.circuits.download.download_racetrack_database`, which
stores them in the cache folder. :func:`racing_env.tracks.tumftm_file` looks in every place in
turn.
"""

from __future__ import annotations

from pathlib import Path

CIRCUITS_DIR = Path(__file__).resolve().parent
"""The folder of the shipped circuit CSVs (package data)."""

SHIPPED = ("Catalunya", "Monza", "Silverstone", "Spa", "Spielberg")
"""Names of the shipped circuits (``tumftm:NAME``)."""


def shipped_dir() -> Path:
    """The folder of the shipped circuits, ``racing_env/circuits/``."""
    return CIRCUITS_DIR
