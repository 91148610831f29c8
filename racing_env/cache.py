"""The one folder for everything alpha-racer compiles or computes once: :func:`cache_dir`.

Location, in this order:

1. ``$ALPHA_RACER_CACHE`` if the variable is set;
2. else the per-user cache folder, ``platformdirs.user_cache_dir("alpha-racer")``:
   ``~/.cache/alpha-racer`` on Linux (or ``$XDG_CACHE_HOME/alpha-racer``),
   ``~/Library/Caches/alpha-racer`` on macOS, ``%LOCALAPPDATA%\\alpha-racer\\Cache`` on Windows;
3. when that folder cannot be created or written (a read-only or missing home in a container
   or on a cluster node), a private temporary folder, ``$TMPDIR/alpha-racer-<uid>``, with a
   warning: one line, once per process, when the cache is first used (not on ``import`` or
   ``alpha-racer --version`` / ``--help``). Everything still works; compiled code is just
   rebuilt once per temporary folder.

When Matplotlib's own config folder cannot be written either, ``MPLCONFIGDIR`` is pointed at
``matplotlib/`` of the cache (Matplotlib would otherwise warn on every import).

Sub-folders: ``numba/<hash>/`` (the compiled kernels of ``racing_env`` and ``agents``, in a
folder named by a hash of both packages' sources, :func:`kernel_sources_hash`), ``mpc/`` (the
MPC's generated C prediction, named by a hash of the code), ``raceline/`` (racing lines, keyed
by the track, the vehicle, the config and the code that computes them). Nothing is written
into the installed package, so a read-only site-packages works and ``pip uninstall
alpha-racer`` leaves nothing behind there. Delete the folder to clear the cache.

Importing this module (each top package, ``racing_env``, ``agents`` and ``experiments``, does
so first) resolves the location once, exports it as ``ALPHA_RACER_CACHE`` (so worker processes
use the same folder and do not warn again) and points numba's cache at the source-hashed
folder unless ``NUMBA_CACHE_DIR`` is set. It sets ``numba.config.CACHE_DIR`` rather than the
``NUMBA_CACHE_DIR`` variable, which would leak into every numba program this process starts.

Why a hash of the sources: numba checks a cached kernel against its *own* source file only. A
kernel that calls a kernel of another file (the MPC's follower rollout calls the simulator's
integrator, the follower calls the track look-up) keeps the callee it was compiled with, so
after an edit of ``simulator.py`` a stale ``agents/mpc/`` kernel would silently race the old physics
(different races from the same seed). Any edit of either package starts a new folder. With
``NUMBA_CACHE_DIR`` set, that folder is used as it is (clear it after editing the sources).
"""

from __future__ import annotations

import getpass
import hashlib
import importlib.util
import os
import stat
import tempfile
import uuid
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable

ENV_VAR = "ALPHA_RACER_CACHE"
APP_NAME = "alpha-racer"

_resolved: dict[str, Path] = {}  # requested location -> folder in use (warn once per request)


def default_cache_root() -> Path:
    """The per-user cache folder, ``platformdirs.user_cache_dir("alpha-racer")``."""
    from platformdirs import user_cache_dir

    return Path(user_cache_dir(APP_NAME, appauthor=False))


def _writable(folder: Path) -> str | None:
    """None if ``folder`` exists (or can be made) and a file can be written in it, else why not
    (without naming the folder: the caller does)."""
    if not folder.is_absolute():  # e.g. "~/.cache" when no home directory can be found
        return "not an absolute path; no home directory?"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{uuid.uuid4().hex}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        return str(exc.strerror or exc)
    return None


def _private_temp_root() -> Path:
    """``$TMPDIR/alpha-racer-<uid>``, readable and writable by this user only (a fresh
    ``mkdtemp`` folder if that name is taken by someone else or open to others: compiled
    libraries from the cache get loaded, so nobody else may be able to plant one)."""
    tmp = Path(tempfile.gettempdir())
    uid = os.getuid() if hasattr(os, "getuid") else None
    folder = tmp / f"{APP_NAME}-{uid if uid is not None else getpass.getuser()}"
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        st = folder.lstat()
        safe = stat.S_ISDIR(st.st_mode) and (
            uid is None or (st.st_uid == uid and not st.st_mode & 0o077)
        )
    except OSError:
        safe = False
    return folder if safe else Path(tempfile.mkdtemp(prefix=f"{APP_NAME}-"))


def cache_root(defer_warning: bool = False) -> Path:
    """The cache folder in use (see the module docstring): ``$ALPHA_RACER_CACHE``, else the
    per-user cache folder, else (with a one-line warning, once) a private temporary folder.
    Resolved once per value of ``ALPHA_RACER_CACHE``; raises OSError only if no temporary folder
    is writable. ``defer_warning`` (used at import) keeps the warning until the cache is first
    used (:func:`notice`), so ``alpha-racer --version`` or ``--help`` print none."""
    requested = os.environ.get(ENV_VAR, "")
    if requested in _resolved:
        return _resolved[requested]
    if requested:
        root, what = Path(requested).expanduser(), f"{ENV_VAR}={requested!r}"
        if not str(root).startswith("~"):  # relative to the working directory
            root = root.absolute()
    else:
        root = default_cache_root()
        what = f"the default cache folder {str(root)!r}"
    why = _writable(root)
    if why is not None:
        fallback = _private_temp_root()
        why_tmp = _writable(fallback)
        if why_tmp is not None:
            raise OSError(
                f"alpha-racer has no writable cache folder: {what}: {why}; temporary "
                f"folder {str(fallback)!r}: {why_tmp}. Set {ENV_VAR} to a writable folder."
            )
        _pending.append(
            f"alpha-racer cannot write to {what} ({why}): its compiled code and racing "
            f"lines go to the temporary folder {str(fallback)!r} instead. Set "
            f"{ENV_VAR} to a writable folder to keep them."
        )
        if not defer_warning:
            notice()
        root = fallback
    _resolved[requested] = root
    return root


_pending: list[str] = []  # the fallback warning, until the cache is first used


def notice() -> None:
    """Emit the cache-fallback warning held back at import (once per process; see
    :func:`cache_root`): one line, ``alpha-racer cache: RuntimeWarning: ...``, with no source
    line under it. Called when the cache is first used: :func:`cache_dir`, a new race core."""
    while _pending:
        warnings.warn_explicit(
            _pending.pop(0), RuntimeWarning, "alpha-racer cache", 0, module="racing_env.cache"
        )


def cache_dir(sub: str | None = None, quiet: bool = False) -> Path:
    """The cache folder, or its sub-folder ``sub`` (``"numba"``, ``"mpc"``, ``"raceline"``,
    ``"matplotlib"``), created if missing. Emits the held-back fallback warning unless ``quiet``."""
    if not quiet:
        notice()
    folder = cache_root() if sub is None else cache_root() / sub
    folder.mkdir(parents=True, exist_ok=True)
    return folder


#: packages whose numba kernels share the cache folder (and call each other's kernels)
KERNEL_PACKAGES = ("racing_env", "agents")


def sources_hash(paths: Iterable[str | os.PathLike]) -> str:
    """Hash [hex, 16 chars] of the files ``paths`` (each one's name and bytes, in the order
    given): a cache key part that changes with the code that made the cached result."""
    h = hashlib.sha1()
    for path in paths:
        path = Path(path)
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:16]


def kernel_sources_hash(folders: Iterable[str | os.PathLike] | None = None) -> str:
    """:func:`sources_hash` of every ``.py`` file (sorted by path) in ``folders`` and their
    sub-folders (sub-packages such as ``agents/mpc/``), by default the installed
    :data:`KERNEL_PACKAGES` (a package that cannot be found is left out): the name of numba's
    cache folder, so that an edit of any kernel's callee recompiles every kernel (see the
    module docstring)."""
    if folders is None:
        folders = []
        for name in KERNEL_PACKAGES:
            spec = importlib.util.find_spec(name)
            if spec is not None and spec.submodule_search_locations:
                folders.extend(spec.submodule_search_locations)
    return sources_hash([path for folder in folders for path in sorted(Path(folder).rglob("*.py"))])


def matplotlib_config_dir() -> Path:
    """Matplotlib's default config folder (where it would go without ``MPLCONFIGDIR``):
    ``$XDG_CONFIG_HOME/matplotlib`` or ``~/.config/matplotlib`` on Linux and the BSDs,
    ``~/.matplotlib`` elsewhere (as ``matplotlib.get_configdir`` finds it, without importing it)."""
    import sys

    if sys.platform.startswith(("linux", "freebsd")):
        xdg = os.environ.get("XDG_CONFIG_HOME")
        return Path(xdg or Path.home() / ".config") / "matplotlib"
    return Path.home() / ".matplotlib"


def _configure_matplotlib() -> None:
    """Point Matplotlib's config and font cache into ``matplotlib/`` of our cache when its own
    default folder cannot be written (it would warn on every import and rebuild its font cache
    each time); ``MPLCONFIGDIR``, when set, is left alone."""
    if os.environ.get("MPLCONFIGDIR"):
        return
    try:
        default = matplotlib_config_dir()
    except (RuntimeError, KeyError):  # no home directory at all
        default = Path("~")
    if not _could_write(default):
        os.environ["MPLCONFIGDIR"] = str(cache_dir("matplotlib", quiet=True))


def _could_write(folder: Path) -> bool:
    """Whether ``folder`` is, or could be created as, a writable folder, judged without
    creating anything (the home folder stays untouched when Matplotlib is never imported)."""
    if not folder.is_absolute():
        return False
    for p in (folder, *folder.parents):
        if p.exists():
            return p.is_dir() and os.access(p, os.W_OK | os.X_OK)
    return False


def _configure() -> None:
    """Export the resolved folder and point numba's cache into it (see the module docstring)."""
    root = cache_root(defer_warning=True)
    os.environ[ENV_VAR] = str(root)
    _resolved.setdefault(str(root), root)
    _configure_matplotlib()
    if not os.environ.get("NUMBA_CACHE_DIR"):
        import numba

        folder = cache_dir("numba", quiet=True) / kernel_sources_hash()
        # numba.config sets its names at run time (from the environment): none are declared
        numba.config.CACHE_DIR = str(folder)  # type: ignore[attr-defined]


_configure()
