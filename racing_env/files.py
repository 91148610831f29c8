"""Files written whole or not at all: :func:`atomic_path`."""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path, suffix: str = ""):
    """A temporary file beside ``path`` (its parent folder created if missing) to write instead
    of ``path``: moved onto ``path`` when the ``with`` block ends, deleted if it raises, so a
    reader never sees half a file. ``suffix`` ends the temporary name (``".npz"``: writers that
    add their own extension find it there)::

        with atomic_path("line.npz", ".npz") as tmp:
            np.savez(tmp, **arrays)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{suffix}")
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
