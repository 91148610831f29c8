"""Track geometry against hand-derived cases; loaders; validation errors."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from racing_env import Track, load_tumftm_csv, make_track, random_track
from racing_env.tracks import tumftm_dir


def circle(radius=2.0, m=200, w=0.3):
    th = np.linspace(0, 2 * np.pi, m, endpoint=False)
    return Track.from_centerline(
        radius * np.cos(th), radius * np.sin(th), np.full(m, w), np.full(m, w), name="circle"
    )


def test_circle_length_heading_curvature():
    r = 2.0
    t = circle(r)
    assert t.length == pytest.approx(2 * np.pi * r, rel=1e-6)
    s = np.linspace(0, t.length, 50, endpoint=False)
    assert np.allclose(t.curvature(s), 1 / r, rtol=1e-4)  # counter-clockwise: left turn
    x, y = t.position(s)
    assert np.allclose(np.hypot(x, y), r, atol=1e-6)
    # heading is tangent: perpendicular to the radius, pointing counter-clockwise
    psi = t.heading(s)
    assert np.allclose(np.cos(psi) * x + np.sin(psi) * y, 0, atol=1e-5)
    assert np.allclose(-np.sin(psi) * x + np.cos(psi) * y, -r, atol=1e-5)  # left normal: inward


def test_left_offset_is_towards_the_centre_of_a_left_turn():
    t = circle(2.0)
    x, y = t.to_cartesian(np.array([0.0, 3.0]), np.array([0.25, -0.25]))
    assert np.hypot(x[0], y[0]) == pytest.approx(1.75, abs=1e-6)
    assert np.hypot(x[1], y[1]) == pytest.approx(2.25, abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(s=st.floats(-100.0, 100.0), n=st.floats(-0.24, 0.24), mu=st.floats(-3.0, 3.0))
def test_frenet_cartesian_round_trip_on_default_track(s, n, mu):
    t = make_track("default")
    x, y, phi = t.to_cartesian(s, n, mu)
    s2, n2, mu2 = t.to_frenet(x, y, phi)
    assert (s2 - s) % t.length == pytest.approx(0, abs=1e-6) or (
        s2 - s
    ) % t.length == pytest.approx(t.length, abs=1e-6)
    assert n2 == pytest.approx(n, abs=1e-6)
    assert np.angle(np.exp(1j * (mu2 - mu))) == pytest.approx(0, abs=1e-6)


def test_projection_is_robust_on_a_hairpin():
    # a hairpin whose two legs' edges are 0.1 m apart: a point on the inside of one leg must
    # project to that leg, not the other one which lies closer than the far edge
    t = make_track("default")
    k = int(np.argmax(t.kappa))  # the hairpin apex
    s_leg = t.s_grid[k] - 2.5  # on the leg before the hairpin
    for n in (-0.24, 0.0, 0.24):
        x, y = t.to_cartesian(s_leg, n)
        s2, n2 = t.to_frenet(x, y)
        assert float(s2) == pytest.approx(s_leg % t.length, abs=1e-6)
        assert float(n2) == pytest.approx(n, abs=1e-6)
    # with a hint, s is unwrapped to the hint's lap
    x, y = t.to_cartesian(3 * t.length + 1.0, 0.1)
    s3, _ = t.to_frenet(x, y, s_hint=3 * t.length + 0.9, window=1.0)
    assert float(s3) == pytest.approx(3 * t.length + 1.0, abs=1e-6)


def test_frenet_is_vectorised():
    t = make_track("oval")
    s = np.linspace(0, 30, 12).reshape(3, 4)
    n = np.full_like(s, 0.1)
    x, y = t.to_cartesian(s, n)
    assert x.shape == (3, 4)
    s2, n2 = t.to_frenet(x, y)
    assert s2.shape == (3, 4)
    assert np.allclose(n2, 0.1, atol=1e-6)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda x, y, wr, wl: (x[:5], y[:5], wr[:5], wl[:5]), "at least 8"),
        (lambda x, y, wr, wl: (x[:60], y[:60], wr[:60], wl[:60]), "not closed"),
        (
            lambda x, y, wr, wl: (x, y, np.where(np.arange(len(x)) == 7, -0.1, wr), wl),
            "w_right must be positive; point 7",
        ),
        (
            lambda x, y, wr, wl: (np.where(np.arange(len(x)) == 3, np.nan, x), y, wr, wl),
            "x is not finite .* at point 3",
        ),
        (lambda x, y, wr, wl: (x, y, wr, wl[:-1]), "differ in length"),
    ],
)
def test_bad_tracks_raise_value_errors(mutate, message):
    m = 100
    th = np.linspace(0, 2 * np.pi, m, endpoint=False)
    args = mutate(2 * np.cos(th), 2 * np.sin(th), np.full(m, 0.3), np.full(m, 0.3))
    with pytest.raises(ValueError, match=message):
        Track.from_centerline(*args)


def test_self_intersecting_and_too_tight_tracks_are_rejected():
    th = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    x, y = np.sin(2 * th + 0.01), 2 * np.sin(th + 0.005)  # figure eight
    w = np.full(200, 0.05)
    with pytest.raises(ValueError, match="intersects itself: segment"):
        Track.from_centerline(x, y, w, w)
    with pytest.raises(ValueError, match="too tight"):
        Track.from_centerline(
            0.3 * np.cos(th), 0.3 * np.sin(th), np.full(200, 0.4), np.full(200, 0.4)
        )


def test_default_track_is_a_real_circuit():
    t = make_track("default")
    assert 30 < t.length < 50
    assert t.width.min() >= 3 * 0.06 + 0.2  # three cars abreast, with room
    straight = np.abs(t.kappa) < 1e-3
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, straight, 0])))[::2]
    assert runs.max() * t.ds > 10.0  # a long straight
    # a hairpin: the heading turns by >150 degrees within 3 m
    win = int(3.0 / t.ds)
    turn = np.abs(t.psi[win:] - t.psi[:-win])
    assert np.rad2deg(turn.max()) > 150
    assert (t.kappa < -0.3).any() and (t.kappa > 0.3).any()  # left and right corners
    assert t.psi[-1] - t.psi[0] == pytest.approx(2 * np.pi, abs=0.05)  # one loop, anticlockwise


def test_random_tracks_are_seeded_and_valid():
    a, b, c = random_track(3), random_track(3), random_track(4)
    np.testing.assert_array_equal(a.x, b.x)
    assert not np.array_equal(a.x, c.x)
    assert make_track("random:3").fingerprint() == a.fingerprint()
    with pytest.raises(ValueError, match="non-negative integer"):
        make_track("random:x")


def test_tumftm_loader_with_scale(tmp_path):
    th = np.linspace(0, 2 * np.pi, 80, endpoint=False)
    data = np.column_stack([100 * np.cos(th), 100 * np.sin(th), np.full(80, 6.0), np.full(80, 5.0)])
    path = tmp_path / "Ring.csv"
    np.savetxt(path, data, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    t = load_tumftm_csv(path, scale=0.01)
    assert t.name == "Ring"
    assert t.length == pytest.approx(2 * np.pi, rel=1e-3)
    assert t.w_right.mean() == pytest.approx(0.06) and t.w_left.mean() == pytest.approx(0.05)
    bad = tmp_path / "bad.csv"
    bad.write_text("1,2,3\n4,5,6\n")
    with pytest.raises(ValueError, match="expected 4 columns"):
        load_tumftm_csv(bad)
    with pytest.raises(ValueError, match="scale must be positive"):
        load_tumftm_csv(path, scale=0)


@pytest.mark.skipif(tumftm_dir() is None, reason="TUMFTM racetrack-database folder not present")
@pytest.mark.filterwarnings("ignore:track .* inner width narrowed")
@pytest.mark.parametrize("name", ["Monza", "Spa", "Suzuka", "Shanghai"])
def test_real_circuits_load(name):
    t = make_track(f"tumftm:{name}")
    assert 50 < t.length < 200  # scaled by 1/43
    assert np.all(t.width > 0.1)
    inner = np.where(t.kappa > 0, t.w_left, t.w_right)
    assert np.all(inner * np.abs(t.kappa) <= 0.8 + 1e-9)


@pytest.mark.skipif(tumftm_dir() is None, reason="TUMFTM racetrack-database folder not present")
def test_tight_surveyed_hairpin_is_narrowed_with_a_warning_or_rejected():
    path = tumftm_dir() / "Spa.csv"
    with pytest.warns(UserWarning, match="inner width narrowed"):
        load_tumftm_csv(path, scale=1 / 43)
    with pytest.raises(ValueError, match="too tight at s = "):
        load_tumftm_csv(path, scale=1 / 43, narrow_tight=False)
    with pytest.raises(ValueError, match="allow_crossing"):
        load_tumftm_csv(tumftm_dir() / "Suzuka.csv", scale=1 / 43)
