"""The racing lines' cache: :func:`get_raceline` from an in-process memo, else a ``.npz`` file
in ``raceline/`` of the alpha-racer cache folder (keyed by :func:`cache_key`), else computed
and stored."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from ..cache import cache_dir as _cache_folder
from ..files import atomic_path
from ..track import Track
from ..vehicle import VehicleParams
from ..vehicles.fullsize import FullSizeParams
from .config import CACHE_VERSION, AnyVehicle, RacelineConfig, cache_key
from .optimise import compute_raceline
from .result import Raceline

_MEMO: dict[str, Raceline] = {}


def cache_dir() -> Path:
    """Folder of cached racing lines: ``raceline/`` of the alpha-racer cache folder
    (``$ALPHA_RACER_CACHE``, else the per-user cache; see :mod:`racing_env.cache`)."""
    return _cache_folder("raceline")


def cache_path(
    track: Track, vehicle: AnyVehicle | None = None, config: RacelineConfig | None = None
) -> Path:
    """The .npz file :func:`get_raceline` uses for these inputs."""
    key = cache_key(track, vehicle or VehicleParams(), config or RacelineConfig())
    safe = "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in track.name)[:40]
    return cache_dir() / f"{safe}_{key}.npz"


def _load(path: Path, key: str) -> Raceline | None:
    try:
        with np.load(path, allow_pickle=False) as d:
            rl = Raceline.from_npz_dict(d)
        if rl.key != key or getattr(rl, "_meta_version", None) != CACHE_VERSION:
            return None
        return rl
    except Exception:  # corrupt, truncated, old or foreign file: recompute
        return None


def _save(path: Path, rl: Raceline) -> None:
    try:
        with atomic_path(path, ".npz") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **rl.to_npz_dict())
    except OSError as exc:
        warnings.warn(
            f"could not write racing-line cache {path}: {exc}", RuntimeWarning, stacklevel=3
        )


def get_raceline(
    track: Track | str,
    vehicle: AnyVehicle | None = None,
    config: RacelineConfig | None = None,
    use_cache: bool = True,
) -> Raceline:
    """The racing line of ``track`` (a :class:`Track` or a :func:`~racing_env.tracks.make_track`
    name) for ``vehicle`` and ``config``, from the in-process memo, else the disk cache
    (:func:`cache_path`), else computed by :func:`compute_raceline` and stored (written to a
    temporary file and moved into place, so readers never see half a file). An unreadable,
    corrupt or mismatched cache file is recomputed and overwritten. ``use_cache=False`` skips
    both caches (and writes nothing).

    ``vehicle``: a :class:`VehicleParams` (the ORCA car, default) or a
    :class:`~racing_env.vehicles.fullsize.FullSizeParams` (the full-size class: a track named
    by a string is then built at full scale, and its racing-line settings are best
    ``racing_env.scaling.scaled_configs(vehicle).raceline``).
    """
    if not isinstance(track, Track):
        from ..tracks import make_track

        full = isinstance(vehicle, FullSizeParams)
        track = make_track(track, vehicle_class="fullsize" if full else None)
    vehicle = vehicle if vehicle is not None else VehicleParams()
    config = config if config is not None else RacelineConfig()
    if not isinstance(vehicle, (VehicleParams, FullSizeParams)):
        raise ValueError(
            f"vehicle must be a VehicleParams or a FullSizeParams, got {type(vehicle).__name__}"
        )
    if not isinstance(config, RacelineConfig):
        raise ValueError(f"config must be a RacelineConfig, got {type(config).__name__}")
    if not use_cache:
        return compute_raceline(track, vehicle, config)
    key = cache_key(track, vehicle, config)
    path = cache_path(track, vehicle, config)
    memo_key = f"{path}"
    rl = _MEMO.get(memo_key)
    if rl is not None and rl.key == key:
        return rl
    rl = _load(path, key) if path.is_file() else None
    if rl is not None:
        rl.from_cache = True
        rl.track = track
    else:
        rl = compute_raceline(track, vehicle, config)
        _save(path, rl)
    _MEMO[memo_key] = rl
    return rl


def clear_memo() -> None:
    """Forget the in-process memo of :func:`get_raceline` (disk files stay)."""
    _MEMO.clear()
