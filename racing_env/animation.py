"""Animations of races: :func:`save_animation` writes frames to an animated ``.gif`` (PIL) or
``.mp4`` (ffmpeg), atomically; :func:`ffmpeg_available` tells beforehand whether ``.mp4`` can be
written here."""

from __future__ import annotations

import math
import numbers
import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from .files import atomic_path


def _check_frames(frames) -> list[np.ndarray]:
    if isinstance(frames, np.ndarray):
        if frames.ndim != 4:
            raise ValueError(f"frames array must have shape (T, H, W, 3), got {frames.shape}")
        frames = list(frames)
    elif isinstance(frames, Iterable) and not isinstance(frames, (str, bytes)):
        frames = list(frames)
    else:
        raise ValueError(
            f"frames must be a sequence of (H, W, 3) uint8 arrays, got {type(frames).__name__}"
        )
    if not frames:
        raise ValueError("frames is empty: nothing to save")
    shape0 = None
    for i, f in enumerate(frames):
        if not isinstance(f, np.ndarray):
            raise ValueError(f"frame {i} is a {type(f).__name__}, expected a numpy array")
        if f.dtype != np.uint8:
            raise ValueError(f"frame {i} has dtype {f.dtype}, expected uint8")
        if f.ndim != 3 or f.shape[2] != 3 or f.shape[0] < 1 or f.shape[1] < 1:
            raise ValueError(f"frame {i} has shape {f.shape}, expected (H, W, 3)")
        if shape0 is None:
            shape0 = f.shape
        elif f.shape != shape0:
            raise ValueError(f"frame {i} has shape {f.shape}, but frame 0 has {shape0}")
    return frames


def _check_fps(fps) -> float:
    if (
        isinstance(fps, bool)
        or not isinstance(fps, numbers.Real)
        or not math.isfinite(fps)
        or fps <= 0
    ):
        raise ValueError(f"fps must be a positive finite number, got {fps!r}")
    return float(fps)


def ffmpeg_available() -> bool:
    """Whether :func:`save_animation` can write ``.mp4`` here (an ffmpeg on ``PATH`` or from
    imageio-ffmpeg); check it before a long run whose animation needs it."""
    return _find_ffmpeg() is not None


def _find_ffmpeg() -> str | None:
    exe = shutil.which("ffmpeg")
    if exe:
        return exe
    try:  # imageio's bundled ffmpeg, if installed
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except Exception:
        return None


def _write_gif(frames: list[np.ndarray], tmp: str, fps: float) -> None:
    # one global palette from up to 8 evenly spaced frames: consistent colours, no flicker
    idx = np.unique(np.linspace(0, len(frames) - 1, min(8, len(frames))).round().astype(int))
    sample = Image.fromarray(np.concatenate([frames[i] for i in idx], axis=0))
    pal = sample.quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    images = [Image.fromarray(f).quantize(palette=pal, dither=Image.Dither.NONE) for f in frames]
    duration = max(int(round(1000.0 / fps)), 10)  # ms; GIF stores centiseconds
    images[0].save(
        tmp,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=duration,
        loop=0,
        optimize=False,
        disposal=1,
    )


def _write_mp4(frames: list[np.ndarray], tmp: str, fps: float, ffmpeg: str) -> None:
    h, w = frames[0].shape[:2]
    base = [
        ffmpeg,
        "-y",
        "-loglevel",
        "error",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        f"{w}x{h}",
        "-r",
        f"{fps:g}",
        "-i",
        "-",
        "-an",
        "-vf",
        "pad=ceil(iw/2)*2:ceil(ih/2)*2",
    ]
    codecs = (
        ["-c:v", "libx264", "-pix_fmt", "yuv420p", "-movflags", "+faststart"],
        ["-c:v", "mpeg4", "-q:v", "3", "-pix_fmt", "yuv420p"],
    )
    errors = []
    for codec in codecs:
        with tempfile.TemporaryFile() as err:
            proc = subprocess.Popen(
                base + codec + ["-f", "mp4", tmp],
                stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL,
                stderr=err,
            )
            stdin = proc.stdin
            assert stdin is not None  # stdin=PIPE
            try:
                for f in frames:
                    stdin.write(np.ascontiguousarray(f).tobytes())
                stdin.close()
            except (BrokenPipeError, OSError):
                pass
            rc = proc.wait()
            if rc == 0:
                return
            err.seek(0)
            errors.append(
                f"{codec[1]}: exit {rc}: {err.read().decode(errors='replace').strip()[-500:]}"
            )
    raise RuntimeError("ffmpeg failed to write the mp4: " + " | ".join(errors))


def save_animation(frames: Sequence[np.ndarray], path: str | os.PathLike, fps: float = 10) -> Path:
    """Write frames to an animated ``.gif`` or ``.mp4`` file; returns the path.

    Parameters
    ----------
    frames : sequence of np.ndarray
        T >= 1 frames, each (H, W, 3) uint8, all the same shape (or one (T, H, W, 3) array).
    path : str or PathLike
        Output file; the suffix picks the format (``.gif`` or ``.mp4``, any case). The parent
        folder is created if needed. The file is written to a temporary file in the same
        folder and moved into place with ``os.replace``, so it is either complete or absent.
    fps : float
        Frames per second (> 0). GIF stores frame durations in 1/100 s, so the GIF duration is
        ``round(1000 / fps)`` ms rounded to 10 ms (at least 10 ms); consecutive identical frames
        are merged by PIL into one longer frame.

    Raises
    ------
    ValueError
        Empty frames, wrong dtype/shape, unknown suffix, fps <= 0.
    RuntimeError
        ``.mp4`` requested but no ffmpeg executable was found (or ffmpeg failed).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(
            f"unknown animation suffix {path.suffix!r} in {str(path)!r}; use .gif or .mp4"
        )
    fps = _check_fps(fps)
    frames = _check_frames(frames)
    ffmpeg = None
    if suffix == ".mp4":
        ffmpeg = _find_ffmpeg()
        if ffmpeg is None:
            raise RuntimeError(
                f"cannot write {str(path)!r}: ffmpeg is missing (not on PATH and "
                f"imageio-ffmpeg not installed); install ffmpeg or save as .gif"
            )
    with atomic_path(path, suffix) as tmp:
        if suffix == ".gif":
            _write_gif(frames, str(tmp), fps)
        else:
            assert ffmpeg is not None  # found above
            _write_mp4(frames, str(tmp), fps, ffmpeg)
    return path
