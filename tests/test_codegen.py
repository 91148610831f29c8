"""The MPC's predictions as C libraries: several compiled at once (one compiler process each),
the same libraries and results as one at a time, a failing or killed compile falling back to
CasADi for its own library only, and one library per platform in a shared cache folder."""

import os
import shutil
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from agents.mpc import MPCConfig, codegen
from agents.mpc.codegen import CompiledTrajectory, InterpretedTrajectory
from agents.mpc.prediction import trajectory_function, trajectory_functions
from racing_env.vehicle import VehicleParams

CFG = MPCConfig(horizon=5)  # small libraries: quick compiles
GCC = shutil.which("gcc") or shutil.which("cc")
needs_cc = pytest.mark.skipif(GCC is None, reason="no C compiler")


@pytest.fixture(autouse=True)
def fresh_process(monkeypatch, tmp_path):
    """An empty cache folder and the compiler fallback as in a new process."""
    monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.setattr(codegen, "_WARNED", False)
    monkeypatch.setattr(codegen, "_FAILED", set())


def _cc(path: Path, body: str) -> str:
    """A compiler script (``$CC``) running ``body`` in sh; ``$GCC`` is the real compiler."""
    path.write_text(f'#!/bin/sh\nGCC="{GCC}"\n' + body)
    path.chmod(0o755)
    return str(path)


def _inputs(cfg: MPCConfig):
    K = cfg.horizon
    x0 = np.array([1.0, 0.05, 0.02, 2.0, 0.1, 0.3])
    U = np.tile([[0.5], [0.1]], (1, K))
    kap = np.full((cfg.substeps, K), 0.5)
    return x0, U, kap


def _files(cache: Path) -> list[str]:
    return sorted(p.name for p in (cache / "mpc").iterdir())


@needs_cc
def test_compiled_together_equals_compiled_one_at_a_time(tmp_path, monkeypatch):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # compiled, not interpreted
        both = trajectory_functions(VehicleParams(), CFG)
        monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path / "other"))
        one = (
            trajectory_function(VehicleParams(), CFG),
            trajectory_function(VehicleParams(), CFG, jacobians=False),
        )
    assert all(isinstance(t, CompiledTrajectory) for t in both + one)
    names = _files(tmp_path / "cache")
    assert names == _files(tmp_path / "other") and len(names) == 2
    assert [n.split("_")[1] for n in names] == ["roll", "traj"]
    for a, b in zip(both, one):
        outs_a, outs_b = a(*_inputs(CFG)), b(*_inputs(CFG))
        assert len(outs_a) == len(outs_b) == (3 if a is both[0] else 1)
        for x, y in zip(outs_a, outs_b):
            np.testing.assert_array_equal(x, y)


@needs_cc
def test_loaded_again_the_prediction_has_its_own_workspace(tmp_path):
    """The second load of the same prediction reuses its generated code (no new graph) but
    gets its own buffers, so that two MPCs never share a workspace; a library removed from
    the cache is built again."""
    first = trajectory_functions(VehicleParams(), CFG)
    second = trajectory_functions(VehicleParams(), CFG)
    for a, b in zip(first, second):
        assert a is not b and not np.shares_memory(a.ws, b.ws)
        x, y = a(*_inputs(CFG))[0].copy(), b(*_inputs(CFG))[0]
        np.testing.assert_array_equal(x, y)
    for lib in (tmp_path / "cache" / "mpc").iterdir():
        lib.unlink()
    third = trajectory_functions(VehicleParams(), CFG)
    assert len(_files(tmp_path / "cache")) == 2
    np.testing.assert_array_equal(third[0](*_inputs(CFG))[0], x)


@needs_cc
def test_the_compilers_run_at_the_same_time(tmp_path, monkeypatch):
    """Each compiler waits (up to 60 s) for the other one to start: both see the other."""
    log = tmp_path / "cc.log"
    script = f"""
echo start >> "{log}"
i=0
while [ "$(grep -c start "{log}")" -lt 2 ] && [ $i -lt 600 ]; do sleep 0.1; i=$((i+1)); done
if [ "$(grep -c start "{log}")" -ge 2 ]; then echo together >> "{log}"; fi
exec "$GCC" "$@"
"""
    monkeypatch.setenv("CC", _cc(tmp_path / "cc", script))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        traj, roll = trajectory_functions(VehicleParams(), CFG)
    assert isinstance(traj, CompiledTrajectory) and isinstance(roll, CompiledTrajectory)
    assert log.read_text().split() == ["start", "start", "together", "together"]


@needs_cc
def test_one_failing_compile_falls_back_alone_with_one_warning(tmp_path, monkeypatch):
    script = 'case "$*" in *mpc_roll*) echo "no room for the rollout" >&2; exit 2;; esac\n'
    monkeypatch.setenv("CC", _cc(tmp_path / "cc", script + 'exec "$GCC" "$@"\n'))
    with pytest.warns(RuntimeWarning) as record:
        traj, roll = trajectory_functions(VehicleParams(), CFG)
    assert len(record) == 1 and "no room for the rollout" in str(record[0].message)
    assert isinstance(traj, CompiledTrajectory) and isinstance(roll, InterpretedTrajectory)
    assert [n.split("_")[1] for n in _files(tmp_path / "cache")] == ["traj"]
    np.testing.assert_allclose(
        roll(*_inputs(CFG))[0], traj(*_inputs(CFG))[0], rtol=1e-9, atol=1e-12
    )
    with warnings.catch_warnings():  # not compiled again in this process, not warned again
        warnings.simplefilter("error")
        again = trajectory_function(VehicleParams(), CFG, jacobians=False)
    assert isinstance(again, InterpretedTrajectory)


@pytest.mark.parametrize(
    "body, why",
    [
        ("kill -9 $$\n", "exit status -9"),  # killed while it compiles
        ("exit 0\n", "wrote no library"),  # claims success, writes nothing
        ('"$GCC" "$@"; echo broken > "$(echo "$@" | sed "s/.* -o //")"\n', "cannot load"),
    ],
    ids=["killed", "no-output", "broken-library"],
)
def test_a_compile_that_dies_leaves_no_library(tmp_path, monkeypatch, body, why):
    if "GCC" in body and GCC is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("CC", _cc(tmp_path / "cc", body))
    with pytest.warns(RuntimeWarning, match=why):
        traj, roll = trajectory_functions(VehicleParams(), CFG)
    assert isinstance(traj, InterpretedTrajectory) and isinstance(roll, InterpretedTrajectory)
    left = _files(tmp_path / "cache")
    assert left == [] or why == "cannot load", left  # no library, no temporary file
    if left:  # a library the compiler broke after it built fine: in place, not loaded
        assert all(n.endswith(".so") and not n.startswith(".") for n in left)


def test_an_interrupted_build_stops_its_compilers_and_leaves_nothing(tmp_path, monkeypatch):
    pids = tmp_path / "pids"
    monkeypatch.setenv("CC", _cc(tmp_path / "cc", f'echo $$ >> "{pids}"\nexec sleep 60\n'))

    def interrupted(proc):
        while not pids.exists() or len(pids.read_text().split()) < 2:
            time.sleep(0.01)  # until both compilers started
        raise KeyboardInterrupt

    monkeypatch.setattr(codegen, "_finish", interrupted)
    with pytest.raises(KeyboardInterrupt):
        trajectory_functions(VehicleParams(), CFG)
    for pid in map(int, pids.read_text().split()):
        with pytest.raises(ProcessLookupError):  # killed and reaped
            os.kill(pid, 0)
    assert _files(tmp_path / "cache") == []


@needs_cc
def test_one_library_per_platform(tmp_path, monkeypatch):
    """A cache folder shared between machines: another platform builds its own library."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        trajectory_function(VehicleParams(), CFG)
        monkeypatch.setattr(codegen, "_platform", lambda: "plan9-mips")
        trajectory_function(VehicleParams(), CFG)
    names = _files(tmp_path / "cache")
    assert len(names) == 2 and all(n.startswith("mpc_traj_") for n in names)
