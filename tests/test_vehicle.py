"""The bicycle model against hand-derived cases, and its three evaluations against each other."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from racing_env.simulator import _ode as ode_numba
from racing_env.vehicle import VehicleParams, casadi_model, frenet_ode_numpy

P = VehicleParams()
p = P.pack()


def ode(n=0.0, mu=0.0, vx=0.0, vy=0.0, omega=0.0, d=0.0, delta=0.0, kappa=0.0):
    return np.array(frenet_ode_numpy(n, mu, vx, vy, omega, d, delta, kappa, p), dtype=float)


def test_straight_line_longitudinal_force():
    # no slip, no steering: only F_rx acts; hand formula of the paper with smooth sign
    vx, d = 2.0, 0.7
    f_rx = (P.C1 - P.C2 * vx) * d - P.C3 * math.tanh(vx / P.v_low) - P.C4 * vx**2
    x_dot = ode(vx=vx, d=d)
    assert x_dot == pytest.approx([vx, 0.0, 0.0, f_rx / P.m, 0.0, 0.0], abs=1e-12)


def test_top_speed_balances_forces():
    v = P.top_speed
    assert ode(vx=v, d=1.0)[3] == pytest.approx(0.0, abs=1e-3)  # tanh(v/v_low) ~ 1 there
    assert ode(vx=0.9 * v, d=1.0)[3] > 0 > ode(vx=1.1 * v, d=1.0)[3]


def test_frenet_kinematics_on_a_curve():
    # car on the centre line heading along it: s' = vx, mu' = -kappa vx (no yaw yet)
    kappa, vx = 0.5, 1.5
    x_dot = ode(vx=vx, kappa=kappa)
    assert x_dot[0] == pytest.approx(vx)
    assert x_dot[2] == pytest.approx(-kappa * vx)
    # offset n to the inside shortens the path: s' = vx / (1 - n kappa)
    n = 0.2
    assert ode(n=n, vx=vx, kappa=kappa)[0] == pytest.approx(vx / (1 - n * kappa))
    # heading mu turns velocity sideways: n' = vx sin mu
    mu = 0.3
    x_dot = ode(mu=mu, vx=vx)
    assert x_dot[1] == pytest.approx(vx * math.sin(mu))
    assert x_dot[0] == pytest.approx(vx * math.cos(mu))


def fade(vx, vy=0.0, omega=0.0):
    v2 = vx**2 + vy**2 + (0.5 * (P.lf + P.lr) * omega) ** 2
    return v2 / (v2 + P.v_low**2)


def test_steering_left_yaws_left_with_hand_pacejka():
    vx, delta = 2.0, 0.1
    vx_eff = math.hypot(vx, P.v_low)
    alpha_f = delta  # vy = omega = 0
    f_fy = fade(vx) * P.Df * math.sin(P.Cf * math.atan(P.Bf * alpha_f))
    x_dot = ode(vx=vx, delta=delta)
    assert x_dot[5] == pytest.approx(f_fy * P.lf * math.cos(delta) / P.Iz)
    assert x_dot[4] == pytest.approx(f_fy * math.cos(delta) / P.m)
    assert x_dot[5] > 0 and x_dot[4] > 0
    # rear slip: alpha_r = atan((omega lr - vy) / vx_eff)
    omega, vy = 1.0, 0.05
    alpha_r = math.atan((omega * P.lr - vy) / vx_eff)
    f_ry = fade(vx, vy, omega) * P.Dr * math.sin(P.Cr * math.atan(P.Br * alpha_r))
    alpha_f = -math.atan((omega * P.lf + vy) / vx_eff)
    f_fy = fade(vx, vy, omega) * P.Df * math.sin(P.Cf * math.atan(P.Bf * alpha_f))
    x_dot = ode(vx=vx, vy=vy, omega=omega)
    assert x_dot[5] == pytest.approx((f_fy * P.lf - f_ry * P.lr) / P.Iz)


def test_standing_start_is_finite_and_does_not_roll_back():
    x_dot = ode(vx=0.0, d=0.0, delta=0.3)
    assert np.isfinite(x_dot).all()
    assert x_dot[3] == pytest.approx(0.0, abs=1e-9)  # rolling resistance is 0 at rest
    assert ode(vx=0.0, d=1.0)[3] == pytest.approx(P.C1 / P.m)
    # the low-speed fade vanishes at rest and is negligible at racing speed
    assert fade(0.0) == 0.0 and fade(1.0) > 0.99
    # braking at rest does not push backwards; braking at speed is the paper's (C1 - C2 vx) d
    assert ode(vx=0.0, d=-1.0)[3] == pytest.approx(0.0, abs=1e-12)
    vx = 2.0
    f = (P.C1 - P.C2 * vx) * -1.0 - P.C3 - P.C4 * vx**2
    assert ode(vx=vx, d=-1.0)[3] == pytest.approx(f / P.m, rel=1e-6)


finite = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    n=st.floats(-0.3, 0.3),
    mu=st.floats(-3, 3),
    vx=st.floats(0, 5),
    vy=st.floats(-2, 2),
    omega=st.floats(-8, 8),
    d=finite,
    delta=st.floats(-0.35, 0.35),
    kappa=st.floats(-1.5, 1.5),
)
def test_numpy_numba_casadi_agree(n, mu, vx, vy, omega, d, delta, kappa):
    ref = ode(n, mu, vx, vy, omega, d, delta, kappa)
    nb = np.array(ode_numba(n, mu, vx, vy, omega, d, delta, kappa, p))
    cas = np.array(casadi_model(P)([0.0, n, mu, vx, vy, omega], [d, delta], kappa)).ravel()
    np.testing.assert_allclose(nb, ref, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(cas, ref, rtol=1e-10, atol=1e-10)


def test_numpy_backend_is_batched():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (7, 8))
    x[:, 2] = np.abs(x[:, 2]) * 3  # vx >= 0
    batched = np.array(frenet_ode_numpy(*x.T, p))
    for k in range(7):
        np.testing.assert_allclose(batched[:, k], ode(*x[k]))


def test_params_validation():
    with pytest.raises(ValueError, match="m must be positive"):
        VehicleParams(m=0.0)
    with pytest.raises(ValueError, match="finite"):
        VehicleParams(Iz=float("nan"))
    with pytest.raises(ValueError, match="d_min < d_max"):
        VehicleParams(d_min=1.0, d_max=1.0)
