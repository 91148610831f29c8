"""Download the TUMFTM racetrack-database at a pinned commit into the cache folder.

Intended use, from the command line (the ``alpha-racer circuits download`` command calls
:func:`main`)::

    alpha-racer circuits download            # all 25 circuits into <cache>/tumftm/
    alpha-racer circuits download --force    # download again, replacing the folder
    alpha-racer circuits download --dest DIR # somewhere else (then set ALPHA_RACER_TUMFTM=DIR)

or from Python::

    from racing_env.circuits.download import download_racetrack_database
    folder = download_racetrack_database()   # Path of the folder of CSVs

Afterwards ``make_track("tumftm:Suzuka")`` finds every circuit of the database (see
:func:`racing_env.tracks.tumftm_file` for the lookup order).

What it does: fetches the GitHub archive of :data:`PINNED_COMMIT`, takes the track files
``tracks/*.csv`` and the licence, checks the SHA-256 of every track file against
:data:`TRACK_SHA256` (a file missing, extra or different is an error naming the file and, for a
difference, both hashes) and only then moves the finished folder into place with one rename:
an interrupted or failed download leaves the previous folder (or none) and no half-filled one.
Partial folders left by a killed process (``.tumftm.partial-*`` next to the folder) are removed
by the next download once they are an hour old.

The checksum table was computed from the project's copy of the database and matches the
files of the same names read at the upstream repository's commits (see ``README.md`` here).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import tarfile
import tempfile
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager
from pathlib import Path
from typing import IO

REPOSITORY = "TUMFTM/racetrack-database"
"""The upstream GitHub repository (LGPL-3.0)."""

PINNED_COMMIT = "e59595d1f3573b30d1ded6a08984935b957688e0"
"""The commit of the racetrack-database whose track files :data:`TRACK_SHA256` describes."""

ARCHIVE_URL = "https://github.com/{repository}/archive/{commit}.tar.gz"
"""Where the archive of a commit is fetched from (``repository``, ``commit``)."""

FOLDER_NAME = "tumftm"
"""Name of the download folder inside the cache folder."""

SOURCE_FILE = "SOURCE.json"
"""File written into the download folder: repository, commit, URL and the checksums."""

STALE_SECONDS = 3600.0
"""Age after which a partial folder of a killed download is removed."""

TRACK_SHA256: dict[str, str] = {
    "Austin": "60d46180320177ba49bec61bad390872039222dbab225fe12781ca662becda55",
    "BrandsHatch": "9c69b09cef717d8abffc7c9450e59d7e339ac0dd0c7ed8121d73fe2f373145bb",
    "Budapest": "3c25a55841af6de1e78a366593108835738d78e75cedfb7acd11c9b36da53d5a",
    "Catalunya": "8d6dc9d50e98bdecd818cb880a4b12bb5cec25d699a6b774e0b593c0f8a9da5e",
    "Hockenheim": "5eb6b7d8ff7b9fc905b38caed9a65d8e76e4bd7af5af9ba82aecdf4a6e0eacc5",
    "IMS": "4254dc23f263bbe6c85c67e48d9a466e4f710da03f1370dff3fdc378de705471",
    "Melbourne": "f9ea4395a25dc4189d8b8c692ce9656682de62ad7b784dfd7c024ac8d4f245e9",
    "MexicoCity": "fc16f83e3e81308a47b8726439f0ff3bb7ce7593f0fdcea053d61e47a14c89f3",
    "Montreal": "0b27cf74193ea20ebab058a300cd935d2c07bb6003a898e108febcd63a3c42be",
    "Monza": "4b5993986e67950df1b89efa03a4df02127f07b7213985917f0bad27ad3d48b6",
    "MoscowRaceway": "843c0f47e7210b5c9bfb3bf2f55cfee02cced0970f9b711a951b650c5cad3753",
    "Norisring": "8857d3c362ad2923c1f93c8d257498f50459770b9021adcc7969b71085c31d9a",
    "Nuerburgring": "9fea2a9daa25311bb251be416140b6c55cb2e53bb4f69c28f512fbfce25a3f87",
    "Oschersleben": "9ce893ee1fde37cc0626d654b765e65cd7159ffca922496ab881d61cad6ab304",
    "Sakhir": "bc3c23da42f9474dbf5700341037bb45521acaa2ad1389bd0a48540fe179ee7a",
    "SaoPaulo": "7383caa2b7af9af6c321aa5442cc5b47b6cfe1a56f70b56f3216ba1a3c015a04",
    "Sepang": "89ee026fd439e9b41311fc742b44efb120c3c1148f55e5963b38b62971352eaf",
    "Shanghai": "3bef7580e6ec9f8e2daac23445c4c81ae23e13aa6b92e4204281e143eabee277",
    "Silverstone": "27c51454e81780a75c353d3e6c9f73dbbcd1e82139782e95bd722ade19736e39",
    "Sochi": "caf3f00d78a7b54aeab131d2a8f263131c33d5431292a05dcbaaad49a19c351c",
    "Spa": "952673dfa772427be8a9013b8c1cb5ff5935f85c0c21d2a223adb04c6d640c8a",
    "Spielberg": "277b2854c4323021b10b6b63ebfe6a6cc971f494c0728202e910d67d7d65dc8c",
    "Suzuka": "b4d3e325edd1e85e4e73765a80f7203b741e6dff5cceec4260390716c10eee67",
    "YasMarina": "befab5a3be5a6ab320ce16d5ac5ec9016d633c5d6e739b9483f4d6364f0fe017",
    "Zandvoort": "f3f2a82c9f41bcee8d7161a6ad6c0b8e6d4b902dd772459918c9fe7f7451bc59",
}
"""SHA-256 of every ``tracks/NAME.csv`` of the racetrack-database at :data:`PINNED_COMMIT`."""

Opener = Callable[[str], AbstractContextManager[IO[bytes]]]
"""Opens a URL for reading bytes (default :func:`urllib.request.urlopen` with a timeout)."""


class ChecksumError(ValueError):
    """A downloaded file is missing, unexpected, or differs from the pinned checksum table."""


def default_dest() -> Path:
    """``<cache folder>/tumftm`` (:func:`racing_env.cache.cache_root`), where downloads go and
    where :func:`racing_env.tracks.tumftm_file` looks."""
    from ..cache import cache_root

    return cache_root() / FOLDER_NAME


def archive_url(commit: str = PINNED_COMMIT, repository: str = REPOSITORY) -> str:
    """The GitHub archive URL of ``commit``."""
    return ARCHIVE_URL.format(repository=repository, commit=commit)


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def verify_tracks(folder: str | os.PathLike, checksums: Mapping[str, str] = TRACK_SHA256) -> None:
    """Check that ``folder`` holds exactly the track CSVs of ``checksums`` (name -> SHA-256),
    each with its checksum. Raises :class:`ChecksumError` naming the first bad file."""
    folder = Path(folder)
    found = {p.stem for p in folder.glob("*.csv")}
    missing = sorted(set(checksums) - found)
    if missing:
        raise ChecksumError(
            f"racetrack-database: {len(missing)} track file(s) missing from {folder}: "
            f"{', '.join(m + '.csv' for m in missing)}"
        )
    extra = sorted(found - set(checksums))
    if extra:
        raise ChecksumError(
            f"racetrack-database: track file(s) not in the checksum table: "
            f"{', '.join(e + '.csv' for e in extra)} (in {folder})"
        )
    for name in sorted(checksums):
        got = sha256_file(folder / f"{name}.csv")
        if got != checksums[name]:
            raise ChecksumError(
                f"racetrack-database: checksum mismatch for tracks/{name}.csv: "
                f"expected SHA-256 {checksums[name]}, got {got}"
            )


def _is_complete(dest: Path, commit: str, checksums: Mapping[str, str]) -> bool:
    try:
        source = json.loads((dest / SOURCE_FILE).read_text())
        if source.get("commit") != commit:
            return False
        verify_tracks(dest, checksums)
    except (OSError, ValueError):
        return False
    return True


def _remove_stale(dest: Path) -> None:
    """Remove partial / replaced folders of earlier downloads that are over an hour old."""
    now = time.time()
    for pattern in (f".{dest.name}.partial-*", f".{dest.name}.old-*"):
        for p in dest.parent.glob(pattern):
            try:
                if now - p.stat().st_mtime > STALE_SECONDS:
                    shutil.rmtree(p, ignore_errors=True)
            except OSError:
                pass


def _default_opener(url: str) -> AbstractContextManager[IO[bytes]]:
    from urllib.request import urlopen

    return urlopen(url, timeout=60)


def _fetch(url: str, target: Path, opener: Opener, progress: bool) -> None:
    from contextlib import ExitStack

    with ExitStack() as stack:
        try:
            response = stack.enter_context(opener(url))
        except OSError as exc:  # no network, a bad mirror: name what was asked for
            raise OSError(
                f"cannot download {url} ({exc}); on a machine without access, fetch that "
                f"archive elsewhere and pass it as --url file:///path/to/archive.tar.gz"
            ) from exc
        _copy(response, target, progress)


def _copy(response: IO[bytes], target: Path, progress: bool) -> None:
    with open(target, "wb") as out:
        total = None
        headers = getattr(response, "headers", None)
        if headers is not None and headers.get("Content-Length"):
            total = int(headers["Content-Length"])
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=total, unit="B", unit_scale=True, desc="racetrack-database")
        try:
            for chunk in iter(lambda: response.read(1 << 16), b""):
                out.write(chunk)
                if bar is not None:
                    bar.update(len(chunk))
        finally:
            if bar is not None:
                bar.close()


def _extract(archive: Path, into: Path) -> None:
    """Copy ``<top>/tracks/*.csv`` and ``<top>/LICENSE`` of the archive into ``into`` (by base
    name only: nothing is written outside ``into``)."""
    try:
        tar = tarfile.open(archive, "r:*")
    except tarfile.TarError as exc:
        raise ValueError(f"racetrack-database: the download is not a tar archive ({exc})") from None
    with tar:
        for member in tar:
            parts = member.name.split("/")
            if not member.isfile() or len(parts) not in (2, 3):
                continue
            wanted = (len(parts) == 3 and parts[1] == "tracks" and parts[2].endswith(".csv")) or (
                len(parts) == 2 and parts[1] in ("LICENSE", "README.md")
            )
            if not wanted:
                continue
            src = tar.extractfile(member)
            if src is None:
                continue
            with src, open(into / parts[-1], "wb") as out:
                shutil.copyfileobj(src, out)


def download_racetrack_database(
    dest: str | os.PathLike | None = None,
    commit: str = PINNED_COMMIT,
    *,
    checksums: Mapping[str, str] | None = None,
    url: str | None = None,
    opener: Opener | None = None,
    force: bool = False,
    progress: bool = False,
) -> Path:
    """Download the racetrack-database's track files at ``commit`` into ``dest`` and return it.

    ``dest`` defaults to :func:`default_dest` (``<cache folder>/tumftm``). The folder then
    holds ``NAME.csv`` for every circuit, the database's ``LICENSE`` (LGPL-3.0) and
    ``README.md``, and ``SOURCE.json`` (repository, commit, URL, checksums). A folder that
    already holds this commit's verified files is returned as it is unless ``force``.

    ``checksums`` (name -> SHA-256 of ``tracks/NAME.csv``) defaults to :data:`TRACK_SHA256`,
    which belongs to :data:`PINNED_COMMIT`: another ``commit`` needs its own table.
    ``url`` (default: the GitHub archive of ``commit``) and ``opener`` (a function opening a
    URL for reading bytes; default ``urllib.request.urlopen``) are for mirrors and tests.
    ``progress`` shows a tqdm bar.

    Raises :class:`ChecksumError` (a ``ValueError``) when a file is missing, unexpected or
    differs, naming it and both hashes, ``ValueError`` for an archive that is not a tar file
    and ``OSError`` for network or disk errors; in every case ``dest`` is left as it was.
    """
    if checksums is None:
        if commit != PINNED_COMMIT:
            raise ValueError(
                f"no checksum table for racetrack-database commit {commit!r} (the built-in one "
                f"is for {PINNED_COMMIT}); pass checksums={{name: sha256}}"
            )
        checksums = TRACK_SHA256
    dest = Path(dest) if dest is not None else default_dest()
    dest = dest.expanduser().absolute()
    if not force and _is_complete(dest, commit, checksums):
        return dest
    dest.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(dest)
    url = url or archive_url(commit)
    partial = Path(tempfile.mkdtemp(prefix=f".{dest.name}.partial-", dir=dest.parent))
    try:
        archive = partial / "archive.tar.gz"
        _fetch(url, archive, opener or _default_opener, progress)
        folder = partial / dest.name
        folder.mkdir()
        _extract(archive, folder)
        verify_tracks(folder, checksums)
        source = {
            "repository": REPOSITORY,
            "commit": commit,
            "url": url,
            "license": "LGPL-3.0 (see LICENSE)",
            "sha256": dict(sorted(checksums.items())),
        }
        (folder / SOURCE_FILE).write_text(json.dumps(source, indent=1) + "\n")
        if dest.exists():
            old = dest.with_name(f".{dest.name}.old-{uuid.uuid4().hex}")
            os.replace(dest, old)
            os.replace(folder, dest)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(folder, dest)
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return dest


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``alpha-racer circuits download`` (and of :func:`main`) on ``parser``."""
    parser.add_argument(
        "--dest",
        default=None,
        help="folder to store the circuits in (default: <cache>/tumftm; for another folder "
        "set ALPHA_RACER_TUMFTM to it)",
    )
    parser.add_argument("--force", action="store_true", help="download again even if present")
    parser.add_argument("--url", default=None, help="archive URL (a mirror); default: GitHub")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


DESCRIPTION = (
    f"Download the circuits of the TUMFTM racetrack-database (LGPL-3.0) at commit "
    f"{PINNED_COMMIT[:12]}, check every file's SHA-256 and store them in the cache "
    f"folder, where make_track('tumftm:NAME') finds them."
)


def run(args: argparse.Namespace, prog: str = "alpha-racer circuits download") -> int:
    """Download as the parsed options of :func:`add_arguments` say. Returns the exit status: 0
    on success, 1 on a failed download (the message on stderr)."""
    import sys

    try:
        folder = download_racetrack_database(
            args.dest, url=args.url, force=args.force, progress=not args.quiet
        )
    except (OSError, ValueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    print(f"{len(TRACK_SHA256)} circuits in {folder} (racetrack-database {PINNED_COMMIT[:12]})")
    return 0


def main(argv: Sequence[str] | None = None, prog: str = "alpha-racer circuits download") -> int:
    """Command line of :func:`download_racetrack_database` (``alpha-racer circuits download``,
    or ``python -m racing_env.circuits.download``). Returns the exit status (see :func:`run`)."""
    parser = argparse.ArgumentParser(prog=prog, description=DESCRIPTION)
    add_arguments(parser)
    return run(parser.parse_args(argv), prog)


if __name__ == "__main__":
    raise SystemExit(main())
