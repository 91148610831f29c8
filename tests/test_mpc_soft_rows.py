"""The MPC's soft rows as DAQP charges them: :func:`agents.mpc.qp.exact_soft_qp` makes DAQP's
penalty the cost's ``v^2 / (2 rho)`` whatever the row's norm; DAQP alone divides by the
norm squared."""

import daqp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.mpc.config import MPCConfig, exact_soft_on
from agents.mpc.qp import exact_soft_qp
from racing_env.vehicle import VehicleParams
from racing_env.vehicles import FullSizeParams


def penalised(H, f, A, blo, bhi, sense, rho, x):
    """The cost model the SQP's merit uses: quadratic plus ``v^2 / (2 rho)`` per soft row."""
    nv = f.shape[0]
    a = A @ x
    v = np.maximum(np.maximum(blo[nv:] - a, a - bhi[nv:]), 0.0)
    v[sense[nv:] != 8] = 0.0
    return 0.5 * x @ H @ x + f @ x + (v @ v) / (2.0 * rho)


def solve(H, f, A, blo, bhi, sense, rho, exact):
    nv = f.shape[0]
    if exact:
        H, f, A, blo, bhi, sense, rho = exact_soft_qp(H, f, A, blo, bhi, sense, rho)
    x, _, flag, _ = daqp.solve(H, f, A, bhi, blo, sense, rho_soft=rho)
    assert flag >= 0
    return x[:nv]


@pytest.mark.parametrize("norm", [1.0, 10.0, 100.0])
def test_one_soft_row_by_hand(norm):
    # min x^2 / 2 + (norm - norm x)^2 / 2 (rho 1, the row norm x >= norm violated by
    # norm (1 - x)): x = norm^2 / (1 + norm^2); DAQP alone gives 1/2 for every norm
    H, f = np.eye(1), np.zeros(1)
    A = np.array([[norm]])
    blo, bhi = np.array([-10.0, norm]), np.array([10.0, 1e30])
    sense = np.array([0, 8], dtype=np.int32)
    x = solve(H, f, A, blo, bhi, sense, 1.0, exact=True)
    assert x[0] == pytest.approx(norm**2 / (1.0 + norm**2), rel=1e-6)
    plain = solve(H, f, A, blo, bhi, sense, 1.0, exact=False)
    assert plain[0] == pytest.approx(0.5, rel=1e-6)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), rho=st.floats(1e-3, 10.0))
def test_step_minimises_the_cost_model(seed, rho):
    # random convex QPs with soft rows of norms from 0.1 to 100: the exact step is a minimum
    # of the penalised model (no coordinate move lowers it), and never worse than DAQP's own
    rng = np.random.default_rng(seed)
    nv, nrows = 6, 8
    M = rng.normal(size=(nv, nv))
    H = M @ M.T + 0.5 * np.eye(nv)
    f = rng.normal(size=nv)
    A = rng.normal(size=(nrows, nv)) * (10.0 ** rng.uniform(-1, 2, size=(nrows, 1)))
    mid = A @ rng.normal(size=nv) * 2.0
    blo = np.concatenate([-np.full(nv, 5.0), mid - 0.1])
    bhi = np.concatenate([np.full(nv, 5.0), mid + 0.1])
    sense = np.concatenate([np.zeros(nv), np.full(nrows, 8)]).astype(np.int32)
    x = solve(H, f, A, blo, bhi, sense, rho, exact=True)
    best = penalised(H, f, A, blo, bhi, sense, rho, x)
    plain = solve(H, f, A, blo, bhi, sense, rho, exact=False)
    assert best <= penalised(H, f, A, blo, bhi, sense, rho, plain) + 1e-4 * (1 + abs(best))
    for i in range(nv):
        for eps in (1e-4, -1e-4):
            y = x.copy()
            y[i] = np.clip(y[i] + eps, -5.0, 5.0)
            assert best <= penalised(H, f, A, blo, bhi, sense, rho, y) + 1e-4 * (
                1 + abs(best)
            )  # DAQP tolerances


def test_class_defaults_and_bad_value():
    assert exact_soft_on(MPCConfig(), FullSizeParams())
    assert not exact_soft_on(MPCConfig(), VehicleParams())  # the paper's MPC as it was
    assert exact_soft_on(MPCConfig(exact_soft=True), VehicleParams())
    with pytest.raises(ValueError, match="exact_soft"):
        MPCConfig(exact_soft="yes")
