"""The g-g-v envelope (racing_env.envelope) against hand-derived cases of the bicycle model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from racing_env.controllers import understeer_gradient
from racing_env.envelope import ggv, steady_corner
from racing_env.vehicle import VehicleParams, frenet_ode_numpy

VEH = VehicleParams()
P = VEH.pack()


@settings(max_examples=40, deadline=None)
@given(V=st.floats(0.5, 4.0), frac=st.floats(0.05, 0.99))
def test_steady_corner_is_an_equilibrium_of_the_model(V, frac):
    """With the steering and velocities steady_corner returns, and the throttle that holds the
    longitudinal acceleration at zero where the motor can, the model's lateral and yaw
    derivatives vanish and the yaw rate is V * curvature."""
    ay = frac * float(ggv().lateral_limit(V))
    c = steady_corner(V, ay)
    assert bool(c["feasible"])
    vx, vy, om, de = (float(c[k]) for k in ("vx", "vy", "omega", "delta"))
    assert math.hypot(vx, vy) == pytest.approx(V, rel=1e-9)
    assert om * V == pytest.approx(ay, rel=1e-9)
    assert abs(de) <= VEH.delta_max + 1e-12
    d = 0.3
    _, _, _, vx_dot, vy_dot, om_dot = frenet_ode_numpy(0.0, 0.0, vx, vy, om, d, de, 0.0, P)
    assert abs(vy_dot) < 1e-6 * max(1.0, vx * om) + 1e-6
    assert abs(om_dot) < 1e-4
    # the drive acceleration is linear in d: full throttle gives ax_max
    _, _, _, vx_full, _, _ = frenet_ode_numpy(0.0, 0.0, vx, vy, om, 1.0, de, 0.0, P)
    assert vx_full == pytest.approx(float(c["ax_max"]), abs=1e-9)


def test_low_speed_limit_is_the_steering_bound():
    """Slowly, the car turns at the kinematic-plus-understeer curvature of full lock:
    tan(delta_max) = (lf + lr) kappa + K_us a_y, so a_y = V^2 tan(delta_max) / (L + K_us V^2)
    (linear tyres and small slip, so only where a_y is small: within 5%)."""
    L, kus = VEH.lf + VEH.lr, understeer_gradient(VEH)
    env = ggv()
    for V in (0.3, 0.6):
        by_hand = V * V * math.tan(VEH.delta_max) / (L + kus * V * V)
        assert float(env.lateral_limit(V)) == pytest.approx(by_hand, rel=0.05)


def test_limit_shape_and_motor_saturation():
    """The lateral limit grows while steering-bound and flattens out; on a straight the drive
    acceleration is the motor law and reaches zero at the top speed; in a corner at the
    lateral limit above ~2.2 m/s the motor cannot hold the speed."""
    env = ggv()
    low = env.lateral_limit(np.linspace(0.2, 1.5, 20))
    assert np.all(np.diff(low) > 0)
    assert 0.7 * 9.81 < float(env.lateral_limit(2.5)) < 0.9 * 9.81
    for V in (1.0, 2.0, 3.0):
        by_hand = (
            (VEH.C1 - VEH.C2 * V) - VEH.C3 * math.tanh(V / VEH.v_low) - VEH.C4 * V * V
        ) / VEH.m
        ax, _ = env.longitudinal_limits(V, 0.0)
        assert float(ax) == pytest.approx(by_hand, rel=1e-3)
    ax_top, _ = env.longitudinal_limits(VEH.top_speed, 0.0)
    assert abs(float(ax_top)) < 0.02
    ax_hi, ax_lo = env.longitudinal_limits(3.0, env.lateral_limit(3.0))
    assert ax_hi < 0 < -ax_lo


def test_infeasible_beyond_the_limit():
    env = ggv()
    for V in (0.5, 1.5, 3.0):
        lim = float(env.lateral_limit(V))
        assert bool(steady_corner(V, 0.98 * lim)["feasible"])
        assert not bool(steady_corner(V, 1.03 * lim)["feasible"])


def test_corner_speed_round_trip():
    env = ggv()
    for V in (1.0, 2.0, 3.0):
        kappa = float(env.lateral_limit(V)) / V**2
        assert float(env.corner_speed(kappa)) == pytest.approx(V, rel=0.01)
    assert float(env.corner_speed(0.0)) == pytest.approx(VEH.top_speed)
    assert float(env.corner_speed(1.0, grip=0.5)) < float(env.corner_speed(1.0))
