"""The envelope (grip) scale is ``grip``; its old name ``mu`` (which names the heading in the
state) still works, with a DeprecationWarning naming ``grip``, and gives the same numbers."""

import numpy as np
import pytest

from agents import make_agent_spec
from racing_env.controllers import RacelineFollower
from racing_env.envelope import ggv
from racing_env.raceline import get_raceline
from racing_env.raceline.speed import accel_limits, speed_limit, speed_profile
from racing_env.tracks import make_track


def test_agent_spec_mu_is_grip_with_a_warning():
    with pytest.warns(DeprecationWarning, match=r"use grip=0\.75"):
        old = make_agent_spec("raceline:mu=0.75")
    assert old.grip == 0.75 and make_agent_spec("raceline:grip=0.75").grip == 0.75
    with pytest.warns(DeprecationWarning, match=r"\.grip"):
        assert old.mu == 0.75
    with pytest.raises(ValueError, match="grip=0.7 and mu=0.8"):
        RacelineFollower(grip=0.7, mu=0.8)


def test_old_keyword_gives_the_same_numbers():
    env = ggv()
    kappa = np.linspace(0.0, 3.0, 7)
    ds = np.full(7, 0.1)
    with pytest.warns(DeprecationWarning, match="grip"):
        assert np.array_equal(env.corner_speed(kappa, mu=0.6), env.corner_speed(kappa, 0.6))
    with pytest.warns(DeprecationWarning, match="grip"):
        assert np.array_equal(speed_limit(kappa, mu=0.6), speed_limit(kappa, grip=0.6))
    with pytest.warns(DeprecationWarning, match="grip"):
        old = accel_limits(1.5, kappa, mu=0.6)
    assert all(np.array_equal(a, b) for a, b in zip(old, accel_limits(1.5, kappa, 0.6)))
    with pytest.warns(DeprecationWarning, match="grip"):
        old = speed_profile(kappa, ds, mu=0.6)
    assert all(np.array_equal(a, b) for a, b in zip(old, speed_profile(kappa, ds, 0.6)))
    rl = get_raceline("default")
    s = make_track("default").s_grid
    with pytest.warns(DeprecationWarning, match="Raceline.speed_at"):
        assert np.array_equal(rl.speed_at(s, mu=0.77), rl.speed_at(s, grip=0.77))
    with pytest.raises(TypeError, match="grip"):
        speed_profile(kappa, ds)
