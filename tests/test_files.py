"""The one atomic-write helper: whole files, normal permissions (the umask), no leftovers."""

import os
import stat

import numpy as np
import pytest

from racing_env.files import atomic_path, current_umask


@pytest.fixture
def umask():
    old = os.umask(0o022)
    os.umask(old)

    def set_mask(mask):
        os.umask(mask)

    yield set_mask
    os.umask(old)


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.parametrize("mask, expected", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_atomic_files_respect_the_umask(tmp_path, umask, mask, expected):
    umask(mask)
    assert current_umask() == mask
    with atomic_path(tmp_path / "sub" / "a.txt") as tmp:
        tmp.write_text("x")
    assert _mode(tmp_path / "sub" / "a.txt") == expected
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["a.txt"]


def test_failed_atomic_write_leaves_nothing(tmp_path):
    (tmp_path / "a.txt").write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "a.txt") as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]
    assert (tmp_path / "a.txt").read_text() == "old"


def test_written_outputs_get_the_same_mode_as_result_json(tmp_path, umask):
    """race.gif / trajectories.png were 0600 (mkstemp) while result.json was 0644."""
    from experiments.infra.artifacts import write_json, write_npz
    from racing_env.render import Renderer, save_animation
    from racing_env.tracks import make_track

    umask(0o022)
    write_json(tmp_path / "result.json", {"a": 1})
    write_npz(tmp_path / "d.npz", x=np.zeros(3))
    track = make_track("oval")
    frame = Renderer(track).frame(np.zeros((1, 6)))
    save_animation([frame, frame], tmp_path / "race.gif")
    for name in ("result.json", "d.npz", "race.gif"):
        assert _mode(tmp_path / name) == 0o644, name
