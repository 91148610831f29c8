"""Tests of racing_env.render and the modules it re-exports (draw, animation, trajectory_plot):
frames, background cache, animations, viewer, trajectory plot."""

from __future__ import annotations

import shutil
import sys
import warnings

import numpy as np
import pytest
from PIL import Image

from racing_env import animation, render
from racing_env.render import CAR_COLORS, HumanViewer, Renderer, plot_trajectories, save_animation
from racing_env.tracks import make_track
from racing_env.vehicle import VehicleParams


@pytest.fixture(scope="module")
def oval():
    return make_track("oval")


@pytest.fixture(scope="module")
def oval_renderer(oval):
    return Renderer(oval, width=320, height=200)


def _mask(img, color):
    return np.all(img == np.array(color, dtype=np.uint8), axis=-1)


def _state(*cars):
    return np.array([[s, n, mu, 1.0, 0.0, 0.0] for s, n, mu in cars], dtype=float)


# ---------------------------------------------------------------------------- frames
def test_frame_shape_dtype_and_new_array(oval_renderer):
    f = oval_renderer.frame(_state((1.0, 0.0, 0.0), (2.0, 0.1, 0.0), (3.0, -0.1, 0.2)))
    assert f.shape == (200, 320, 3) and f.dtype == np.uint8
    assert f.flags.writeable
    f[:] = 0  # must not touch the cached background
    assert oval_renderer.background.any()


def test_background_has_no_car_colours(oval, oval_renderer):
    rl = oval.to_cartesian(oval.s_grid, 0.1 * np.sin(oval.s_grid))
    for r in (oval_renderer, Renderer(make_track("default")), Renderer(oval, raceline_xy=rl)):
        for c in CAR_COLORS:
            assert not _mask(r.background, c).any(), c


def test_car_drawn_at_projected_position(oval, oval_renderer):
    r = oval_renderer
    for s, n, mu in ((1.0, 0.0, 0.0), (9.0, 0.15, 0.3), (15.0, -0.2, -0.1)):
        x, y = oval.to_cartesian(s, n)
        u, v = r.world_to_pixel(x, y)
        f = r.frame(_state((s, n, mu)))
        m = _mask(f, CAR_COLORS[0])
        rows, cols = np.nonzero(m)
        assert len(rows) >= 6, "car too small or missing"
        dist = np.hypot(cols + 0.5 - u, rows + 0.5 - v)
        radius = 0.5 * np.hypot(r.car_length_px, r.car_width_px) + 1.0
        assert dist.max() <= radius  # nothing of that colour elsewhere
        assert abs(np.mean(cols + 0.5) - u) < 2.0 and abs(np.mean(rows + 0.5) - v) < 2.0
        # only the car's pixels changed
        changed = np.any(f != r.background, axis=-1)
        rc, cc = np.nonzero(changed)
        assert np.hypot(cc + 0.5 - u, rc + 0.5 - v).max() <= radius


def test_car_orientation_and_size(oval):
    # on the first straight (heading +x) a car with mu = 0 is wider than tall in pixels
    r = Renderer(oval, width=640, height=480, car_scale=3.0)
    assert r.car_length_px >= 3.0 * VehicleParams().length * r.scale - 1e-9
    assert r.car_width_px == pytest.approx(r.car_length_px * 0.5)
    rows, cols = np.nonzero(_mask(r.frame(_state((1.0, 0.0, 0.0))), CAR_COLORS[0]))
    assert np.ptp(cols) > np.ptp(rows)
    rows, cols = np.nonzero(_mask(r.frame(_state((1.0, 0.0, np.pi / 2))), CAR_COLORS[0]))
    assert np.ptp(rows) > np.ptp(cols)


def test_min_car_size_on_big_image(oval):
    r = Renderer(oval, width=64, height=48)
    assert r.car_length_px >= 8.0 - 1e-9
    assert _mask(r.frame(_state((1.0, 0.0, 0.0))), CAR_COLORS[0]).sum() >= 10


def test_each_car_has_its_colour(oval_renderer):
    st = _state(*[(1.0 + 2.5 * i, 0.0, 0.0) for i in range(8)])
    f = oval_renderer.frame(st)
    for c in CAR_COLORS:
        assert _mask(f, c).sum() >= 6, c


def test_different_states_give_different_frames(oval_renderer):
    a = oval_renderer.frame(_state((1.0, 0.0, 0.0), (4.0, 0.0, 0.0)))
    b = oval_renderer.frame(_state((1.5, 0.0, 0.0), (4.0, 0.0, 0.0)))
    c = oval_renderer.frame(_state((1.0, 0.0, 0.0), (4.0, 0.0, 0.0)))
    assert not np.array_equal(a, b)
    assert np.array_equal(a, c)


def test_background_cached(oval_renderer):
    r = oval_renderer
    assert np.array_equal(r.frame(np.zeros((0, 6))), r.background)
    assert not r.background.flags.writeable
    bg_before = r.background.copy()
    r.frame(_state((1.0, 0.0, 0.0)), labels=["A"], hud=["step 1"])
    assert np.array_equal(r.background, bg_before)


def test_unwrapped_s_same_place(oval, oval_renderer):
    a = oval_renderer.frame(_state((1.0, 0.0, 0.0)))
    b = oval_renderer.frame(_state((1.0 + 2 * oval.length, 0.0, 0.0)))
    assert np.array_equal(a, b)


def test_hud_and_labels_drawn(oval_renderer):
    st = _state((5.0, 0.0, 0.0))
    plain = oval_renderer.frame(st)
    hud = oval_renderer.frame(st, hud=["step 3", "t 0.30 s"])
    lab = oval_renderer.frame(st, labels=["car A"])
    assert not np.array_equal(plain, hud)
    assert not np.array_equal(plain, lab)
    # HUD sits at the top-left
    diff = np.any(plain != hud, axis=-1)
    rows, cols = np.nonzero(diff)
    assert rows.max() < 60 and cols.max() < 160


def test_nonfinite_car_skipped_and_offscreen_ok(oval_renderer):
    st = _state((1.0, 0.0, 0.0), (2.0, 0.0, 0.0))
    st[1, 0] = np.nan
    f = oval_renderer.frame(st)
    assert _mask(f, CAR_COLORS[0]).any() and not _mask(f, CAR_COLORS[1]).any()
    far = _state((1.0, 50.0, 0.0))  # far off the image: nothing drawn, no error
    assert np.array_equal(oval_renderer.frame(far), oval_renderer.background)


def test_frame_bad_inputs(oval, oval_renderer):
    with pytest.raises(ValueError, match="shape"):
        oval_renderer.frame(np.zeros((2, 5)))
    with pytest.raises(ValueError, match="labels"):
        oval_renderer.frame(_state((1.0, 0.0, 0.0)), labels=["a", "b"])
    with pytest.raises(ValueError, match="width"):
        Renderer(oval, width=0)
    with pytest.raises(ValueError, match="car_scale"):
        Renderer(oval, car_scale=-1.0)
    with pytest.raises(ValueError, match="raceline_xy"):
        Renderer(oval, raceline_xy=np.zeros((3, 3)))


def test_single_car_vector_accepted(oval_renderer):
    a = oval_renderer.frame(np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0]))
    b = oval_renderer.frame(_state((1.0, 0.0, 0.0)))
    assert np.array_equal(a, b)


def test_aspect_ratio_and_y_up(oval):
    r = Renderer(oval, width=400, height=400)
    (xl, yl), (xr, yr) = oval.edges()
    u, v = r.world_to_pixel(np.r_[xl, xr], np.r_[yl, yr])
    assert u.min() >= 0 and u.max() <= 400 and v.min() >= 0 and v.max() <= 400
    # oval is wider than tall, so it fills the width; same scale on both axes
    assert (u.max() - u.min()) / (v.max() - v.min()) == pytest.approx(
        (np.ptp(np.r_[xl, xr])) / np.ptp(np.r_[yl, yr]), rel=1e-9
    )
    _, v_lo = r.world_to_pixel(0.0, 0.0)
    _, v_hi = r.world_to_pixel(0.0, 1.0)
    assert v_hi < v_lo  # y up in the world is up in the image


# ---------------------------------------------------------------------------- animations
def _frames(k=5, h=24, w=32):
    out = []
    for i in range(k):
        f = np.zeros((h, w, 3), np.uint8)
        f[:, : (i + 1) * w // (k + 1)] = CAR_COLORS[i % 8]
        out.append(f)
    return out


def test_gif_roundtrip(tmp_path):
    path = save_animation(_frames(), tmp_path / "anim.gif", fps=10)
    assert path == tmp_path / "anim.gif"
    with Image.open(path) as im:
        assert im.n_frames == 5 and im.size == (32, 24)
        assert im.info.get("loop") == 0
        assert im.info.get("duration") == 100
        im.seek(4)
        last = np.array(im.convert("RGB"))
    assert np.array_equal(last, _frames()[4])  # few colours: exact round trip
    assert [p.name for p in tmp_path.iterdir()] == ["anim.gif"]  # no temp files left


def test_gif_from_renderer(tmp_path, oval_renderer):
    frames = [
        oval_renderer.frame(_state((1.0 + 0.3 * k, 0.0, 0.0)), hud=[f"step {k}"]) for k in range(4)
    ]
    path = save_animation(np.stack(frames), tmp_path / "sub" / "race.GIF", fps=20)
    with Image.open(path) as im:
        assert im.n_frames == 4 and im.size == (320, 200)


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg not installed")
def test_mp4_written(tmp_path, oval_renderer):
    frames = [oval_renderer.frame(_state((1.0 + 0.3 * k, 0.0, 0.0))) for k in range(6)]
    path = save_animation(frames, tmp_path / "race.mp4", fps=10)
    assert path.stat().st_size > 0
    assert [p.name for p in tmp_path.iterdir()] == ["race.mp4"]


def _fake_ffmpeg(tmp_path, fail=False):
    """A stand-in ffmpeg: checks the raw-video byte count and writes it to the output path."""
    script = tmp_path / "fake_ffmpeg.py"
    script.write_text(
        "import sys\n"
        "args = sys.argv[1:]\n"
        "w, h = map(int, args[args.index('-s') + 1].split('x'))\n"
        "data = sys.stdin.buffer.read()\n"
        f"if {fail!r}:\n"
        "    sys.stderr.write('boom'); sys.exit(1)\n"
        "assert len(data) % (w * h * 3) == 0\n"
        "open(args[-1], 'w').write(str(len(data) // (w * h * 3)))\n"
    )
    exe = tmp_path / "ffmpeg"
    exe.write_text(f'#!/bin/sh\nexec {sys.executable} {script} "$@"\n')
    exe.chmod(0o755)
    return str(exe)


@pytest.mark.skipif(sys.platform.startswith("win"), reason="shell script stand-in")
def test_mp4_pipe_with_stand_in_ffmpeg(tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(animation.shutil, "which", lambda name: _fake_ffmpeg(tmp_path))
    path = save_animation(_frames(7), out / "a.mp4", fps=5)
    assert path.read_text() == "7"
    assert [p.name for p in out.iterdir()] == ["a.mp4"]


@pytest.mark.skipif(sys.platform.startswith("win"), reason="shell script stand-in")
def test_mp4_failure_leaves_nothing(tmp_path, monkeypatch):
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(animation.shutil, "which", lambda name: _fake_ffmpeg(tmp_path, fail=True))
    with pytest.raises(RuntimeError, match="ffmpeg failed"):
        save_animation(_frames(3), out / "a.mp4")
    assert list(out.iterdir()) == []


def test_mp4_without_ffmpeg_raises(tmp_path, monkeypatch):
    monkeypatch.setattr(animation, "_find_ffmpeg", lambda: None)
    with pytest.raises(RuntimeError, match="ffmpeg is missing.*gif"):
        save_animation(_frames(), tmp_path / "a.mp4")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "frames, path, fps, match",
    [
        ([], "a.gif", 10, "empty"),
        ([np.zeros((4, 4, 3), np.float32)], "a.gif", 10, "float32"),
        ([np.zeros((4, 4), np.uint8)], "a.gif", 10, r"\(4, 4\)"),
        (
            [np.zeros((4, 4, 3), np.uint8), np.zeros((5, 4, 3), np.uint8)],
            "a.gif",
            10,
            r"\(5, 4, 3\)",
        ),
        ([np.zeros((4, 4, 3), np.uint8)], "a.avi", 10, "'.avi'"),
        ([np.zeros((4, 4, 3), np.uint8)], "a", 10, "suffix"),
        ([np.zeros((4, 4, 3), np.uint8)], "a.gif", 0, "fps.*0"),
        ([np.zeros((4, 4, 3), np.uint8)], "a.gif", -2.5, "-2.5"),
        ([np.zeros((4, 4, 3), np.uint8)], "a.gif", float("nan"), "nan"),
        ("not frames", "a.gif", 10, "str"),
    ],
)
def test_save_animation_bad_inputs(tmp_path, frames, path, fps, match):
    with pytest.raises(ValueError, match=match):
        save_animation(frames, tmp_path / path, fps=fps)
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------- human viewer
def test_human_viewer_without_display_warns_once(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(render.sys, "platform", "linux")
    with pytest.warns(RuntimeWarning, match="needs a display"):
        viewer = HumanViewer()
    frame = np.zeros((10, 12, 3), np.uint8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no second warning
        viewer.show(frame)
        viewer.show(frame + 1)
        viewer.close()
    assert not viewer.available
    assert np.array_equal(viewer.last_frame, frame + 1)


def test_human_viewer_non_interactive_backend(monkeypatch):
    import matplotlib

    monkeypatch.setenv("DISPLAY", ":99")
    monkeypatch.setattr(matplotlib, "get_backend", lambda: "agg")
    with pytest.warns(RuntimeWarning, match="non-interactive"):
        viewer = HumanViewer()
    viewer.show(np.zeros((4, 4, 3), np.uint8))
    viewer.close()


# ---------------------------------------------------------------------------- trajectory plot
def test_plot_trajectories(tmp_path, oval):
    t = np.linspace(0, 5, 40)
    states = np.zeros((40, 3, 6))
    for i in range(3):
        states[:, i, 0] = t * (1 + 0.2 * i)
        states[:, i, 1] = 0.1 * np.sin(t + i)
    rl = oval.to_cartesian(oval.s_grid, np.zeros_like(oval.s_grid))
    path = plot_trajectories(
        oval, states, tmp_path / "traj.png", raceline_xy=rl, labels=["a", "b", "c"]
    )
    with Image.open(path) as im:
        assert im.format == "PNG" and im.size[0] > 100
    assert [p.name for p in tmp_path.iterdir()] == ["traj.png"]
    with pytest.raises(ValueError, match="shape"):
        plot_trajectories(oval, np.zeros((5, 2, 4)), tmp_path / "x.png")
    with pytest.raises(ValueError, match="labels"):
        plot_trajectories(oval, states, tmp_path / "x.png", labels=["a"])
