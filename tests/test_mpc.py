"""The MPC's building blocks (issue 3, in progress): prediction, condensing, one QP."""
import warnings

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents.mpc import MPC, MPCConfig, condense  # noqa: E402
from racing_env import make_track  # noqa: E402


@pytest.fixture(scope="module")
def mpc():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MPC(make_track("default"))


def test_condensed_sensitivities_match_finite_differences(mpc):
    K = mpc.cfg.horizon
    x0 = np.array([3.0, 0.05, 0.02, 2.0, 0.0, 0.3])
    U = np.tile([[0.5], [0.1]], (1, K))
    kap = mpc._kappa_at_substeps(x0)
    X, A, B = (np.asarray(o) for o in mpc._traj(x0, U, kap))
    G = condense(np.ascontiguousarray(A), np.ascontiguousarray(B), K)
    u = U.T.reshape(-1)
    eps = 1e-6
    for i in range(2 * K):
        up = u.copy()
        up[i] += eps
        Xp = np.asarray(mpc._traj(x0, up.reshape(K, 2).T, kap)[0])
        fd = (Xp[:2].T.reshape(-1) - X[:2].T.reshape(-1)) / eps
        np.testing.assert_allclose(G[:, i], fd, atol=1e-4)
    assert np.all(G[:2 * (K - 1), 2 * K - 2:] == 0)          # causality: late inputs move nothing early


def test_steady_tracking_on_a_straight_is_one_cheap_qp(mpc):
    mpc.reset()
    K = mpc.cfg.horizon
    x = np.array([3.0, 0.0, 0.0, 2.5, 0.0, 0.0])
    s_ref = 3.0 + 2.5 * 0.1 * np.arange(1, K + 1)
    n_ref = np.zeros(K)
    for _ in range(3):
        u = mpc.solve(x, s_ref, n_ref, 50.0, None, np.zeros(2))
        mpc._U = np.concatenate([u[:, None], mpc._U[:, :-1]], axis=1)   # same problem again
    assert mpc.last_status == "ok"
    pred = mpc.last_prediction
    np.testing.assert_allclose(pred[0], s_ref, atol=1e-2)               # holds the speed (1 cm)
    np.testing.assert_allclose(pred[1], 0.0, atol=1e-3)                 # stays on the line
    assert abs(u[1]) < 1e-3 and -1 <= u[0] <= 1


def test_config_validation():
    with pytest.raises(ValueError, match="horizon"):
        MPCConfig(horizon=1)
    with pytest.raises(ValueError, match="sep_s"):
        MPCConfig(sep_s=0.0)
