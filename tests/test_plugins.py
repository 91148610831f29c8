"""Agent plugins: entry points of the ``alpha_racer.agents`` group, ``--import MODULE`` and
``alpha-racer agents``."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from agents import agent_names, agent_parameters, register_agent
from agents.base import _REGISTRY, ENTRY_POINT_GROUP
from agents.reference import THETA_HIGH, THETA_LOW
from experiments.cli import main

ROOT = Path(__file__).resolve().parents[1]

PLUGIN = '''
import numpy as np


class Mine:
    """A plugin driver: steady throttle, steering back to the centre line."""

    def __init__(self, throttle: float = 0.6, gain: float = 4.0):
        self.throttle, self.gain = throttle, gain

    def reset(self, track, agent_id, seed=None):
        pass

    def act(self, observation):
        n, mu = observation[1], observation[2]
        return np.array([self.throttle, np.clip(-self.gain * n - 2 * mu, -1, 1)], dtype=np.float32)
'''


def _cli(args, cwd, pythonpath):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(map(str, pythonpath)))
    return subprocess.run(
        [sys.executable, "-m", "experiments.cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def plugin_site(tmp_path_factory):
    """A folder like site-packages after ``pip install my-agent``: the module and a dist-info
    whose entry_points.txt names ``mine``."""
    site = tmp_path_factory.mktemp("site")
    (site / "my_agent.py").write_text(PLUGIN)
    info = site / "my_agent-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: my-agent\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nmine = my_agent:Mine\n")
    return site


@pytest.mark.slow
def test_installed_plugin_races_from_the_command_line(plugin_site, tmp_path):
    out = tmp_path / "race"
    proc = _cli(
        [
            "race",
            "--agents",
            "mine:throttle=0.8",
            "raceline",
            "--steps",
            "5",
            "--no-animation",
            "--out",
            str(out),
        ],
        ROOT,
        [plugin_site, ROOT],
    )
    assert proc.returncode == 0, proc.stderr
    assert "mine:throttle=0.8" in proc.stdout
    assert json.loads((out / "result.json").read_text())["agents"][0] == "mine:throttle=0.8"


def test_installed_plugin_benches_and_is_listed(plugin_site, tmp_path):
    proc = _cli(
        [
            "bench",
            "--ego",
            "mine",
            "--opponents",
            "raceline",
            "--races",
            "1",
            "--steps",
            "5",
            "--workers",
            "1",
            "--out",
            str(tmp_path / "b"),
        ],
        ROOT,
        [plugin_site, ROOT],
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "b" / "summary.md").exists()
    proc = _cli(["agents"], ROOT, [plugin_site, ROOT])
    assert proc.returncode == 0, proc.stderr
    assert "mine: A plugin driver" in proc.stdout
    assert "throttle = 0.6" in proc.stdout and "gain = 4.0" in proc.stdout


def test_broken_plugin_is_a_one_line_error(tmp_path):
    info = tmp_path / "broken-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\nbroken = no_such_module:X\n")
    proc = _cli(
        [
            "race",
            "--agents",
            "broken",
            "--steps",
            "5",
            "--no-animation",
            "--out",
            str(tmp_path / "r"),
        ],
        ROOT,
        [tmp_path, ROOT],
    )
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0
    assert "agent plugin 'broken'" in proc.stderr and "no_such_module" in proc.stderr


def test_import_option_registers_user_agents(tmp_path):
    (tmp_path / "my_agents.py").write_text(
        "from agents import register_agent\nfrom my_agent import Mine\n"
        "register_agent('imported', Mine)\n"
    )
    (tmp_path / "my_agent.py").write_text(PLUGIN)
    proc = _cli(
        [
            "race",
            "--import",
            "my_agents",
            "--agents",
            "imported",
            "raceline",
            "--steps",
            "5",
            "--no-animation",
            "--out",
            str(tmp_path / "r"),
        ],
        tmp_path,
        [ROOT],
    )  # found in the current directory
    assert proc.returncode == 0, proc.stderr
    assert "imported" in proc.stdout


def test_import_option_failure_is_one_line(capsys):
    assert main(["race", "--import", "no_such_module_xyz", "--steps", "5", "--no-animation"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'no_such_module_xyz'" in err
    assert main(["bench", "--import", "missing_file.py", "--races", "1", "--steps", "5"]) == 2
    assert "'missing_file.py'" in capsys.readouterr().err


def test_agents_command_lists_parameters_defaults_and_theta_bounds(capsys):
    assert main(["agents"]) == 0
    text = capsys.readouterr().out
    for name in ("alpha", "mpc", "ibr", "ppo", "raceline", "random", "constant"):
        assert f"\n{name}:" in "\n" + text
    assert f"zeta = 0.9  in [{THETA_LOW[1]:g}, {THETA_HIGH[1]:g}]" in text
    assert f"q = 20.0  in [{THETA_LOW[0]:g}, {THETA_HIGH[0]:g}]" in text
    assert "model = 'auto'" in text and "rounds = 6" in text and "grip = 1.0" in text
    assert "mu = None  (deprecated name of grip)" in text


def test_agent_parameters_follow_kwargs_to_the_base_class():
    alpha = {p.name: p for p in agent_parameters("alpha")[0]}
    assert {"model", "restarts", "q", "zeta", "s1", "s2", "s3"} <= set(alpha)
    assert alpha["s1"].bounds == (float(THETA_LOW[2]), float(THETA_HIGH[2]))
    ibr, open_kwargs = agent_parameters("ibr")
    assert not open_kwargs and "rounds" in {p.name for p in ibr}

    @register_agent("_kw_open")
    def _factory(**kwargs):
        raise AssertionError("not built")

    try:
        assert agent_parameters("_kw_open") == ([], True)
        assert "_kw_open" in agent_names()
    finally:
        _REGISTRY.pop("_kw_open")
