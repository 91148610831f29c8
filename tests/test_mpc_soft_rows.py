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


@pytest.mark.slow
def test_ipopt_solves_the_full_size_mpcs_problem():
    # IPOPT's NLP at full size (scaled weights, slip-angle slacks) is the problem the RTI's
    # cost describes: from the RTI's plan in a fast curve of Monza, IPOPT's plan costs no
    # more on the RTI's own merit, and its objective is that merit
    from agents.mpc import MPC
    from agents.mpc_ipopt import IpoptMPC
    from racing_env.controllers import raceline_config_for
    from racing_env.raceline import get_raceline
    from racing_env.tracks import make_track
    from racing_env.vehicles import FullSizeParams

    car = FullSizeParams()
    track = make_track("tumftm:Monza", vehicle_class="fullsize")
    line = get_raceline(track, car, raceline_config_for(car))
    rti, ipopt = MPC(track), IpoptMPC(track)
    assert isinstance(ipopt.vehicle, FullSizeParams)
    # the Curva Grande at the line's speed (at full throttle, where the drive law's traction
    # and power limits meet in a kink, IPOPT does not converge: benchmarks/mpc_speed.py
    # counts those states apart)
    s0 = 1300.0
    v = float(line.speed_at(s0))
    x0 = np.array([s0, float(line.offset_at(s0)), 0.0, v, 0.0, 0.0])
    K, dt = rti.cfg.horizon, rti.cfg.dt
    s_ref = s0 + v * dt * np.arange(1, K + 1)
    n_ref = np.array([float(line.offset_at(s)) for s in s_ref])
    rti.solve(x0, s_ref, n_ref, 20.0)
    U_rti = rti.last_plan[0]
    nodes = x0[0] + x0[3] * dt * np.arange(K + 1)
    X_rti = rti._plan(x0, U_rti, s_prev=nodes, jacobians=False, passes=3)[0]
    ipopt.solve(x0, s_ref, n_ref, 20.0, init=(np.column_stack([x0, X_rti]), U_rti))
    assert ipopt.last_U is not None

    def merit(U):
        X = rti._plan(x0, U, s_prev=nodes, jacobians=False, passes=3)[0]
        return rti._merit(X, np.asarray(U, dtype=float), s_ref, n_ref, 20.0, None)

    j_rti, j_ipopt = merit(U_rti), merit(ipopt.last_U)
    assert j_ipopt <= j_rti * (1.0 + 1e-3)
    assert ipopt.last_cost == pytest.approx(j_ipopt, rel=0.02)


def test_a_blown_up_qp_goes_to_daqps_own_weighting_not_to_an_abort():
    """A full-size QP from a blown-up linearisation (soft rows of norm 1.9e10, slip rows near
    rest; recorded from the race that aborted, Monza, seed 77 of the defend bench) scales the
    exact soft rows' rho to 8e-23, where DAQP broke its heap and the process aborted. The
    MPC hands such a QP to DAQP's own weighting: in a fresh process, it returns a step or a
    failure, and counts it."""
    import subprocess
    import sys
    from pathlib import Path

    from agents.mpc.qp import EXACT_RHO_FLOOR

    path = Path(__file__).parent / "data" / "daqp_abort_qp.npz"
    d = np.load(path)
    args = [d[k] for k in ("H", "f", "A", "blo", "bhi", "sense")]
    assert exact_soft_qp(*args, float(d["rho"]))[6] < EXACT_RHO_FLOOR
    code = f"""
import daqp, numpy as np
from agents.mpc.solver import MPC
d = np.load({str(path)!r})
mpc = MPC.__new__(MPC)
mpc._exact_soft, mpc.stats = True, {{"exact_failed": 0, "qp_iterations": 0}}
mpc._soft_rho = lambda q: float(d["rho"])
mpc.cfg = type("C", (), {{"qp_iter_limit": 300}})()
du, flag = mpc._qp(daqp, *[d[k] for k in ("H", "f", "A", "blo", "bhi", "sense")], 5.0)
assert mpc.stats["exact_failed"] == 1 and du.shape == (30,), (flag, mpc.stats)
print("ok", flag)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("ok")
