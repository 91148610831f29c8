"""Files of long jobs: atomic writes and the manifest that ties an output folder to one config.

A job killed mid-write must leave either the old file or the new one, never half of one:
every write goes to a temporary file that is then renamed over the target. A resumable job
claims its folder with :func:`claim`: the first run writes the manifest, a later run with
another config is refused (so results of two configs never mix). :class:`ResumableRun` is the
output folder of such a job (bench, league, policy map, the strategy suite's pace races): the
claim, the records file, the missing tasks, their running and the adding of a finished one, in
one place.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import time
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

from experiments.infra.parallel import Pool, run_tasks_with_progress
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


def as_stored(obj):
    """``obj`` as it reads back from JSON (tuples become lists, dict keys strings), so that a
    config compares equal with the manifest it wrote."""
    return json.loads(json.dumps(obj))


def manifest_config(config, added: dict) -> dict:
    """``asdict(config)`` as a manifest records it: a field of ``added`` (name -> the value it
    defaults to) is left out while it has that value, so that a folder written before the
    field existed keeps its manifest and resumes."""
    from dataclasses import asdict

    return {k: v for k, v in asdict(config).items() if not (k in added and v == added[k])}


def claim(
    path, meta: dict, what: str, overwrite: bool = False, provenance: dict | None = None
) -> None:
    """Tie the folder of manifest ``path`` to ``meta``: write it if missing (or ``overwrite``),
    else raise a ValueError naming both configs when the stored one differs (compared as
    stored, :func:`as_stored`: a config's tuples equal the stored lists). ``what`` names
    the folder's content in the message ("a benchmark", "race data", ...).

    ``provenance`` (:func:`provenance`: package version, git commit, content hashes of the
    model files the agents load) is stored beside ``meta`` under ``"provenance"`` and checked
    on a resume by :func:`check_provenance`: changed weights are refused, a changed version or
    commit is warned about (naming both)."""
    path = Path(path)
    meta = as_stored(meta)
    if path.exists() and not overwrite:
        old = json.loads(path.read_text())
        stored_prov = old.pop("provenance", None)
        if "env" in meta and "env" not in old:  # made before manifests named the env
            old = {**old, "env": "alpha_racer_v1 or older"}
        if old != meta:
            diff = "; ".join(
                f"{k}: stored {old.get(k)!r}, this run {meta.get(k)!r}"
                for k in sorted(set(old) | set(meta), key=str)
                if old.get(k) != meta.get(k)
            )
            raise ValueError(
                f"{path.parent} holds {what} of another configuration ({diff}). "
                f"Use another --out or the same settings to resume"
            )
        if provenance is not None:
            merged = check_provenance(stored_prov, provenance, path.parent, what)
            if merged != stored_prov:
                write_json(path, {**json.loads(path.read_text()), "provenance": merged})
        return
    write_json(path, {**meta, "provenance": provenance} if provenance is not None else meta)


# ---------------------------------------------------------------------------- provenance
def sha256_file(path) -> str:
    """Hex SHA-256 of a file's content."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@functools.cache
def git_commit() -> str | None:
    """The commit of the git work tree the ``racing_env`` package is imported from (with
    ``+dirty`` when its tracked files have uncommitted changes), or None (an installed wheel,
    no git)."""
    import subprocess

    import racing_env

    root = Path(racing_env.__file__).resolve().parent.parent
    try:
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        if head.returncode:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def agent_model_files(spec: str, agent=None) -> list[Path]:
    """The model and checkpoint files the agent of ``spec`` loads: its ``model_files()`` if it
    has one (``ppo``: the checkpoint and a ``vecnormalize`` file); for ``alpha``, the shipped
    model its ``model`` names (every candidate of ``model=auto`` in the agent's policy space,
    :data:`agents.alpha_agent.AUTO_MODELS`) or the path; and any spec
    parameter value that is an existing file (a plugin's ``weights=...``)."""
    from agents import make_agent_spec

    agent = make_agent_spec(spec) if agent is None else agent
    files: list[Path] = []
    if callable(getattr(agent, "model_files", None)):
        files += [Path(f) for f in agent.model_files()]
    name = getattr(agent, "model_name", None)
    if spec.partition(":")[0] == "alpha" and isinstance(name, str):
        from agents.alpha_agent import AUTO_MODELS
        from agents.potential import MODEL_DIR, SHIPPED

        if name == "auto":  # a space without shipped models has none to list
            space = getattr(agent, "space", "paper")
            names = [n for n in AUTO_MODELS.get(space, ()) if n is not None]
        else:
            names = [name]
        files += [MODEL_DIR / SHIPPED[n] if n in SHIPPED else Path(n) for n in names]
    for item in filter(None, spec.partition(":")[2].split(",")):
        value = item.partition("=")[2].strip()
        if value and Path(value).is_file():
            files.append(Path(value))
    seen = {}
    for f in files:
        if f.is_file():
            seen.setdefault(str(f.resolve()), f)
    return list(seen.values())


def provenance(specs=(), agents=None) -> dict:
    """What made a run, for its manifest: ``package_version``, ``git_commit`` (None outside a
    git work tree) and ``model_files``: per agent spec, ``{path: sha256}`` of every model or
    checkpoint file it loads (:func:`agent_model_files`). ``agents``: already built agents of
    ``specs`` (same order), to avoid building them twice."""
    from racing_env import __version__

    files = {}
    for spec in dict.fromkeys(specs):
        agent = None if agents is None else agents[list(specs).index(spec)]
        found = agent_model_files(spec, agent)
        if found:
            files[spec] = {str(f.resolve()): sha256_file(f) for f in found}
    return {"package_version": __version__, "git_commit": git_commit(), "model_files": files}


def check_provenance(stored: dict | None, current: dict, folder, what: str) -> dict:
    """Compare a resumed run's stored provenance with this run's: a model file of an agent
    whose content changed is refused (``ValueError`` naming the agent, the file and both
    hashes: the races would mix two different agents); another package version or commit is
    warned about (naming both) and recorded under ``resumed_with``. Returns the provenance to
    store (the stored one, with the files of agents new to the run added)."""
    import warnings

    if not stored:
        return current
    changed = []
    merged_files = {k: dict(v) for k, v in stored.get("model_files", {}).items()}
    for spec, files in current.get("model_files", {}).items():
        old = merged_files.setdefault(spec, {})
        for path, digest in files.items():
            if path in old and old[path] != digest:
                changed.append(
                    f"agent {spec!r}: {path} was sha256 {old[path][:12]}..., now {digest[:12]}..."
                )
            old.setdefault(path, digest)
    if changed:
        raise ValueError(
            f"{folder} holds {what} raced with other weights, so resuming would mix "
            f"two different agents: {'; '.join(changed)}. Use another --out, or "
            f"restore the files"
        )
    merged = {**stored, "model_files": merged_files}
    code = ("package_version", "git_commit")
    if any(stored.get(k) != current.get(k) for k in code):
        warnings.warn(
            f"{folder}: resuming {what} made by alpha-racer {stored.get('package_version')} "
            f"(commit {stored.get('git_commit')}) with alpha-racer "
            f"{current.get('package_version')} (commit {current.get('git_commit')}); "
            f"its summary will hold races of both",
            RuntimeWarning,
            stacklevel=3,
        )
        seen = [{k: r.get(k) for k in code} for r in merged.get("resumed_with", [])]
        now = {k: current.get(k) for k in code}
        if now not in seen:
            merged["resumed_with"] = [*merged.get("resumed_with", []), now]
    return merged


def write_npz(path, compressed: bool = False, **arrays) -> Path:
    """Save ``arrays`` to the ``.npz`` file ``path`` atomically."""
    import numpy as np

    path = Path(path)
    with (
        atomic_path(path, ".npz") as tmp,
        open(tmp, "wb") as f,
    ):  # savez would append ".npz" to a name
        (np.savez_compressed if compressed else np.savez)(f, **arrays)
    return path


def record_run(path, what: dict, races: int, wall_seconds: float, pool) -> None:
    """Append one invocation's record to a run history (``runs.jsonl``): ``what`` it ran
    (e.g. ``{"config": ...}``), the ``races`` it simulated, its wall time [s], the
    ``pool``'s workers and backend, and when it finished."""
    append_jsonl(
        path,
        {
            **what,
            "races_simulated": races,
            "wall_seconds": wall_seconds,
            "workers": pool.workers,
            "backend": pool.backend,
            "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
        },
    )


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


def check_track_specs(tracks) -> None:
    """A ``ValueError`` unless ``tracks`` (a config's) are one or more distinct, non-empty track
    spec strings."""
    if (
        not tracks
        or len(set(tracks)) != len(tracks)
        or not all(isinstance(t, str) and t for t in tracks)
    ):
        raise ValueError(f"tracks must be distinct track specs, got {list(tracks)}")


def best_theta_spaces(specs) -> list[str]:
    """The policy spaces whose best-theta entries the agent specs of ``specs`` race
    (``theta=best``; the spec's ``space``, the paper's when it names none), in order of first
    use."""
    spaces = []
    for spec in specs:
        items = spec.replace(" ", "").partition(":")[2].split(",")
        params = dict(item.partition("=")[::2] for item in items if item)
        if params.get("theta") == "best":
            spaces.append(params.get("space", "paper"))
    return list(dict.fromkeys(spaces))


def uses_best_theta(specs) -> bool:
    """Whether any agent spec of ``specs`` races the best-theta table (``theta=best``)."""
    return bool(best_theta_spaces(specs))


def claim_best_thetas(
    folder, tracks, table=None, spaces=("paper",), vehicle_class: str = "orca"
) -> dict:
    """Tie ``folder`` (a run whose races use ``mpc:theta=best``, or ``theta=best`` in another
    policy space of ``spaces``) to the thetas the table now holds for ``tracks``:
    ``folder/best_fixed_theta.json`` records them (the paper's under ``config``, as before
    policy spaces; another space's under ``spaces``), and a later run after the table
    changed is refused (its races would mix two controls). The entries are those of the
    circuits at ``vehicle_class``'s scale. Returns the entries by space and track."""
    from agents.best_theta import lookup
    from racing_env.tracks import make_track

    tracks = list(dict.fromkeys(tracks))
    built = {t: make_track(t, vehicle_class=vehicle_class) for t in tracks}
    entries = {s: {t: lookup(built[t], table, s) for t in tracks} for s in dict.fromkeys(spaces)}
    meta = {
        "config": {
            t: {"theta": e["theta"], "env": e["env"]} for t, e in entries.get("paper", {}).items()
        }
    }
    others = {
        s: {t: {"theta": e["theta"], "env": e["env"]} for t, e in by_track.items()}
        for s, by_track in entries.items()
        if s != "paper"
    }
    if others:
        meta["spaces"] = others
    Path(folder).mkdir(parents=True, exist_ok=True)
    claim(Path(folder) / "best_fixed_theta.json", meta, "races of a best fixed theta")
    return entries


# ---------------------------------------------------------------------------- resumable runs
class ResumableRun:
    """The output folder of a resumable job of one configuration (:attr:`config`): a manifest
    that ties the folder to it (:meth:`claim`) and a JSON-lines file of finished records, one
    per task, appended and fsynced as each task finishes (:meth:`add`), so that a rerun does
    only the :meth:`missing` tasks (:meth:`run_missing`).

    A subclass sets :attr:`what` (the folder's content, for refusals) and
    :attr:`records_name`, and defines :meth:`tasks` (every task of the run, in order),
    :meth:`record_key` (a record's key) and, when a task is not its own key,
    :meth:`task_key`. :meth:`check_record` may drop a record (its other files are missing) or
    refuse it."""

    what = "a run"
    records_name = "records.jsonl"
    manifest_name = "manifest.json"

    def __init__(self, out_dir, config: Any):
        self.out = Path(out_dir)
        self.config = config
        self.out.mkdir(parents=True, exist_ok=True)

    @property
    def manifest_path(self) -> Path:
        return self.out / self.manifest_name

    @property
    def records_path(self) -> Path:
        return self.out / self.records_name

    def claim(
        self,
        meta: dict,
        agents=None,
        tracks=(),
        stored: dict | None = None,
        built=None,
        vehicle_class: str = "orca",
    ) -> None:
        """Tie the folder to ``meta`` (:func:`claim`). With ``agents``
        (agent specs), the run's :func:`provenance` is stored and checked on a resume, and
        when an agent races the best-theta table, the thetas of ``tracks`` (circuits at
        ``vehicle_class``'s scale) are claimed too
        (:func:`claim_best_thetas`). ``built``: the agents of ``agents`` already built (same
        order), so that the provenance does not build them again. ``stored``: the manifest
        the folder holds (as read) when the caller has checked it against this run and it
        differs from ``meta`` (a league that agents join holds the league before them): its
        provenance is checked, then the manifest is rewritten with ``meta`` and the merged
        provenance."""
        prov = None if agents is None else provenance(agents, built)
        if stored is None:
            claim(self.manifest_path, meta, self.what, provenance=prov)
        elif prov is None:
            write_json(self.manifest_path, meta)
        else:
            merged = check_provenance(stored.get("provenance"), prov, self.out, self.what)
            write_json(self.manifest_path, {**meta, "provenance": merged})
        spaces = best_theta_spaces(agents or ())
        if spaces:  # a changed table never mixes in
            claim_best_thetas(self.out, tracks, spaces=spaces, vehicle_class=vehicle_class)

    def tasks(self) -> list:
        """Every task of the run, in order."""
        raise NotImplementedError

    def task_key(self, task):
        """The key of ``task``'s record (the task itself by default)."""
        return task

    def record_key(self, record: dict):
        """The key of a finished ``record``."""
        raise NotImplementedError

    def check_record(self, record: dict) -> bool:
        """Whether ``record`` counts as finished (raise to refuse the folder)."""
        return True

    def records(self) -> dict:
        """Finished records by key; a torn (partly written) last line is ignored."""
        return {
            self.record_key(rec): rec
            for rec in read_jsonl(self.records_path)
            if self.check_record(rec)
        }

    def missing(self) -> list:
        """The tasks without a finished record, in order."""
        done = self.records()
        return [task for task in self.tasks() if self.task_key(task) not in done]

    def add(self, record: dict) -> None:
        """Store one finished record (one JSON line, flushed and fsynced)."""
        append_jsonl(self.records_path, record)

    def run_missing(
        self,
        fn: Callable[..., dict],
        args: Callable[[Any], tuple],
        pool: Pool,
        *,
        desc: str,
        unit: str,
        postfix: Callable[[Hashable, dict], str] | None = None,
        batch: int = 0,
    ) -> int:
        """Run the :meth:`missing` tasks, ``fn(*args(task))`` each, on ``pool``
        (:func:`run_missing`; with ``batch``, ``fn(*args(tasks))`` for up to ``batch`` tasks
        at once), storing each record (:meth:`add`) as it arrives, behind a progress bar over
        all the run's tasks (``desc``, ``unit``; ``postfix(key, record)`` with the task's
        :meth:`task_key` shows the last one). Returns the number of tasks run."""
        return run_missing(
            {None: self},
            fn,
            lambda run, task: args(task),
            pool,
            desc=desc,
            unit=unit,
            postfix=None if postfix is None else lambda key, record: postfix(key[1], record),
            batch=batch,
        )


def run_missing(
    runs: dict[Hashable, ResumableRun],
    fn: Callable[..., Any],
    args: Callable[[Any, Any], tuple],
    pool: Pool,
    *,
    desc: str,
    unit: str,
    postfix: Callable[[tuple, dict], str] | None = None,
    batch: int = 0,
) -> int:
    """Run the :meth:`~ResumableRun.missing` tasks of every run of ``runs`` (name -> run) in
    one pool, ``fn(*args(run, task))`` each (:func:`experiments.infra.parallel.run_tasks`), storing
    each record in its run (:meth:`~ResumableRun.add`) as it arrives, behind one progress bar
    over all the runs' tasks (``desc``, ``unit``; ``postfix((name, key), record)`` with the
    task's :meth:`~ResumableRun.task_key` shows the last one). Returns the number of tasks
    run.

    ``batch`` > 0: a pool task is up to ``batch`` tasks of one run, ``fn(*args(run, tasks))``
    with the list of tasks returning their records in order (races raced together); each
    batch is spread over the workers (at most ``ceil(missing / workers)`` tasks), and a
    killed run loses at most its unfinished batches."""
    if batch > 0:
        return _run_missing_batches(runs, fn, args, pool, desc, unit, postfix, batch)
    tasks = [
        ((name, run.task_key(task)), args(run, task))
        for name, run in runs.items()
        for task in run.missing()
    ]
    total = sum(len(run.tasks()) for run in runs.values())
    run_tasks_with_progress(
        fn,
        tasks,
        lambda key, record: runs[key[0]].add(record),
        pool,
        total=total,
        done=total - len(tasks),
        desc=desc,
        unit=unit,
        postfix=postfix,
    )
    return len(tasks)


def _run_missing_batches(runs, fn, args, pool, desc, unit, postfix, batch: int) -> int:
    """:func:`run_missing` with ``batch`` tasks of one run per pool task."""
    missing = {name: run.missing() for name, run in runs.items()}
    n_missing = sum(len(m) for m in missing.values())
    size = max(1, min(batch, -(-n_missing // max(1, pool.workers))))
    tasks = []
    for name, todo in missing.items():
        run = runs[name]
        for i in range(0, len(todo), size):
            chunk = todo[i : i + size]
            tasks.append(((name, tuple(run.task_key(t) for t in chunk)), args(run, chunk)))
    total = sum(len(run.tasks()) for run in runs.values())

    def finished(key, records):
        for record in records:
            runs[key[0]].add(record)

    run_tasks_with_progress(
        fn,
        tasks,
        finished,
        pool,
        total=total,
        done=total - n_missing,
        desc=desc,
        unit=unit,
        count=lambda key: len(key[1]),
        postfix=None if postfix is None else lambda key, records: postfix(key, records[-1]),
    )
    return n_missing
