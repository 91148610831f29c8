"""The wake rule against the published figures it was fitted to, and its bookkeeping."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from racing_env import wake as W
from racing_env.vehicle import VehicleParams
from racing_env.vehicles.fullsize import FullSizeParams

TOL = 1e-9  # the fits go through the published points (3 parameters, 3 points)


def test_fit_reproduces_the_published_points():
    rows = W.fit_rows()
    assert len(rows) == 7
    for _, _, published, fitted in rows:
        assert fitted == pytest.approx(published, abs=TOL)


def test_constants_are_the_fit():
    assert W.fit_curve(W.FIA_2017_21) == pytest.approx((W.A_DOWNFORCE, W.G0, W.Q), rel=1e-8)
    assert W.fit_curve(W.FIA_2022) == pytest.approx(W.DOWNFORCE_2022, rel=1e-8)
    assert W.A_DRAG * W.wake_shape(0.5, W.G0, W.Q) == pytest.approx(0.43, abs=TOL)


def test_print_fit(capsys):
    W.print_fit()
    out = capsys.readouterr().out
    assert "| FIA 2017-21 downforce | 1 | 50% | 50.00% |" in out
    assert "| Cerutti 2021 drag (rear van) | 0.5 | 43% | 43.00% |" in out


def test_tow_at_the_drs_window_is_worth_about_a_drs():
    """Check, not fitted: ~16 lengths (1 s at 80 m/s) gives +3% top speed at constant power,
    10 km/h at 330 km/h (FIA: DRS is worth 10-12 km/h)."""
    fd, _ = W.wake_factors(16.0, 0.0, 1.0)
    assert 0.08 < 1 - fd < 0.10
    assert 9.0 < 330 * (fd ** (-1 / 3) - 1) < 12.0


gaps = st.floats(0.0, 70.0)
lats = st.floats(0.0, 5.0)


@given(g1=gaps, g2=gaps, y=st.floats(0.0, 0.5), strength=st.floats(0.1, 3.0))
@settings(max_examples=60, deadline=None)
def test_monotone_in_gap(g1, g2, y, strength):
    """Weaker further back, for a follower overlapping the leader by at least half a width
    (the bound: q / (G0 + g) >= y^2 SPREAD / sigma^3 holds at g = 0 up to y = 0.55)."""
    lo, hi = min(g1, g2), max(g1, g2)
    a, b = W.wake_factors(lo, y, strength), W.wake_factors(hi, y, strength)
    assert a[0] <= b[0] + 1e-15 and a[1] <= b[1] + 1e-15


def test_the_widening_wake_reaches_an_offset_car_further_back():
    """TORCS' cone: a car a full width aside is clear of the wake close behind, not far back."""
    near, far = W.wake_factors(0.0, 1.5, 1.0), W.wake_factors(5.0, 1.5, 1.0)
    assert near[1] > 0.98 and far[1] < 0.9


@given(g=gaps, y1=lats, y2=lats, strength=st.floats(0.1, 3.0))
@settings(max_examples=60, deadline=None)
def test_monotone_in_lateral_offset(g, y1, y2, strength):
    lo, hi = min(y1, y2), max(y1, y2)
    a, b = W.wake_factors(g, lo, strength), W.wake_factors(g, hi, strength)
    assert a[0] <= b[0] + 1e-15 and a[1] <= b[1] + 1e-15
    assert W.wake_factors(g, -lo, strength) == a  # symmetric (the batched path takes |dn|)


@given(g=st.floats(-2.0, 100.0), y=st.floats(-10.0, 10.0), strength=st.floats(0.0, 5.0))
@settings(max_examples=60, deadline=None)
def test_factors_in_unit_interval_and_downforce_suffers_more(g, y, strength):
    fd, fz = W.wake_factors(g, y, strength)
    assert 0.0 < fz <= fd <= 1.0


def test_range_and_overlap():
    assert W.wake_factors(W.WAKE_RANGE, 0.0, 1.0) == (1.0, 1.0)
    assert W.wake_factors(-1.0, 0.0, 1.0) == (1.0, 1.0)  # alongside: no wake
    assert W.wake_factors(-0.5, 0.0, 1.0)[1] == pytest.approx(1 - 0.5 * W.A_DOWNFORCE)
    assert W.wake_factors(0.0, 0.0, 1.0)[1] == pytest.approx(1 - W.A_DOWNFORCE)
    # lateral: at 1 width aside, close behind, the wake is weak (sigma 0.5 widths)
    assert W.wake_factors(0.0, 1.0, 1.0)[1] == pytest.approx(1 - W.A_DOWNFORCE * math.exp(-2))


@given(
    s=st.lists(st.floats(-500.0, 5000.0), min_size=1, max_size=8),
    data=st.data(),
)
@settings(max_examples=30, deadline=None)
def test_strength_zero_is_exactly_off(s, data):
    n = data.draw(st.lists(st.floats(-6.0, 6.0), min_size=len(s), max_size=len(s)))
    fd, fz = W.wake_factors_cars(np.array(s), np.array(n), 4.7, 2.0, 300.0, 0.0)
    assert np.all(fd == 1.0) and np.all(fz == 1.0)
    for g in (0.0, 0.5, 3.0):
        assert W.wake_factors(g, 0.0, 0.0) == (1.0, 1.0)


def test_a_car_ahead_across_the_line_is_seen():
    L = 300.0
    # follower near the end of lap 1, leader 1.5 lengths ahead (nose to tail) on lap 2
    s = np.array([L - 3.0, L - 3.0 + 2.5 * 4.7])
    fd, fz = W.wake_factors_cars(s, np.zeros(2), 4.7, 2.0, L)
    ref = W.wake_factors(1.5, 0.0, 1.0)
    assert (fd[0], fz[0]) == pytest.approx(ref)
    assert fd[1] == 1.0 and fz[1] == 1.0  # the leader has nobody ahead within range
    # unwrapped s a lap apart (the follower is a lap ahead on paper): position is what counts
    s = np.array([L + 10.0, 10.0 + 2.5 * 4.7 - 2 * L])
    fd, fz = W.wake_factors_cars(s, np.zeros(2), 4.7, 2.0, L)
    assert (fd[0], fz[0]) == pytest.approx(ref)


@given(
    s=st.lists(st.floats(0.0, 400.0), min_size=2, max_size=8),
    data=st.data(),
    strength=st.floats(0.0, 2.0),
)
@settings(max_examples=30, deadline=None)
def test_batched_equals_compiled_per_car(s, data, strength):
    s = np.array(s)
    n = np.array(data.draw(st.lists(st.floats(-6.0, 6.0), min_size=len(s), max_size=len(s))))
    lengths, widths = np.full(len(s), 4.7), np.full(len(s), 2.0)
    fd, fz = W.wake_factors_cars(s, n, lengths, widths, 250.0, strength)
    for i in range(len(s)):
        a, b = W.wake_of_car(i, s, n, lengths, widths, 250.0, strength)
        assert fd[i] == pytest.approx(a, rel=1e-12) and fz[i] == pytest.approx(b, rel=1e-12)
    # the strongest wake: never weaker than that of any single car ahead
    for i in range(len(s)):
        for j in range(len(s)):
            if i != j:
                g = ((s[j] - s[i]) % 250.0) / 4.7 - 1
                one = W.wake_factors(g, abs(n[j] - n[i]) / 2.0, strength)
                assert fd[i] <= one[0] + 1e-12 and fz[i] <= one[1] + 1e-12


@pytest.mark.parametrize("bad", [-0.5, float("nan"), float("inf"), True, "1"])
def test_bad_strength_is_named(bad):
    with pytest.raises(ValueError, match="wake strength must be a finite number >= 0, got"):
        W.wake_factors_cars(np.zeros(2), np.zeros(2), 4.7, 2.0, 100.0, bad)


def test_bad_strength_in_the_compiled_kernel():
    with pytest.raises(ValueError, match="wake strength"):
        W.wake_factors(1.0, 0.0, -1.0)


def test_full_size_tow_against_the_orca_car():
    """Drag-limited vs motor-limited: the same wake (1 length) is worth +14% top speed to the
    full-size car and about 1% to the 1:43 car."""
    fd, _ = W.wake_factors(1.0, 0.0, 1.0)
    big = FullSizeParams()
    gain_big = big.top_speed(fd) / big.top_speed() - 1
    assert 0.13 < gain_big < 0.16
    orca = VehicleParams()
    a, b, c = orca.C4 * fd, orca.C2, orca.C3 - orca.C1
    v_tow = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    gain_orca = v_tow / orca.top_speed - 1
    assert 0.0 < gain_orca < 0.02
