"""Integration, rules and reward of the compiled step, through BatchedRaces."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from racing_env import BatchedRaces, RaceConfig, RulesConfig, make_track
from racing_env.simulator import integrate_car
from racing_env.vehicle import VehicleParams

P = VehicleParams()
NO_RULES = RulesConfig(contact=False, offtrack=False)


def races(n_cars=1, rules=None, track="oval", n_races=1, **cfg):
    return BatchedRaces(
        track,
        RaceConfig(n_cars=n_cars, rules=rules or RulesConfig(), **cfg),
        n_races=n_races,
        seed=0,
    )


def place(r, states):
    r.reset()
    r.state[0] = np.asarray(states, dtype=float)
    r.start[0] = r.state[0]
    r.s_line[0] = r.state[0, :, 0].max()


def phys(r, d=0.0, delta=0.0):
    a = np.zeros((r.n_races, r.n_cars, 2))
    a[..., 0], a[..., 1] = d, delta
    return a


def test_rk4_substeps_match_a_fine_reference():
    track = make_track("default")
    r = races(track=track, rules=NO_RULES)
    x0 = np.array([2.0, 0.05, 0.02, 2.5, 0.0, 0.3])
    place(r, [x0])
    r.step_physical(phys(r, 0.4, 0.08))
    ref = x0.copy()
    tb = r._tables
    integrate_car(ref, 0.4, 0.08, tb.kappa, tb.ds, tb.length, r._params, 0.1, 400)
    # positions to 0.1 mm; rates (the stiff yaw mode) to 1 %
    np.testing.assert_allclose(r.state[0, 0, :3], ref[:3], atol=1e-4)
    np.testing.assert_allclose(r.state[0, 0, 3:], ref[3:], rtol=1e-2, atol=5e-3)


def test_coasting_on_a_straight_decelerates_by_resistance_and_drag():
    # hand check: d = 0 on the straight; vx' = -(C3 + C4 vx^2) / m (tanh ~ 1); 0.1 s of it
    r = races(rules=NO_RULES)
    place(r, [[1.0, 0.0, 0.0, 2.0, 0.0, 0.0]])
    r.step_physical(phys(r))
    expected = 2.0 - 0.1 * (P.C3 + P.C4 * 4.0) / P.m
    assert r.state[0, 0, 3] == pytest.approx(expected, abs=2e-3)
    assert r.state[0, 0, 0] == pytest.approx(1.0 + 0.1 * 0.5 * (2.0 + expected), abs=2e-3)


def test_standing_start_full_lock_stays_finite_and_moves_forward():
    r = races(rules=NO_RULES)
    place(r, [[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    for _ in range(30):
        r.step_physical(phys(r, P.d_max, P.delta_max))
        assert np.isfinite(r.state).all()
    assert r.state[0, 0, 0] > 0.1 and r.state[0, 0, 3] >= 0.0


def test_brake_never_reverses():
    r = races(rules=NO_RULES)
    place(r, [[1.0, 0.0, 0.0, 0.5, 0.0, 0.0]])
    for _ in range(20):
        r.step_physical(phys(r, P.d_min))
    assert r.state[0, 0, 3] == pytest.approx(0.0, abs=1e-6)
    assert r.state[0, 0, 0] >= 1.0 - 1e-6


def _contact_pair(rules):
    r = races(n_cars=2, rules=rules)
    # car 0 just ahead of car 1, overlapping bodies
    place(r, [[1.05, 0.0, 0.0, 2.0, 0.0, 0.0], [1.0, 0.01, 0.0, 2.0, 0.0, 0.0]])
    r.step_physical(phys(r, 0.2))
    return r


def test_contact_slows_front_by_half_and_rear_by_a_third():
    # the pair touches at the start of the period, so both are slowed there and then: each
    # ends the period as a free car that started it at vx/2 (front) and vx/3 (rear) would
    hit = _contact_pair(RulesConfig())
    assert hit.contact[0].tolist() == [1, 1]
    free = races(n_cars=2, rules=RulesConfig(contact=False))
    place(free, [[1.05, 0.0, 0.0, 1.0, 0.0, 0.0], [1.0, 0.01, 0.0, 2.0 / 3.0, 0.0, 0.0]])
    free.step_physical(phys(free, 0.2))
    assert free.contact[0].tolist() == [0, 0]
    np.testing.assert_allclose(hit.state[0, :, 3], free.state[0, :, 3], atol=2e-3)


COAST_DV = 0.1 * (P.C3 + P.C4 * 4.5**2) / P.m + 1e-3  # most speed coasting can lose in 0.1 s


@settings(max_examples=60, deadline=None)
@given(
    gap=st.floats(0.005, 1.0),
    v_fast=st.floats(2.0, 4.0),
    v_slow=st.floats(0.0, 0.5),
    n=st.floats(-0.1, 0.1),
    dn=st.floats(-0.05, 0.05),
    s=st.floats(0.6, 1.5),
)
def test_a_fast_car_cannot_drive_through_a_slow_one(gap, v_fast, v_slow, n, dn, s):
    # hand check on the oval's first straight (0.5..5.5 m), both coasting (d = 0): the fast
    # car (car 1) closes at least (v_fast - v_slow - 2 COAST_DV) * 0.1 m per step, so it meets
    # the slow one; at that moment it is behind, so it must get the rear factor (1/3) and the
    # slow car the front factor (1/2), there and then: cut to a third at the moment it touches
    # (<= 4/3 m/s against a car that is slowed too), it cannot clear the slow car's body
    # (0.12 m) in the rest of the step. Env v2: a bump also limits the rear car's speed to the
    # front car's (it cannot push on through), so it may end slower than a third
    r = races(n_cars=2)
    place(r, [[s + 0.12 + gap, n + dn, 0.0, v_slow, 0.0, 0.0], [s, n, 0.0, v_fast, 0.0, 0.0]])
    for _ in range(30):
        v0 = r.state[0, :, 3].copy()
        r.step_physical(phys(r))
        if r.contact[0].any():
            break
        assert r.state[0, 1, 0] < r.state[0, 0, 0] - 0.12  # never through without contact
    else:
        pytest.fail("the fast car never touched the slow one")
    assert r.contact[0].tolist() == [1, 1]
    v_front, v_rear = r.state[0, :, 3]
    assert max(0.0, (v0[0] - COAST_DV) / 2 - COAST_DV) <= v_front <= v0[0] / 2 + 1e-9
    assert (
        min(max(0.0, (v0[1] - COAST_DV) / 3 - COAST_DV), v_front - COAST_DV)
        <= v_rear
        <= v0[1] / 3 + 1e-9
    )
    if abs(dn) < 0.06:  # not laterally clear: kept apart
        assert r.state[0, 1, 0] <= r.state[0, 0, 0] - 0.12 + 1e-9
    assert r.state[0, 1, 0] < r.state[0, 0, 0] + 0.12  # not through


def test_contact_across_the_start_line_uses_wrapped_distance():
    r = races(n_cars=2)
    length = r.track.length
    # car 1 is a lap down but physically alongside car 0: contact must still apply
    place(r, [[length + 0.02, 0.0, 0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    r.step_physical(phys(r))
    assert r.contact[0].tolist() == [1, 1]


def test_no_contact_when_side_by_side_with_room():
    r = races(n_cars=2)
    place(r, [[1.0, 0.1, 0.0, 2.0, 0.0, 0.0], [1.0, -0.1, 0.0, 2.0, 0.0, 0.0]])
    r.step_physical(phys(r, 0.2))
    assert r.contact[0].tolist() == [0, 0]


def test_off_track_halves_speed_and_realigns():
    free = races(rules=NO_RULES)
    off = races()
    w = off.track.w_left[0]
    x0 = [[1.0, w + 0.05, 0.2, 2.0, 0.1, 0.5]]
    place(free, x0)
    place(off, x0)
    free.step_physical(phys(free, 0.2))
    off.step_physical(phys(off, 0.2))
    assert off.offtrack[0, 0] == 1
    assert off.state[0, 0, 3] == pytest.approx(free.state[0, 0, 3] / 2)
    assert off.state[0, 0, 2] == 0.0 and off.state[0, 0, 4] == 0.0 and off.state[0, 0, 5] == 0.0


def test_wall_stops_a_car_sideways():
    r = races(rules=NO_RULES)
    wall = r._tables.wall_left[0]
    place(r, [[1.0, wall - 0.01, 1.2, 3.0, 0.0, 0.0]])  # heading hard left at the wall
    r.step_physical(phys(r, 1.0))
    assert r.state[0, 0, 1] <= wall + 1e-9


def test_reward_is_change_of_gap_to_best_opponent():
    r = races(n_cars=3, rules=NO_RULES)
    place(
        r, [[2.0, 0.0, 0.0, 2.0, 0, 0], [1.0, 0.15, 0.0, 1.0, 0, 0], [0.5, -0.15, 0.0, 3.0, 0, 0]]
    )
    before = r.state[0, :, 0].copy()
    r.step_physical(phys(r, 0.1))
    after = r.state[0, :, 0]
    for i in range(3):
        others = [j for j in range(3) if j != i]
        expect = (after[i] - after[others].max()) - (before[i] - before[others].max())
        assert r.reward[0, i] == pytest.approx(expect)


def test_single_car_reward_is_progress_and_has_no_jump_at_the_line():
    r = races(n_cars=1, rules=NO_RULES)
    length = r.track.length
    place(r, [[length - 0.1, 0.0, 0.0, 2.5, 0.0, 0.0]])
    s0 = r.state[0, 0, 0]
    r.step_physical(phys(r, 0.5))
    assert r.state[0, 0, 0] > length  # unwrapped
    assert r.reward[0, 0] == pytest.approx(r.state[0, 0, 0] - s0)
    assert 0.2 < r.reward[0, 0] < 0.35


def test_driving_backwards_costs_reward():
    r = races(n_cars=2, rules=NO_RULES)
    place(r, [[0.05, 0.1, np.pi, 2.0, 0, 0], [3.0, -0.1, 0.0, 0.0, 0, 0]])
    total = 0.0
    for _ in range(5):
        r.step_physical(phys(r, 0.3))
        total += r.reward[0, 0]
    assert total < -0.5 and r.state[0, 0, 0] < 0.0  # crossed the line backwards, no jump


def test_laps_and_lap_times_are_counted():
    r = races(n_cars=1, rules=NO_RULES, laps=1)
    length = r.track.length
    place(r, [[0.0, 0.0, 0.0, 2.0, 0.0, 0.0]])
    r.state[0, 0, 0] = length - 0.05
    r.step_physical(phys(r, 0.3))
    assert r.laps[0, 0] == 1 and r.terminated()[0]
    t = r.lap_times[0][0][0]
    assert 0.0 < t < 0.1  # crossed within the first control period


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n_cars=st.integers(1, 8))
def test_batched_races_equal_single_races(seed, n_cars):
    rng = np.random.default_rng(seed)
    batch = BatchedRaces("default", RaceConfig(n_cars=n_cars), n_races=3, seed=seed)
    batch.reset(start=None)
    actions = rng.uniform(-1, 1, (6, 3, n_cars, 2))
    singles = []
    for b in range(3):
        one = BatchedRaces("default", RaceConfig(n_cars=n_cars), n_races=1)
        one.reset()
        one.state[0] = batch.state[b]
        one.start[0] = batch.start[b]
        one.s_line[0] = batch.s_line[b]
        singles.append(one)
    for a in actions:
        batch.step(a)
        for b, one in enumerate(singles):
            one.step(a[b : b + 1])
    for b, one in enumerate(singles):
        np.testing.assert_array_equal(batch.state[b], one.state[0])


def test_parallel_kernel_equals_serial_kernel(monkeypatch):
    # the same 8 races stepped once by each kernel: the threshold that picks the kernel is set
    # per call, so the comparison holds whatever core.PARALLEL_MIN_RACES is
    import racing_env.core as core

    rng = np.random.default_rng(1)
    par = BatchedRaces("default", RaceConfig(n_cars=3), n_races=8, seed=5)
    ser = BatchedRaces("default", RaceConfig(n_cars=3), n_races=8, seed=5)
    par.reset()
    ser.reset()
    ser.state[:] = par.state
    kernels = {"parallel": 0, "serial": 0}
    for name, fn in (("parallel", "advance_parallel"), ("serial", "advance")):
        real = getattr(core, fn)

        def counted(*args, _real=real, _name=name, **kwargs):
            kernels[_name] += 1
            return _real(*args, **kwargs)

        monkeypatch.setattr(core, fn, counted)
    for _ in range(20):
        a = rng.uniform(-1, 1, (8, 3, 2))
        monkeypatch.setattr(core, "PARALLEL_MIN_RACES", 1)  # parallel for any n
        op, _, _, _ = par.step(a)
        monkeypatch.setattr(core, "PARALLEL_MIN_RACES", 10**9)  # serial for any n
        os_, _, _, _ = ser.step(a)
    assert kernels == {"parallel": 20, "serial": 20}
    np.testing.assert_array_equal(par.state, ser.state)
    np.testing.assert_array_equal(op, os_)


def test_bad_actions_raise_clear_errors():
    r = races(n_cars=2)
    r.reset()
    with pytest.raises(ValueError, match="shape"):
        r.step(np.zeros((1, 3, 2)))
    a = np.zeros((1, 2, 2))
    a[0, 1, 0] = np.nan
    with pytest.raises(ValueError, match="car 1 in race 0 is NaN"):
        r.step(a)


def test_start_regions_put_cars_in_the_requested_order():
    r = races(n_cars=3, track="default")
    r.reset(seed=3, order=[2, 0, 1])  # car_1 in R1, car_2 in R2, car_0 in R3
    s = r.state[0, :, 0]
    assert s[1] > s[2] > s[0]
    with pytest.raises(ValueError, match="permutation"):
        r.reset(order=[0, 0, 1])


def test_config_validation_names_the_value():
    with pytest.raises(ValueError, match="n_cars must be an integer in 1..8, got 9"):
        RaceConfig(n_cars=9)
    with pytest.raises(ValueError, match="front_factor"):
        RulesConfig(front_factor=1.5)
    with pytest.raises(ValueError, match="max_cycles"):
        RaceConfig(max_cycles=0)


# ---------------------------------------------------------------------- env v2: bodies apart
C_DS, C_DN = RulesConfig().contact_ds, RulesConfig().contact_dn


def _order_kept(before, after, length):
    """Per pair of cars: (laterally overlapping at both ends, order the same at both ends)."""
    out = []
    n = before.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            d0 = (before[i, 0] - before[j, 0] + length / 2) % length - length / 2
            d1 = (after[i, 0] - after[j, 0] + length / 2) % length - length / 2
            # (a pair pushed apart sideways sits at exactly c_dn: touching, not overlapping)
            overlap = (
                abs(before[i, 1] - before[j, 1]) < C_DN - 1e-7
                and abs(after[i, 1] - after[j, 1]) < C_DN - 1e-7
            )
            out.append((overlap, (d0 > 0) == (d1 > 0), d1, after[i, 1] - after[j, 1]))
    return out


def _assert_apart(r):
    """No two cars of race 0 overlap (|ds| < c_ds and |dn| < c_dn) at the end of a step."""
    st, length = r.state[0], r.track.length
    for i in range(r.n_cars):
        for j in range(i + 1, r.n_cars):
            d = (st[i, 0] - st[j, 0] + length / 2) % length - length / 2
            assert not (abs(d) < C_DS - 1e-7 and abs(st[i, 1] - st[j, 1]) < C_DN - 1e-7), (i, j, d)


@pytest.mark.parametrize(
    "track, s0",
    [("oval", 1.0), ("oval", 7.0), ("default", 3.0), ("default", 13.5), ("default", 33.0)],
)
def test_full_throttle_cannot_push_through_a_stopped_car(track, s0):
    # the case: a car at full throttle from rest, 0.5 m behind a braking (stopped)
    # car on the same line; both steer along the racing line (oval 7 m and default 13.5 and
    # 33 m are corners). v1 let the rear car end 8-14 m ahead after 60 steps; v2 keeps it
    # behind, touching (contact at nearly every step), for the whole 6 s of pushing
    from racing_env.controllers import RacelineFollower, follower_action

    r = races(n_cars=2, track=track)
    f = RacelineFollower()
    f.reset(r.track)
    n_ref = f.tables()[0]
    line_n = lambda s: float(r.track.interp(n_ref, s))
    assert abs(r.track.curvature(s0 + 0.5)) > 0.5 or s0 in (1.0, 3.0)  # the corner cases bend
    place(r, [[s0 + 0.5, line_n(s0 + 0.5), 0, 0, 0, 0], [s0, line_n(s0), 0, 0, 0, 0]])
    tb = [np.asarray(a, dtype=float) for a in f.tables()]
    contacts = 0
    for _ in range(60):
        before = r.state[0].copy()
        a = np.zeros((1, 2, 2))
        for i in range(2):
            a[0, i] = follower_action(r.state[0, i], *tb, r.track.ds, r.track.length, f.gains())
        a[0, 0, 0], a[0, 1, 0] = -1.0, 1.0  # front brakes, rear full throttle
        r.step(a)
        contacts += int(r.contact[0, 1])
        _assert_apart(r)
        for overlap, kept, *_ in _order_kept(before, r.state[0], r.track.length):
            assert kept or not overlap
    gap = r.state[0, 0, 0] - r.state[0, 1, 0]
    assert r.state[0, 0, 3] == 0.0 and gap >= C_DS - 1e-9  # stopped, and still ahead
    assert abs(r.state[0, 0, 1] - r.state[0, 1, 1]) < C_DN and gap == pytest.approx(C_DS)
    assert contacts >= 50  # pushing is contact


@settings(max_examples=40, deadline=None)
@example(seed=2_147_483_647, n_cars=2, s=20.40397426061176, spread=0.13, track="default")
@given(
    seed=st.integers(0, 2**31 - 1),
    n_cars=st.integers(2, 4),
    s=st.floats(0.5, 25.0),
    spread=st.floats(0.13, 0.6),
    track=st.sampled_from(["oval", "default"]),
)
def test_no_two_cars_swap_order_while_they_overlap_laterally(seed, n_cars, s, spread, track):
    # cars bunched up close behind one another at random offsets and speeds, random held
    # inputs: at every step end no two bodies overlap, and a pair that overlaps laterally at
    # both ends of a step keeps its order (a pass needs free space beside the other car)
    rng = np.random.default_rng(seed)
    r = races(n_cars=n_cars, track=track)
    x = np.zeros((n_cars, 6))
    x[:, 0] = s + spread * np.arange(n_cars)[::-1]
    x[:, 1] = rng.uniform(-0.05, 0.05, n_cars)
    x[:, 3] = rng.uniform(0.0, 3.0, n_cars)
    place(r, x)
    a = rng.uniform(-1, 1, (1, n_cars, 2))
    for k in range(40):
        if k % 5 == 0:
            a = rng.uniform(-1, 1, (1, n_cars, 2))
            a[..., 0] = np.where(rng.random(n_cars) < 0.5, 1.0, a[..., 0])
        before = r.state[0].copy()
        r.step(a)
        _assert_apart(r)
        for overlap, kept, *_ in _order_kept(before, r.state[0], r.track.length):
            assert kept or not overlap


def test_a_car_steering_into_one_alongside_pushes_it_aside_not_back():
    # side by side on the oval's straight, 3 cm apart along s and 8 cm sideways; the left car
    # steers right into the other: the two are pushed apart sideways (to c_dn), nobody is
    # thrown back along the track, and each keeps its place
    r = races(n_cars=2)
    place(r, [[2.03, 0.04, 0.0, 2.0, 0.0, 0.0], [2.0, -0.04, 0.0, 2.0, 0.0, 0.0]])
    a = np.zeros((1, 2, 2))
    a[0, 0, 1] = -P.delta_max
    for _ in range(3):
        s_before = r.state[0, :, 0].copy()
        r.step_physical(a)
        _assert_apart(r)
        assert np.all(r.state[0, :, 0] > s_before)  # nobody thrown back
    assert r.contacts[0, 0] == r.contacts[0, 1] >= 1  # bumped, both
    assert r.state[0, 0, 1] - r.state[0, 1, 1] >= C_DN - 1e-7  # apart sideways
    assert r.state[0, 0, 0] > r.state[0, 1, 0]  # order kept


def test_rewards_telescope_through_contact():
    # the rear car pushes the front one for 30 steps: the corrections move cars, and the
    # summed rewards still equal the change of s_i - max_{j != i} s_j
    r = races(n_cars=3, track="default")
    place(r, [[4.0, 0.0, 0, 0.5, 0, 0], [3.8, 0.01, 0, 2.5, 0, 0], [3.6, -0.02, 0, 3.0, 0, 0]])
    x0 = r.state[0].copy()
    total = np.zeros(3)
    a = np.zeros((1, 3, 2))
    a[0, :, 0] = [P.d_min, P.d_max, P.d_max]
    for _ in range(30):
        r.step_physical(a)
        total += r.reward[0]
        _assert_apart(r)
    rel = lambda st: np.array([st[i, 0] - np.delete(st[:, 0], i).max() for i in range(3)])
    np.testing.assert_allclose(total, rel(r.state[0]) - rel(x0), atol=1e-9)
    assert r.contacts[0].min() > 0
