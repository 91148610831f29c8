"""DAQP from compiled code (agents.mpc.daqp_native): bit for bit the Python binding's solutions."""

import os
import subprocess
import sys
import textwrap
import warnings

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

daqp = pytest.importorskip("daqp")

from agents.mpc import daqp_native  # noqa: E402

if not daqp_native.AVAILABLE:
    pytest.skip(
        f"DAQP's C solver is not callable from compiled code here: "
        f"{daqp_native.UNAVAILABLE_REASON}",
        allow_module_level=True,
    )

from agents.mpc.daqp_native import solve_qp, solve_qps  # noqa: E402

INF = 1e30  # the MPC's infinity


def reference(qp):
    """``(x, exitflag, iterations)`` of ``daqp.solve`` on ``qp = (H, f, A, bupper, blower,
    sense, rho_soft, iter_limit)``."""
    H, f, A, bu, bl, sense, rho, limit = qp
    x, _, flag, info = daqp.solve(H, f, A, bu, bl, sense, rho_soft=rho, iter_limit=limit)
    return x, flag, info["iterations"]


def assert_same(qp, got):
    """``got = (x, exitflag, iterations)`` equals ``daqp.solve``'s bit for bit (x only where
    the binding reports a solution)."""
    x_ref, flag_ref, it_ref = reference(qp)
    x, flag, it = got
    assert (flag, it) == (flag_ref, it_ref)
    if flag_ref >= 0:
        assert x.dtype == np.float64 and np.array_equal(x, x_ref)


def random_qp(rng, n, mA, ms, soft, inf_share, eq_share=0.0, rho=1e-3, limit=1000):
    """A feasible QP: ``n`` variables, ``ms`` simple bounds, ``mA`` general rows, bounds about
    a random point (each side infinite with probability ``inf_share``, a hard row an
    equality with ``eq_share``), the rows soft (sense 8) with probability ``soft``."""
    M = rng.standard_normal((n, n))
    H = M @ M.T + 0.1 * np.eye(n)
    f = rng.standard_normal(n)
    A = rng.standard_normal((mA, n))
    x0 = rng.standard_normal(n)
    centre = np.concatenate((x0[:ms], A @ x0))
    m = ms + mA
    bu = centre + rng.uniform(0.0, 1.0, m)
    bl = centre - rng.uniform(0.0, 1.0, m)
    bu[rng.random(m) < inf_share] = INF
    bl[rng.random(m) < inf_share] = -INF
    sense = np.zeros(m, np.int32)
    sense[ms:][rng.random(mA) < soft] = 8
    eq = (sense == 0) & (rng.random(m) < eq_share)
    bu[eq] = bl[eq] = centre[eq]
    sense[eq] = 5
    return H, f, A, bu, bl, sense, rho, limit


@pytest.fixture(scope="module")
def mpc_qps():
    """The QPs of a few MPC solves on the default track, a car ahead (soft separation rows),
    recorded at ``MPC._qp``'s call of ``daqp.solve``."""
    from agents.mpc import MPC
    from racing_env import make_track

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mpc = MPC(make_track("default"))
    qps = []
    qp = MPC._qp

    def recording_qp(self, daqp_module, *args):
        class Spy:
            @staticmethod
            def solve(H, f, A, bu, bl, sense, rho_soft, iter_limit):
                qps.append(
                    tuple(np.array(a) for a in (H, f, A, bu, bl, sense)) + (rho_soft, iter_limit)
                )
                return daqp_module.solve(
                    H, f, A, bu, bl, sense, rho_soft=rho_soft, iter_limit=iter_limit
                )

        return qp(self, Spy, *args)

    K = mpc.cfg.horizon
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(MPC, "_qp", recording_qp)
        mp.setattr(MPC, "compiled_solves", False)  # the Python solve, whose QPs pass here
        u = np.zeros(2)
        for n0, gap in ((0.05, 0.6), (-0.1, 0.4), (0.12, 0.3)):
            x = np.array([3.0, n0, 0.0, 2.5, 0.0, 0.0])
            s_ref = 3.0 + 2.6 * 0.1 * np.arange(1, K + 1)
            opp = np.array([[3.0 + gap, 0.0, 2.0]])
            for _ in range(2):
                u = mpc.solve(x, s_ref, np.zeros(K), 50.0, opp, u)
    assert len(qps) >= 10
    return qps


def test_mpc_qps_bit_for_bit(mpc_qps):
    flags = set()
    for qp in mpc_qps:
        got = solve_qp(*qp)
        assert_same(qp, got)
        flags.add(int(got[1]))
    assert flags & {1, 2}  # solved ones among them


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 12),
    mA=st.integers(0, 14),
    ms_share=st.floats(0.0, 1.0),
    soft=st.sampled_from([0.0, 0.5, 1.0]),
    inf_share=st.sampled_from([0.0, 0.3]),
    eq_share=st.sampled_from([0.0, 0.2]),
    rho=st.sampled_from([1e-6, 1e-3, 1.0]),
)
def test_random_qps_bit_for_bit(seed, n, mA, ms_share, soft, inf_share, eq_share, rho):
    rng = np.random.default_rng(seed)
    ms = int(round(ms_share * n))
    qp = random_qp(rng, n, mA, ms, soft, inf_share, eq_share, rho)
    assert_same(qp, solve_qp(*qp))


def test_infeasible_and_iteration_limited_flags_match():
    rng = np.random.default_rng(3)
    H, f, A, bu, bl, sense, rho, limit = random_qp(rng, 6, 8, 3, 0.0, 0.0)
    # two hard rows that contradict: a x >= 1 and a x <= -1
    A[1] = A[0]
    bl[3], bu[3] = 1.0, INF
    bl[4], bu[4] = -INF, -1.0
    infeasible = (H, f, A, bu, bl, sense, rho, limit)
    flag = reference(infeasible)[1]
    assert flag < 0
    assert_same(infeasible, solve_qp(*infeasible))
    # a problem that needs several active-set iterations, capped at one
    qp = random_qp(np.random.default_rng(5), 10, 12, 10, 0.0, 0.0)
    capped = qp[:-1] + (1,)
    assert reference(qp)[2] > 1 and reference(capped)[1] < 0
    assert_same(capped, solve_qp(*capped))


def test_inputs_are_not_written_and_other_layouts_are_copied(mpc_qps):
    H, f, A, bu, bl, sense, rho, limit = mpc_qps[0]
    before = [a.copy() for a in (H, f, A, bu, bl, sense)]
    x = solve_qp(H, f, A, bu, bl, sense, rho, limit)[0]
    assert all(np.array_equal(a, b) for a, b in zip(before, (H, f, A, bu, bl, sense)))
    # Fortran-ordered H and A, int64 sense: copied to what DAQP takes, the same solution
    x_f = solve_qp(
        np.asfortranarray(H), f, np.asfortranarray(A), bu, bl, sense.astype(np.int64), rho, limit
    )[0]
    assert np.array_equal(x, x_f)


def test_sizes_are_checked():
    H, f, A, bu, bl, sense, rho, limit = random_qp(np.random.default_rng(0), 4, 3, 2, 0.0, 0.0)
    with pytest.raises(ValueError, match="blower and sense"):
        solve_qp(H, f, A, bu, bl[:-1], sense, rho, limit)
    with pytest.raises(ValueError, match="H must be"):
        solve_qp(H[:3, :3], f, A, bu, bl, sense, rho, limit)


def pad(qps):
    """``qps`` in solve_qps' padded layout, with a margin past the largest sizes."""
    B = len(qps)
    n = np.array([q[1].shape[0] for q in qps])
    m = np.array([q[3].shape[0] for q in qps])
    mA = np.array([q[2].shape[0] for q in qps])
    N, M, R = n.max() + 1, m.max() + 2, mA.max() + 1
    H, f, A = np.full((B, N, N), np.nan), np.full((B, N), np.nan), np.full((B, R, N), np.nan)
    bu, bl, sense = np.full((B, M), np.nan), np.full((B, M), np.nan), np.full((B, M), 99, np.int32)
    for b, (Hb, fb, Ab, bub, blb, sb, _, _) in enumerate(qps):
        H[b, : n[b], : n[b]], f[b, : n[b]], A[b, : mA[b], : n[b]] = Hb, fb, Ab
        bu[b, : m[b]], bl[b, : m[b]], sense[b, : m[b]] = bub, blb, sb
    rho = np.array([q[6] for q in qps])
    limit = np.array([q[7] for q in qps])
    return H, f, A, bu, bl, sense, n, m, m - mA, rho, limit


@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("size", [1, 3, 8])
def test_batch_equals_single_solves(mpc_qps, size, threads):
    rng = np.random.default_rng(size)
    qps = []
    for b in range(size):  # mixed sizes: captured MPC QPs and small random ones
        if b % 2 == 0:
            qps.append(mpc_qps[(3 * b + size) % len(mpc_qps)])
        else:
            n = int(rng.integers(1, 9))
            qps.append(
                random_qp(rng, n, int(rng.integers(0, 9)), int(rng.integers(0, n + 1)), 0.5, 0.3)
            )
    if size == 8:  # an infeasible one among them
        H, f, A, bu, bl, sense, rho, limit = random_qp(rng, 4, 2, 0, 0.0, 0.0)
        A[1] = A[0]
        bl[0], bu[0], bl[1], bu[1] = 1.0, INF, -INF, -1.0
        qps[-1] = (H, f, A, bu, bl, sense, rho, limit)
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        x, flags, iters = solve_qps(*pad(qps))
    finally:
        numba.set_num_threads(old)
    assert x.shape[0] == flags.shape[0] == iters.shape[0] == size
    for b, qp in enumerate(qps):
        x1, flag1, it1 = solve_qp(*qp)
        n = qp[1].shape[0]
        assert (flags[b], iters[b]) == (flag1, it1)
        assert np.array_equal(x[b, :n], x1) and np.all(x[b, n:] == 0.0)
        assert_same(qp, (x[b, :n], flags[b], iters[b]))


FAKE_DAQP = """
import ctypes.util
__file__ = ctypes.util.find_library("m")  # a shared library without DAQP's symbols
"""


def test_missing_symbols_give_a_clear_error(tmp_path):
    """With a daqp whose file exports no DAQP symbol (libm in its place): not available, and
    solve_qp raises an error naming what is missing (it is not loaded from the cache, which
    would call a null address)."""
    solve_qp(
        np.eye(1),
        np.zeros(1),
        np.zeros((0, 1)),
        np.zeros(0),
        np.zeros(0),
        np.zeros(0, np.int32),
        1e-3,
        10,
    )  # cached
    (tmp_path / "daqp.py").write_text(FAKE_DAQP)
    script = textwrap.dedent(
        """
        import numpy as np
        from agents.mpc import daqp_native as d
        assert not d.AVAILABLE
        print(d.UNAVAILABLE_REASON)
        try:
            d.solve_qp(np.eye(1), np.zeros(1), np.zeros((0, 1)), np.zeros(0), np.zeros(0),
                       np.zeros(0, np.int32), 1e-3, 10)
        except Exception as e:
            print("ERROR", e)
        """
    )
    # numba's usual cache: where kernels that call DAQP are cached, they must not be loaded
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), env.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert "exports no C symbol daqp_quadprog, daqp_default_settings" in out.stdout
    error = out.stdout.split("ERROR", 1)[1]
    assert "DAQP's C solver cannot be called from compiled code" in error
    assert "daqp_quadprog" in error
