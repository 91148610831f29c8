"""Installs anywhere: one movable cache folder, a failing C compiler, racing without the learning
extra, packaging metadata, and (slow) a wheel racing from a read-only site-packages."""

import os
import shutil
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]

STEPS = """
import numpy as np
import racing_env
env = racing_env.parallel_env(n_cars=2, max_cycles=5)
env.reset(seed=0)
for _ in range(3):
    env.step({a: np.array([0.5, 0.0]) for a in env.agents})
from racing_env.cache import cache_root
print(cache_root())
"""


def _run(code: str, env: dict, cwd=ROOT, timeout=600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _clean_env(**extra) -> dict:
    env = {
        k: v
        for k, v in os.environ.items()
        if k
        not in (
            "HOME",
            "XDG_CACHE_HOME",
            "NUMBA_CACHE_DIR",
            "ALPHA_RACER_CACHE",
            "CC",
            "PYTHONPATH",
            "TMPDIR",
        )
    }
    env.update({k: str(v) for k, v in extra.items()})
    return env


def _kernels(folder: Path, package: str) -> list[Path]:
    """numba index files under ``folder`` of functions defined in ``package`` or one of its
    sub-packages (numba names a kernel's folder after its source file's folder, plus a hash)."""
    import importlib.util

    root = Path(importlib.util.find_spec(package).origin).parent
    names = {d.name for d in (root, *root.rglob("*")) if (d / "__init__.py").is_file()}
    return [p for p in folder.rglob("*.nbi") if p.parent.name.rsplit("_", 1)[0] in names]


# ------------------------------------------------------------------------------ cache folder
@pytest.mark.slow
@pytest.mark.parametrize("where", ["ALPHA_RACER_CACHE", "HOME"])
def test_unwritable_cache_and_home_fall_back_to_a_temp_folder(tmp_path, where):
    """No writable cache folder, no usable home: import and race anyway, with a warning, and
    compile into a private temporary folder."""
    blocker = tmp_path / "a-file"  # nothing can be created under a file, even by root
    blocker.write_text("")
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = _clean_env(TMPDIR=tmp)
    if where == "ALPHA_RACER_CACHE":
        env["ALPHA_RACER_CACHE"] = str(blocker / "cache")  # and HOME unset
    else:
        env["HOME"] = str(blocker)  # the default is under HOME
    r = _run(STEPS, env)
    assert r.returncode == 0, r.stderr
    assert "alpha-racer cannot write to" in r.stderr and "temporary folder" in r.stderr, r.stderr
    used = Path(r.stdout.strip().splitlines()[-1])
    assert used.parent == tmp and used.name.startswith("alpha-racer-")
    assert _kernels(used / "numba", "racing_env")


def _unwritable_home(tmp_path) -> dict:
    blocker = tmp_path / "a-file"  # nothing can be created under a file, even by root
    blocker.write_text("")
    tmp = tmp_path / "tmp"
    tmp.mkdir(exist_ok=True)
    return _clean_env(TMPDIR=tmp, HOME=blocker)


def test_cache_fallback_is_one_line_once_and_not_on_version_or_help(tmp_path):
    env = _unwritable_home(tmp_path)
    for args in (["--version"], ["--help"], ["race", "--help"]):
        r = subprocess.run(
            [sys.executable, "-m", "experiments.cli", *args],
            cwd=ROOT,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert r.returncode == 0 and r.stderr == "", (args, r.stderr)
    code = (
        "import racing_env\nracing_env.parallel_env(n_cars=2)\nracing_env.parallel_env(n_cars=3)\n"
        "from racing_env.cache import cache_dir, cache_root\ncache_dir('raceline')\nprint(cache_root())"
    )
    r = _run(code, env)  # two envs and a cache look-up: one line in all
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert len(lines) == 1, r.stderr
    assert "cannot write to the default cache folder" in lines[0] and "Not a directory" in lines[0]
    used = r.stdout.strip().splitlines()[-1]
    assert f"temporary folder {used!r}" in lines[0] and "Set ALPHA_RACER_CACHE" in lines[0]


def test_import_under_W_error_and_matplotlib_in_our_cache(tmp_path):
    """``python -W error -c "import racing_env"`` with a writable ALPHA_RACER_CACHE, even
    without a writable home: Matplotlib's config goes into our cache, so it does not warn."""
    env = _unwritable_home(tmp_path)
    env["ALPHA_RACER_CACHE"] = str(tmp_path / "cache")
    code = (
        "import os, racing_env, matplotlib.pyplot, matplotlib; "
        "print(os.environ['MPLCONFIGDIR']); print(matplotlib.get_configdir())"
    )
    r = subprocess.run(
        [sys.executable, "-W", "error", "-c", code],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0 and r.stderr == "", r.stderr
    mpl = str(tmp_path / "cache" / "matplotlib")
    assert r.stdout.split() == [mpl, mpl]
    env["HOME"] = str(tmp_path / "home")  # a writable home: Matplotlib's own folder
    env["MPLCONFIGDIR"] = ""
    r = _run("import os, racing_env; print(os.environ.get('MPLCONFIGDIR', ''))", env)
    assert r.returncode == 0 and r.stdout.strip() == "", r.stderr


@pytest.mark.slow
def test_compiled_artefacts_land_under_ALPHA_RACER_CACHE(tmp_path):
    """numba kernels (racing_env's and agents'), the MPC's C library and the racing line all go
    to $ALPHA_RACER_CACHE; nothing goes to the home folder."""
    cache, home = tmp_path / "cache", tmp_path / "home"
    home.mkdir()
    code = (
        STEPS
        + """
import warnings
from agents import make_agent
env = racing_env.parallel_env(n_cars=1, max_cycles=5)
obs, _ = env.reset(seed=0)
agent = make_agent("mpc")
with warnings.catch_warnings():
    warnings.simplefilter("error")                       # compiled, not interpreted
    agent.reset(env.track, "car_0")
agent.act(obs["car_0"])
"""
    )
    r = _run(code, _clean_env(ALPHA_RACER_CACHE=cache, HOME=home))
    assert r.returncode == 0, r.stderr
    assert Path(r.stdout.strip().splitlines()[-1]) == cache
    assert _kernels(cache / "numba", "racing_env")
    assert _kernels(cache / "numba", "agents")
    assert list((cache / "mpc").glob("mpc_traj_*.so"))
    assert list((cache / "raceline").glob("*.npz"))
    assert not any(home.iterdir())


def test_cache_dir_is_one_function(tmp_path, monkeypatch):
    from agents.mpc import codegen
    from racing_env import cache, raceline

    monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path / "c"))
    assert cache.cache_dir() == tmp_path / "c"
    assert raceline.cache_dir() == cache.cache_dir("raceline") == tmp_path / "c" / "raceline"
    assert codegen._cache_root() == cache.cache_dir("mpc") == tmp_path / "c" / "mpc"
    assert (tmp_path / "c" / "mpc").is_dir()


def test_kernel_folder_changes_with_any_source_of_either_package(tmp_path):
    """numba checks a kernel against its own file only; the folder name covers every file, so an
    edit of a callee in another file (or another package) cannot leave a stale kernel in use."""
    from racing_env.cache import kernel_sources_hash

    env_pkg, agents_pkg = tmp_path / "racing_env", tmp_path / "agents"
    for pkg in (env_pkg, agents_pkg):
        pkg.mkdir()
        (pkg / "a.py").write_text("x = 1\n")
    (env_pkg / "notes.txt").write_text("not a source")
    base = kernel_sources_hash([env_pkg, agents_pkg])
    assert base == kernel_sources_hash([env_pkg, agents_pkg])  # stable
    (env_pkg / "notes.txt").write_text("edited")
    assert kernel_sources_hash([env_pkg, agents_pkg]) == base  # only .py files count
    (env_pkg / "a.py").write_text("x = 2\n")
    edited = kernel_sources_hash([env_pkg, agents_pkg])
    assert edited != base
    (agents_pkg / "b.py").write_text("")
    added = kernel_sources_hash([env_pkg, agents_pkg])
    assert added not in (base, edited)
    (agents_pkg / "sub").mkdir()  # a sub-package counts too
    (agents_pkg / "sub" / "c.py").write_text("")
    assert kernel_sources_hash([env_pkg, agents_pkg]) not in (base, edited, added)


def test_numba_cache_points_at_the_hashed_folder():
    import numba

    from racing_env.cache import cache_dir, kernel_sources_hash

    if os.environ.get("NUMBA_CACHE_DIR"):
        pytest.skip("NUMBA_CACHE_DIR is set: numba's own folder is used as it is")
    assert Path(numba.config.CACHE_DIR) == cache_dir("numba") / kernel_sources_hash()


# -------------------------------------------------------------------------------- C compiler
def _script(path: Path, body: str) -> Path:
    path.write_text("#!/bin/sh\n" + body)
    path.chmod(0o755)
    return path


@pytest.fixture
def fresh_compiler_fallback(monkeypatch):
    """The compiler fallback as in a new process (it warns once per process)."""
    from agents.mpc import codegen

    monkeypatch.setattr(codegen, "_WARNED", False)
    monkeypatch.setattr(codegen, "_FAILED", set())


def test_failing_c_compiler_shows_its_message_and_falls_back(
    tmp_path, monkeypatch, fresh_compiler_fallback
):
    from agents.mpc import MPCConfig, trajectory_function
    from racing_env.cache import cache_root
    from racing_env.vehicle import VehicleParams

    default_cache = str(cache_root())
    cc = _script(
        tmp_path / "broken-cc", "echo 'broken-cc: fatal error: no licence for -O3' >&2\nexit 3\n"
    )
    monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(cc))
    with pytest.warns(RuntimeWarning) as record:
        traj = trajectory_function(VehicleParams(), MPCConfig())
    msg = "\n".join(str(w.message) for w in record)
    assert "no licence for -O3" in msg and "status 3" in msg and "interpreted" in msg
    assert not list((tmp_path / "cache" / "mpc").glob("*.so"))

    monkeypatch.setenv("ALPHA_RACER_CACHE", default_cache)
    monkeypatch.delenv("CC")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        compiled = trajectory_function(VehicleParams(), MPCConfig())
    K = MPCConfig().horizon
    x0 = np.array([1.0, 0.05, 0.02, 2.0, 0.1, 0.3])
    U = np.tile([[0.5], [0.1]], (1, K))
    kap = np.full((MPCConfig().substeps, K), 0.5)
    for a, b in zip(traj(x0, U, kap), compiled(x0, U, kap)):
        assert isinstance(a, np.ndarray)
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_mpc_agent_races_with_a_failing_compiler(tmp_path, monkeypatch, fresh_compiler_fallback):
    from agents import make_agent
    from racing_env import parallel_env

    monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(_script(tmp_path / "cc", "exit 1\n")))
    env = parallel_env(n_cars=1, max_cycles=3)
    obs, _ = env.reset(seed=0)
    agent = make_agent("mpc")
    with pytest.warns(RuntimeWarning, match="interpreted"):
        agent.reset(env.track, "car_0")
    for _ in range(2):
        a = agent.act(obs["car_0"])
        assert np.all(np.isfinite(a))
        obs, *_ = env.step({"car_0": a})


def test_compiler_fallback_warns_once_per_process_in_one_line(
    tmp_path, monkeypatch, fresh_compiler_fallback
):
    """Three MPC cars with a broken compiler: one warning line in all, and the failing
    compiler runs once per compiled function, not once per car."""
    from agents import make_agent
    from racing_env import parallel_env

    log = tmp_path / "cc.log"
    monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", str(_script(tmp_path / "cc", f'echo run >> "{log}"\nexit 1\n')))
    env = parallel_env(n_cars=3, max_cycles=2)
    obs, _ = env.reset(seed=0)
    cars = [make_agent("mpc") for _ in range(3)]
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")  # no dedup by the warnings module itself
        for i, car in enumerate(cars):
            car.reset(env.track, f"car_{i}")
        env.step({f"car_{i}": car.act(obs[f"car_{i}"]) for i, car in enumerate(cars)})
    warned = [str(w.message) for w in record if issubclass(w.category, RuntimeWarning)]
    assert len(warned) == 1, warned
    assert "\n" not in warned[0]
    assert "not compiled" in warned[0] and "exit status 1" in warned[0] and "Set CC" in warned[0]
    assert log.read_text().count("run") <= 2  # 6 before: every car compiled again


def test_CC_is_the_compiler(tmp_path, monkeypatch):
    from agents.mpc import MPCConfig, trajectory_function
    from racing_env.vehicle import VehicleParams

    gcc = shutil.which("gcc") or shutil.which("cc")
    if gcc is None:
        pytest.skip("no C compiler")
    log = tmp_path / "cc.log"
    cc = _script(tmp_path / "my cc", f'echo "$@" >> "{log}"\nexec "{gcc}" "$@"\n')
    monkeypatch.setenv("ALPHA_RACER_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", f"'{cc}' -O1")  # a command, quoted like in a shell
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        trajectory_function(VehicleParams(), MPCConfig(horizon=5))
    assert log.read_text().startswith("-O1 ") and list((tmp_path / "cache" / "mpc").glob("*.so"))


# ------------------------------------------------------------------ racing without [learn]
BLOCK_LEARN = """
import sys
for name in ("torch", "stable_baselines3", "tensorboard"):
    sys.modules[name] = None                 # import torch -> ImportError, as if not installed
"""


@pytest.mark.slow
def test_race_without_the_learn_extra(tmp_path):
    code = (
        BLOCK_LEARN
        + """
import racing_env, agents, agents.mpc_agent, agents.alpha_agent, agents.ibr
from experiments.evaluation.race import run_race
result, _ = run_race(["alpha", "mpc", "mpc:zeta=0.8"], max_cycles=2, render=False)
print("raced", len(result.table().splitlines()))
from agents import make_agent_spec
from racing_env.extras import MissingExtraError
for make in (lambda: make_agent_spec("ppo"), lambda: __import__("racing_env.vec_env")):
    try:
        make()
    except MissingExtraError as exc:
        print("MISSING:", exc)
assert not any(sys.modules.get(m) for m in ("torch", "stable_baselines3"))
"""
    )
    from racing_env.cache import cache_root

    r = _run(code, _clean_env(ALPHA_RACER_CACHE=cache_root()))
    assert r.returncode == 0, r.stderr
    assert "raced" in r.stdout
    missing = [line for line in r.stdout.splitlines() if line.startswith("MISSING:")]
    assert len(missing) == 2 and all('pip install "alpha-racer[learn]"' in m for m in missing)
    assert "the 'ppo' agent" in missing[0]


def test_cli_names_the_extra(capsys, monkeypatch):
    from experiments.cli import main

    monkeypatch.setitem(sys.modules, "stable_baselines3", None)
    assert (
        main(
            [
                "race",
                "--agents",
                "ppo",
                "mpc",
                "--steps",
                "1",
                "--no-animation",
                "--out",
                os.devnull,
            ]
        )
        == 2
    )
    assert 'pip install "alpha-racer[learn]"' in capsys.readouterr().err


# ---------------------------------------------------------------------------- packaging
def _pyproject() -> dict:
    tomllib = pytest.importorskip("tomllib")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def _names(reqs) -> set[str]:
    import re

    return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower().replace("_", "-") for r in reqs}


def test_learning_packages_are_an_extra_that_dev_includes():
    project = _pyproject()["project"]
    learn = _names(project["optional-dependencies"]["learn"])
    assert learn == {
        "torch",
        "stable-baselines3",
        "tensorboard",
        "rich",
    }  # rich: SB3's progress_bar
    assert not learn & _names(project["dependencies"])
    assert learn <= _names(project["optional-dependencies"]["dev"])
    assert not [r for r in project["dependencies"] if "==" in r]  # ranges, not pins
    # the code is MIT; the circuits shipped as package data keep the racetrack-database's LGPL
    assert project["license"] == "MIT AND LGPL-3.0-only"
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    lgpl = ROOT / "racing_env" / "circuits" / "LICENSE"
    assert "GNU LESSER GENERAL PUBLIC LICENSE" in lgpl.read_text()
    assert project["license-files"] == ["LICENSE", "racing_env/circuits/LICENSE"]


def test_metadata_declares_llvmlite_and_every_supported_python():
    import re

    project = _pyproject()["project"]
    assert "llvmlite" in _names(project["dependencies"])  # codegen.py imports llvmlite.ir
    minimum = re.fullmatch(r">=3\.(\d+)", project["requires-python"]).group(1)
    versions = sorted(
        int(c.rsplit(".", 1)[1])
        for c in project["classifiers"]
        if re.fullmatch(r"Programming Language :: Python :: 3\.\d+", c)
    )
    assert versions == list(range(int(minimum), versions[-1] + 1)), versions
    assert sys.version_info[1] in versions


def test_package_index_description_renders_without_broken_links():
    """README.md's pictures and links are repository-relative: the index page gets its own."""
    import re

    readme = _pyproject()["project"]["readme"]
    text = (ROOT / readme).read_text()
    assert len(text) < 5000 and not re.search(r"!\[", text)  # no images
    for target in re.findall(r"\]\(([^)\s]+)\)|<(\S+?)>", text):
        link = next(t for t in target if t)
        assert link.startswith("https://"), link
    assert "pip install alpha-racer" in text and "HeadToHead-v2" in text


def test_version(capsys):
    import agents
    import experiments
    import racing_env
    from experiments.cli import main

    assert racing_env.__version__ == agents.__version__ == experiments.__version__
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"alpha-racer {racing_env.__version__}"


# ------------------------------------------------------------------ the wheel, read-only
def _read_only_runner(paths: list[Path]) -> list[str] | None:
    """A command prefix that runs a program with ``paths`` read-only: a private mount namespace
    (root), or nothing after ``chmod -R a-w`` (anyone else); None if neither works."""
    if os.geteuid() != 0:
        for p in paths:
            subprocess.run(["chmod", "-R", "a-w", str(p)], check=True)
        return []
    if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"]).returncode:
        return None
    mounts = " && ".join(
        f"mount --bind {q} {q} && mount -o remount,ro,bind {q}" for q in (f"'{p}'" for p in paths)
    )
    return ["unshare", "-m", "sh", "-c", mounts + ' && exec "$@"', "sh"]


def _inherit_site_packages(python: Path) -> None:
    """Let the venv of ``python`` import this test run's dependencies: a ``.pth`` file in its
    site-packages names the running interpreter's site-packages, wherever they are (a user's
    virtual environment, CI's, or the machine's own). Paths a ``.pth`` file adds come after the
    venv's own site-packages, and ``.pth`` files inside them are not run, so an editable
    install of this tree there cannot shadow the wheel."""
    import sysconfig

    ours = {sysconfig.get_paths()[k] for k in ("purelib", "platlib")}
    theirs = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(theirs) / "_test_run_site_packages.pth").write_text("\n".join(sorted(ours)) + "\n")


def test_a_venv_sees_the_running_environment_s_packages_but_not_this_tree(tmp_path):
    """The wheel test's venv gets its dependencies from the environment the tests run in,
    even when that is itself a virtual environment (no ``--system-site-packages``), and
    ``racing_env`` is not importable there until the wheel is installed."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    _inherit_site_packages(python)
    code = (
        "import importlib.util as u, platformdirs, numpy\nprint(u.find_spec('racing_env') is None)"
    )
    r = subprocess.run([str(python), "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "True"


@pytest.mark.slow
def test_wheel_races_from_a_read_only_install_without_home(tmp_path):
    """The issue's "done when": a wheel of this tree, installed into a venv whose site-packages
    is then read-only, with HOME unset (and, for root, the home folder read-only too), races
    alpha, mpc and ibr without torch."""
    import pwd

    whl, venv, out, tmp = (tmp_path / d for d in ("whl", "venv", "out", "tmp"))
    tmp.mkdir()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            str(ROOT),
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(whl),
        ],
        check=True,
        cwd=tmp_path,
    )
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    _inherit_site_packages(python)
    subprocess.run(
        [
            str(python),
            "-m",
            "pip",
            "install",
            "-q",
            "--no-deps",
            "--no-index",
            *map(str, whl.glob("*.whl")),
        ],
        check=True,
    )
    home = Path(pwd.getpwuid(os.getuid()).pw_dir)  # where ~ points with HOME unset
    runner = _read_only_runner([venv] + ([home] if home.is_dir() and home != Path("/") else []))
    if runner is None:
        pytest.skip("cannot make the venv read-only (root without unshare)")
    code = (
        BLOCK_LEARN
        + f"""
import racing_env
assert racing_env.__file__.startswith({str(venv)!r}), racing_env.__file__
from experiments.cli import main
sys.exit(main(["race", "--agents", "alpha", "mpc", "ibr", "--steps", "30", "--no-animation",
               "--out", {str(out)!r}]))
"""
    )
    env = _clean_env(TMPDIR=tmp, MPLCONFIGDIR=tmp / "mpl")
    r = subprocess.run(
        [*runner, str(python), "-c", code],
        cwd="/",
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Race on 'default'" in r.stdout and (out / "result.json").exists()
    for agent in ("alpha", "mpc", "ibr"):
        assert agent in r.stdout
    if runner:  # root: the home folder was read-only too
        assert "alpha-racer cannot write to the default cache folder" in r.stderr
    installed = [  # the packages in site-packages (dist-info/licenses/racing_env/ is not one)
        d
        for pkg in ("racing_env", "agents", "experiments")
        for d in venv.rglob(pkg)
        if d.parent.name == "site-packages"
    ]
    assert len(installed) == 3, installed
    assert not [p for d in installed for p in d.rglob("*") if p.suffix in (".nbi", ".nbc", ".so")]
