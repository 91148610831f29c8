"""The wake policy space (issue 48): a wake theta with ``h = c = 0`` is the extended theta;
``h`` holds the tow (the lateral target on the car ahead) on a straight until ``p`` lengths
before the braking point, where the overtake shift takes over; ``c`` covers the inside of the
coming corner against a car in the ego's tow. Hand-built states on the full-size Monza's main
straight (braking point 704 m, first apex to the right)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents import make_agent_spec
from agents.reference import WAKE_NAMES, Theta, reference_trajectory
from agents.reference_tables import _tables
from agents.theta import policy_space
from racing_env.controllers import raceline_config_for
from racing_env.raceline import get_raceline
from racing_env.tracks import make_track
from racing_env.vehicles import FullSizeParams

CAR = FullSizeParams()
BASE = dict(q=5.0, zeta=1.0, s1=0.3, s2=0.5, s3=1.0)  # the ORCA box: s1 = 10 m at full size


@pytest.fixture(scope="module")
def monza():
    track = make_track("tumftm:Monza", vehicle_class="fullsize")  # shipped with the package
    return track, get_raceline(track, CAR, raceline_config_for(CAR, "curvature"))


def car(s, n, v=60.0):
    return np.array([s, n, 0.0, v, 0.0, 0.0])


def ref(theta, ego, others, monza):
    track, line = monza
    return reference_trajectory(theta, ego, np.array(others), line, track, vehicle=CAR, tow=True)


def test_the_braking_points_are_the_line_s_and_the_first_corner_turns_right(monza):
    track, line = monza
    d, d_apex, side = _tables(line, track, None).next_brake(300.0)
    assert 350.0 < d < 450.0 and d < d_apex < d + 300.0  # the first chicane's braking zone
    assert side == -1.0  # the Rettifilo turns right first


@settings(max_examples=25, deadline=None)
@given(
    s=st.floats(100.0, 5000.0),
    n=st.floats(-3.0, 3.0),
    gap=st.floats(-60.0, 60.0).filter(lambda g: abs(g) > 6.0),
    dn=st.floats(-4.0, 4.0),
    p=st.floats(0.0, 60.0),
)
def test_without_hold_and_cover_a_wake_theta_is_the_extended_theta(monza, s, n, gap, dn, p):
    ext = ref(Theta(**BASE), car(s, n), [car(s + gap, n + dn, 55.0)], monza)
    wake = ref(Theta(**BASE, p=p), car(s, n), [car(s + gap, n + dn, 55.0)], monza)
    assert np.array_equal(ext.n_ref, wake.n_ref) and np.array_equal(ext.s_ref, wake.s_ref)


def test_in_the_tow_on_the_straight_the_target_is_the_car_ahead(monza):
    ahead = car(320.0, 1.5, 58.0)
    held = ref(Theta(**BASE, h=5.0, p=20.0), car(300.0, 0.0), [ahead], monza)
    assert np.all(held.n_ref == 1.5) and not held.n_ot.any()
    ext = ref(Theta(**BASE), car(300.0, 0.0), [ahead], monza)
    assert np.abs(ext.n_ref - 1.5).max() > 5.0  # the extended theta pulls out 10 m at once


def test_too_far_behind_or_aside_there_is_no_hold(monza):
    theta = Theta(**BASE, h=3.0, p=20.0)
    far = ref(theta, car(300.0, 0.0), [car(320.0, 1.5)], monza)  # 4.3 lengths > 3
    aside = ref(Theta(**BASE, h=5.0, p=20.0), car(300.0, 0.0), [car(320.0, 3.5)], monza)
    for r, ahead in ((far, car(320.0, 1.5)), (aside, car(320.0, 3.5))):
        ext = ref(Theta(**BASE), car(300.0, 0.0), [ahead], monza)
        assert np.array_equal(r.n_ref, ext.n_ref)


def test_within_p_lengths_of_the_braking_point_it_pulls_out(monza):
    track, line = monza
    d, _, _ = _tables(line, track, None).next_brake(650.0)  # 54 m before the braking point
    ahead = car(670.0, 1.5, 58.0)
    assert d < 20 * CAR.length
    pulled = ref(Theta(**BASE, h=8.0, p=20.0), car(650.0, 0.0), [ahead], monza)
    ext = ref(Theta(**BASE), car(650.0, 0.0), [ahead], monza)
    assert np.array_equal(pulled.n_ref, ext.n_ref) and pulled.n_ot.any()
    held = ref(Theta(**BASE, h=8.0, p=5.0), car(650.0, 0.0), [ahead], monza)  # 23.5 m: holds
    assert np.all(held.n_ref == 1.5)


def test_cover_moves_to_the_inside_of_the_coming_corner(monza):
    track, line = monza
    behind = car(630.0, 0.5, 62.0)  # in the ego's tow
    ego = car(650.0, 0.5)
    quiet = {**BASE, "s1": 0.0, "s3": 0.0}  # no shifts: the line, inside the clip
    base = ref(Theta(**quiet), ego, [behind], monza)
    half = ref(Theta(**quiet, p=20.0, c=0.5), ego, [behind], monza)
    full = ref(Theta(**quiet, p=20.0, c=1.0), ego, [behind], monza)
    _, d_apex, side = _tables(line, track, None).next_brake(650.0)
    inside = side * (float(np.interp(650.0 + d_apex, track.s_grid, track.w_right)) - CAR.width / 2)
    assert side < 0 and np.allclose(full.n_ref, inside)  # the right-hand edge, body on the track
    assert np.allclose(half.n_ref, base.n_ref + 0.5 * (inside - base.n_ref))
    early = ref(Theta(**quiet, p=5.0, c=1.0), ego, [behind], monza)  # 54 m > 23.5 m: not yet
    assert np.array_equal(early.n_ref, base.n_ref)


def test_the_space_and_its_bounds():
    space = policy_space("wake")
    assert space.names == WAKE_NAMES and space.dim == 9
    theta = Theta(**BASE, b=1.0, h=5.0, p=30.0, c=0.5)
    assert np.array_equal(
        space.theta(theta.as_array("wake")).as_array("wake"), theta.as_array("wake")
    )
    with pytest.raises(ValueError, match="outside the 'extended' space"):
        theta.as_array("extended")
    with pytest.raises(
        ValueError, match=r"theta parameter h = 11.0 is outside its bounds \[0, 10\]"
    ):
        Theta(**BASE, h=11.0)
    with pytest.raises(ValueError, match="parameters of the wake policy space; add space='wake'"):
        make_agent_spec("mpc:space=extended,h=5")
    agent = make_agent_spec("mpc:space=wake,b=1,h=5,p=30,c=0.5")
    assert agent.theta.h == 5.0 and agent.space == "wake"


def test_a_wake_agent_keeps_the_extended_space_s_pass_side(monza):
    """The agents, not only the reference: a wake MPC with ``h = p = c = 0`` aims its overtake
    shift at the side the extended MPC chooses by room (the ego 5 m left near the edge, the car
    ahead 3 m left: room says right), where the paper's rule keeps it left."""
    track, _ = monza
    ego, ahead = car(300.0, 5.0), car(308.0, 3.0, 55.0)
    refs = {}
    for space in ("paper", "extended", "wake"):
        b = "" if space == "paper" else ",b=0"
        agent = make_agent_spec(f"mpc:space={space},q=5,zeta=1.0,s1=0.3,s2=0.5,s3=0{b}")
        agent.reset(track, "car_0", 0)
        obs = np.concatenate([ego, ahead - ego, np.zeros(agent.n_preview)]).astype(np.float32)
        refs[space] = agent._solve_args(obs)[2]  # n_ref [m]
    assert np.array_equal(refs["wake"], refs["extended"])
    assert refs["extended"][-1] < 0.0 < refs["paper"][-1]  # right by room, left by the paper
