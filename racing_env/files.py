"""Files written whole or not at all: :func:`atomic_path`, the one atomic-write helper."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterator


def current_umask() -> int:
    """The process's file-mode creation mask (read without changing it where Linux allows)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # elsewhere: set and restore (not atomic across threads)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = "", mode: int = 0o666) -> Iterator[Path]:
    """A temporary file beside ``path`` (its parent folder created if missing) to write instead
    of ``path``: moved onto ``path`` when the ``with`` block ends, deleted if it raises, so a
    reader never sees half a file. ``suffix`` ends the temporary name (``".npz"``: writers that
    add their own extension find it there). The file gets ``mode & ~umask`` (0644 under the
    usual umask 022), as ``open`` would give it, not the private 0600 of a temporary file::

        with atomic_path("line.npz", ".npz") as tmp:
            np.savez(tmp, **arrays)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{suffix}")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, mode & ~current_umask())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
