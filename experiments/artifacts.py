"""Files of long jobs: atomic writes and the manifest that ties an output folder to one config.

A job killed mid-write must leave either the old file or the new one, never half of one:
every write goes to a temporary file that is then renamed over the target. A resumable job
claims its folder with :func:`claim`: the first run writes the manifest, a later run with
another config is refused (so results of two configs never mix).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from racing_env.files import atomic_path


def slug(spec: str) -> str:
    """An agent or track spec as a file-name part: characters other than letters, digits,
    ``.`` and ``-`` become ``_`` (``mpc:zeta=0.9`` -> ``mpc_zeta_0.9``)."""
    return "".join(ch if ch.isalnum() or ch in ".-" else "_" for ch in spec)


def env_version() -> str:
    """The env version races run on (PettingZoo ``metadata["name"]``, e.g. ``alpha_racer_v2``).
    Race folders store it in their manifest, so races of two env versions never mix."""
    from racing_env.parallel_env import RacingParallelEnv
    return RacingParallelEnv.metadata["name"]


def write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (temporary file, then rename)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path


def write_json(path, obj) -> Path:
    """Write ``obj`` as indented JSON to ``path`` atomically."""
    return write_text(path, json.dumps(obj, indent=2))


def claim(path, meta: dict, what: str, overwrite: bool = False) -> None:
    """Tie the folder of manifest ``path`` to ``meta``: write it if missing (or ``overwrite``),
    else raise a ValueError naming both configs when the stored one differs. ``what`` names
    the folder's content in the message ("a benchmark", "race data", ...)."""
    path = Path(path)
    if path.exists() and not overwrite:
        old = json.loads(path.read_text())
        if "env" in meta and "env" not in old:     # made before manifests named the env
            old = {**old, "env": "alpha_racer_v1 or older"}
        if old != meta:
            diff = "; ".join(f"{k}: stored {old.get(k)!r}, this run {meta.get(k)!r}"
                             for k in sorted(set(old) | set(meta), key=str)
                             if old.get(k) != meta.get(k))
            raise ValueError(f"{path.parent} holds {what} of another configuration ({diff}). "
                             f"Use another --out or the same settings to resume")
        return
    write_json(path, meta)


def write_npz(path, compressed: bool = False, **arrays) -> Path:
    """Save ``arrays`` to the ``.npz`` file ``path`` atomically."""
    import numpy as np
    path = Path(path)
    with atomic_path(path, ".npz") as tmp, open(tmp, "wb") as f:   # savez would append ".npz" to a name
        (np.savez_compressed if compressed else np.savez)(f, **arrays)
    return path


def append_jsonl(path, obj) -> None:
    """Append ``obj`` as one JSON line to ``path``, flushed to disk (a finished record survives
    a kill). A torn last line left by an earlier kill is closed first, so it stays one bad
    line that :func:`read_jsonl` skips."""
    path = Path(path)
    torn = False
    if path.exists() and path.stat().st_size:
        with open(path, "rb") as f:
            f.seek(-1, os.SEEK_END)
            torn = f.read(1) != b"\n"
    with open(path, "a") as f:
        f.write(("\n" if torn else "") + json.dumps(obj) + "\n")
        f.flush()
        os.fsync(f.fileno())


def read_jsonl(path) -> list:
    """The records of a JSON-lines file (none if it is missing), skipping torn lines."""
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return out


def uses_best_theta(specs) -> bool:
    """Whether any agent spec of ``specs`` races the best-theta table (``theta=best``)."""
    return any("theta=best" in spec.replace(" ", "") for spec in specs)


def claim_best_thetas(folder, tracks, table=None) -> dict:
    """Tie ``folder`` (a run whose races use ``mpc:theta=best``) to the thetas the table now
    holds for ``tracks``: ``folder/best_fixed_theta.json`` records them, and a later run after
    the table changed is refused (its races would mix two controls). Returns the entries."""
    from agents.best_theta import lookup
    entries = {t: lookup(t, table) for t in dict.fromkeys(tracks)}
    Path(folder).mkdir(parents=True, exist_ok=True)
    claim(Path(folder) / "best_fixed_theta.json",
          {"config": {t: {"theta": e["theta"], "env": e["env"]} for t, e in entries.items()}},
          "races of a best fixed theta")
    return entries
