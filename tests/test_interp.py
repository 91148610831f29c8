"""The one periodic grid interpolation: numpy and numba agree bit for bit, and every user
(track, simulator, racing line, general features) goes through it."""

import numpy as np
import pytest
from numba import njit

from racing_env.interp import periodic_interp, periodic_lookup
from racing_env.tracks import make_track


@njit(cache=False)
def _lookup_all(table, s, ds, length):
    out = np.empty_like(s)
    for i in range(s.size):
        out[i] = periodic_lookup(table, s[i], ds, length)
    return out


def _arc_lengths(track, rng):
    L = track.length
    grid = np.asarray(track.s_grid, dtype=float)
    return np.concatenate(
        [
            rng.uniform(-3 * L, 5 * L, 5000),
            grid,
            grid + L,
            grid - 7 * L,
            np.nextafter(grid, np.inf),
            [0.0, -0.0, -1e-20, 1e-300, L, -L, np.nextafter(L, 0.0)],
        ]
    )


@pytest.mark.parametrize("name", ["default", "oval", "random:20001"])
def test_numpy_and_numba_agree_bit_for_bit(name):
    track = make_track(name)
    s = _arc_lengths(track, np.random.default_rng(1))
    for table in (
        track.kappa,
        track.w_left,
        np.random.default_rng(2).normal(size=len(track.kappa)),
    ):
        table = np.ascontiguousarray(table, dtype=float)
        a = periodic_interp(table, s, track.length, track.ds)
        b = _lookup_all(table, s, float(track.ds), float(track.length))
        assert a.tobytes() == b.tobytes()
        assert track.interp(table, s).tobytes() == a.tobytes()


def test_grid_points_return_their_entries_and_values_between_are_linear():
    table = np.array([0.0, 1.0, 4.0, 9.0])
    length, ds = 8.0, 2.0
    assert periodic_interp(table, [0.0, 2.0, 4.0, 6.0, 8.0, -2.0], length, ds).tolist() == [
        0.0,
        1.0,
        4.0,
        9.0,
        0.0,
        9.0,
    ]
    assert periodic_interp(table, [1.0, 7.0, 15.0], length, ds).tolist() == [0.5, 4.5, 4.5]
    # per_metre and snap (the racing line's indexing), a stacked table, several laps in one
    assert periodic_interp(table, [2.0 + 1e-12], length, per_metre=0.5, snap=1e-9)[0] == 1.0
    assert periodic_interp(np.vstack([table, -table]), [3.0], length, ds)[:, 0].tolist() == [
        2.5,
        -2.5,
    ]
    two = np.concatenate([table, 10 * table])
    got = periodic_interp(
        two,
        [1.0, 1.0],
        np.array([8.0, 8.0]),
        np.array([2.0, 2.0]),
        size=np.array([4, 4]),
        offset=np.array([0, 4]),
    )
    assert got.tolist() == [0.5, 5.0]


def test_the_grid_spacing_is_given_exactly_once():
    with pytest.raises(ValueError, match="exactly one of ds and per_metre.*ds=None"):
        periodic_interp(np.zeros(3), [0.0], 3.0)
    with pytest.raises(ValueError, match="exactly one of ds and per_metre"):
        periodic_interp(np.zeros(3), [0.0], 3.0, 1.0, per_metre=1.0)


def test_the_users_share_the_implementation():
    import agents.general_features as gf
    import racing_env.raceline.result as result
    import racing_env.simulator as sim
    import racing_env.track as track

    assert sim._lookup is periodic_lookup
    assert track.periodic_interp is periodic_interp
    assert result.periodic_interp is periodic_interp
    assert gf.periodic_interp is periodic_interp
