"""The env's kernels compiled by a background worker (racing_env.warmup): started only when it
has something to do, and the env then steps on the worker's kernels, the same races bit for
bit."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from racing_env import make_track, warmup

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def no_worker(monkeypatch):
    """Fail if a worker process would start."""

    def popen(*a, **k):
        raise AssertionError("a worker was started")

    monkeypatch.setattr(warmup.subprocess, "Popen", popen)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"track": make_track("default")},  # an object: the worker could not rebuild it
        {"n_cars": 2, "render_mode": "rgb_array"},  # not an argument it takes
        {"n_cars": [2]},
    ],
    ids=["track-object", "other-argument", "not-plain"],
)
def test_no_worker_for_arguments_it_cannot_pass_on(kwargs, no_worker):
    assert warmup.start_env_warmup(busy_ok=True, **kwargs) is None


def test_no_worker_on_a_busy_machine_or_once_warmed(no_worker, monkeypatch, tmp_path):
    monkeypatch.setattr(warmup, "idle_cores", lambda: 0.2)
    assert warmup.start_env_warmup(n_cars=2) is None
    monkeypatch.setattr(warmup, "idle_cores", lambda: 1.0)
    marker = tmp_path / "env-warmup.done"
    marker.touch()
    monkeypatch.setattr(warmup, "_marker", lambda kwargs: marker)
    assert warmup.start_env_warmup(n_cars=2) is None
    marker.unlink()  # no marker, but an env has stepped on this cache: its kernels are there
    (tmp_path / "racing_env_1234").mkdir()
    (tmp_path / "racing_env_1234" / "simulator._advance_serial-233.py311.nbi").touch()
    assert warmup.start_env_warmup(n_cars=2) is None


def test_idle_cores_is_a_number():
    assert isinstance(warmup.idle_cores(), float)


RACE = """
import json
import numpy as np
from numba.core import event

compiled = []


class Compiles(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__module__)

    def on_end(self, ev):
        pass


event.register("numba:compile", Compiles())
from racing_env import RacingParallelEnv

env = RacingParallelEnv(n_cars=3, max_cycles=30)
env.reset(seed=3)
for k in range(25):
    env.step({a: np.array([0.9, 0.4 * np.sin(0.3 * k + i)]) for i, a in enumerate(env.agents)})
print(json.dumps({"compiled": compiled, "state": env.core.state[0].tolist()}))
"""

WARM = """
from racing_env.warmup import start_env_warmup

worker = start_env_warmup(busy_ok=True, n_cars=3, max_cycles=30)
print(worker.wait())
print(start_env_warmup(busy_ok=True, n_cars=3, max_cycles=30))
"""


def _python(code: str, cache: Path) -> str:
    env = dict(os.environ, ALPHA_RACER_CACHE=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    r = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr
    return r.stdout


@pytest.mark.slow
def test_the_env_steps_on_the_workers_kernels_the_same_race(tmp_path):
    cold = json.loads(_python(RACE, tmp_path / "cold").splitlines()[-1])
    assert any(m.startswith("racing_env.") for m in cold["compiled"])  # compiled them itself
    assert _python(WARM, tmp_path / "warm").split() == ["0", "None"]  # once only
    warm = json.loads(_python(RACE, tmp_path / "warm").splitlines()[-1])
    assert [m for m in warm["compiled"] if m.startswith("racing_env.")] == []
    assert warm["state"] == cold["state"]  # bit for bit (floats through JSON exactly)
