"""Strategy metrics from hand-built races: passes, contact, fall-backs, wins from behind."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from experiments.evaluation.metrics import (
    behind_time,
    hold_steps,
    pass_events,
    race_metrics,
    winner_and_front,
)

DT = 0.1


def race(s, n=None):
    """States (T + 1, N, 6) from s (T + 1, N) [m] and n (T + 1, N) [m] (default 0)."""
    s = np.asarray(s, dtype=float)
    out = np.zeros(s.shape + (6,))
    out[:, :, 0] = s
    if n is not None:
        out[:, :, 1] = np.broadcast_to(np.asarray(n, dtype=float), s.shape)
    return out


def steady(T, speeds, starts):
    t = np.arange(T + 1)[:, None] * DT
    return np.asarray(starts)[None, :] + np.asarray(speeds)[None, :] * t


# ---------------------------------------------------------------------------- passes
def test_a_clean_pass_is_credited_to_the_passer_at_the_interpolated_crossing():
    # car 0 starts 1 m behind car 1, 1 m/s faster: level at t = 1.0 s, beside it by 0.2 m
    s = steady(40, [4.0, 3.0], [0.0, 1.0])
    s[:, 0] += 0.01  # the crossing at t = 0.99 s: between steps 9 and 10
    m = race_metrics(race(s, [0.2, 0.0]), DT)
    assert m["passes"] == [1, 0] and m["passes_contact"] == [0, 0]
    (e,) = m["pass_events"]
    assert (e["passer"], e["passed"], e["step"], e["kind"]) == (0, 1, 10, "pass")
    assert e["time_s"] == pytest.approx(0.99, abs=1e-9)
    assert e["dn_m"] == pytest.approx(0.2)
    assert m["winner"] == 0 and m["front"] == 1 and m["won_from_behind"]


def test_a_crossing_lost_within_one_second_is_no_pass_nor_is_regaining_the_place():
    T = 60
    s = np.zeros((T + 1, 2))
    s[:, 1] = 3.0 * np.arange(T + 1) * DT
    gap = np.full(T + 1, -0.5)  # car 0 0.5 m behind ...
    gap[20:25] = 0.1  # ... ahead for 5 steps (0.5 s), then behind again
    s[:, 0] = s[:, 1] + gap
    m = race_metrics(race(s, [0.3, 0.0]), DT)
    assert m["passes"] == [0, 0] and m["passes_contact"] == [0, 0]
    assert m["fell_back"] == [1, 0]  # car 0's failed attempt, once
    assert [e["kind"] for e in m["pass_events"]] == ["fell_back"]
    assert not m["won_from_behind"]


def test_a_pass_that_holds_exactly_the_hold_counts_and_one_step_less_does_not():
    hold = hold_steps(DT)
    assert hold == 10
    gap = np.full(50, -0.5)
    gap[20 : 20 + hold] = 0.2  # car 0 ahead for 10 states, then behind for good
    s = np.column_stack([gap, np.zeros(50)])
    e = pass_events(race(s, [0.5, 0.0]), DT)
    assert [(x.kind, x.passer, x.step) for x in e] == [("pass", 0, 20), ("pass", 1, 30)]
    gap[20 + hold - 1] = -0.5  # ahead for 9 states: a failed attempt only
    s = np.column_stack([gap, np.zeros(50)])
    e = pass_events(race(s, [0.5, 0.0]), DT)
    assert [(x.kind, x.passer, x.step) for x in e] == [("fell_back", 0, 20)]


def test_a_crossing_in_the_last_second_does_not_count():
    gap = np.full(30, -0.5)
    gap[22:] = 0.2  # ahead in the last 8 states: unconfirmed
    s = np.column_stack([gap, np.zeros(30)])
    m = race_metrics(race(s, [0.5, 0.0]), DT)
    assert m["passes"] == [0, 0] and m["passes_race_end"] == [1, 0]
    assert m["won_from_behind"]  # it still won: progress decides the race


def test_a_crossing_with_lateral_overlap_is_a_pass_through_contact():
    s = steady(40, [4.0, 3.0], [0.0, 1.05])
    n = np.zeros((41, 2))
    n[:, 0] = 0.03  # 3 cm apart sideways: the bodies (6 cm) overlap
    m = race_metrics(race(s, n), DT, contact_dn=0.06)
    assert m["passes"] == [0, 0] and m["passes_contact"] == [1, 0]
    assert m["pass_events"][0]["kind"] == "contact"
    # the same with the cars a body width apart at the crossing: a clean pass
    n[:, 0] = 0.06
    assert race_metrics(race(s, n), DT, contact_dn=0.06)["passes"] == [1, 0]


def test_the_lateral_gap_is_interpolated_at_the_crossing():
    # crossing exactly half way between steps 10 and 11; n gap 0.02 m before, 0.12 m after:
    # 0.07 m at the crossing (clean), though one of the two steps overlaps
    gap = np.concatenate([np.full(11, -0.1), np.full(20, 0.1)])
    dn = np.concatenate([np.full(11, 0.02), np.full(20, 0.12)])
    s = np.column_stack([gap, np.zeros(31)])
    n = np.column_stack([dn, np.zeros(31)])
    (e,) = pass_events(race(s, n), DT, contact_dn=0.06)
    assert e.kind == "pass" and e.dn_m == pytest.approx(0.07) and e.time_s == pytest.approx(1.05)
    (e,) = pass_events(race(s, n), DT, contact_dn=0.08)
    assert e.kind == "contact"


def test_side_by_side_cars_never_pass_and_level_steps_are_no_change_of_order():
    s = steady(50, [3.0, 3.0], [0.0, 0.0])  # level all race
    m = race_metrics(race(s, [0.1, -0.1]), DT)
    assert m["pass_events"] == [] and m["behind_1m_s"] == [0.0, 0.0]
    assert m["winner"] == 0 and m["front"] == 0 and not m["won_from_behind"]
    # behind, level for 5 steps, behind again: no crossing
    gap = np.full(40, -0.3)
    gap[10:15] = 0.0
    assert pass_events(race(np.column_stack([gap, np.zeros(40)])), DT) == []
    # behind, level for 5 steps, then ahead for good: one pass at the first step ahead, its
    # time interpolated between the last step behind (0.9 s, -0.3 m) and it (1.5 s, +0.3 m)
    gap[15:] = 0.3
    (e,) = pass_events(race(np.column_stack([gap, np.zeros(40)]), [[0.2, 0.0]]), DT)
    assert e.kind == "pass" and e.step == 15 and e.time_s == pytest.approx(1.2)


def test_four_cars_a_car_passing_the_whole_field():
    # car 3 starts last and is faster than everybody; the others keep their order
    s = steady(100, [3.0, 3.0, 3.0, 3.6], [2.9, 2.0, 1.1, 0.0])
    n = np.array([0.0, 0.0, 0.0, 0.2])
    m = race_metrics(race(s, n), DT)
    assert m["passes"] == [0, 0, 0, 3] and m["passes_contact"] == [0] * 4
    assert [e["passed"] for e in m["pass_events"]] == [2, 1, 0]
    assert [e["time_s"] for e in m["pass_events"]] == pytest.approx(
        [1.1 / 0.6, 2 / 0.6, 2.9 / 0.6], abs=1e-4
    )
    assert m["winner"] == 3 and m["front"] == 0 and m["won_from_behind"]
    # car 1 is 0.9 m behind car 0 all race (close behind), car 2 likewise behind car 1
    assert m["behind_1m_s"][1] == pytest.approx(10.0) and m["behind_1m_s"][2] == pytest.approx(10.0)
    assert m["behind_1m_s"][0] < 10.0  # only while car 3 is close ahead of it


def test_time_within_one_metre_behind_counts_steps_after_each_control_period():
    s = np.column_stack([np.zeros(21), np.full(21, 1.5)])
    s[5:15, 0] = 0.6  # 0.9 m behind car 1 in states 5..14: 1.0 s
    np.testing.assert_allclose(behind_time(race(s), DT), [1.0, 0.0])
    s[0, 0] = 1.0  # state 0 is the start, not a period: not counted
    np.testing.assert_allclose(behind_time(race(s), DT), [1.0, 0.0])


def test_winner_and_front_ties_go_to_the_lower_index():
    s = np.array([[1.0, 1.0, 0.0], [5.0, 5.0, 5.0]])
    assert winner_and_front(race(s)) == (0, 0)


def test_bad_input_is_refused_with_the_value():
    with pytest.raises(ValueError, match=r"shape \(T \+ 1, N, 6\).*\(5, 6\)"):
        race_metrics(np.zeros((5, 6)))
    bad = race(np.zeros((5, 2)))
    bad[2, 1, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        race_metrics(bad)
    with pytest.raises(ValueError, match="contact_dn must be a positive number, got -1"):
        race_metrics(race(np.zeros((5, 2))), contact_dn=-1)
    with pytest.raises(ValueError, match="dt must be a positive number, got 0"):
        race_metrics(race(np.zeros((5, 2))), dt=0)


# ---------------------------------------------------------------------------- properties
def random_race(data, n_cars):
    T = data.draw(st.integers(1, 60))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**31)))
    speed = rng.uniform(2.0, 4.0, (T, n_cars))
    speed[rng.random((T, n_cars)) < 0.1] = 0.0  # stops make exact ties
    s = np.vstack([rng.uniform(0, 2, n_cars).round(1), np.zeros((T, n_cars))])
    s[1:] = s[0] + np.cumsum(speed * DT, axis=0).round(2)
    n = rng.uniform(-0.2, 0.2, (T + 1, n_cars)).round(2)
    return race(s, n)


@settings(max_examples=150, deadline=None)
@given(data=st.data(), n_cars=st.integers(2, 5))
def test_renumbering_the_cars_renumbers_the_metrics(data, n_cars):
    states = random_race(data, n_cars)
    perm = np.random.default_rng(data.draw(st.integers(0, 1000))).permutation(n_cars)
    a, b = race_metrics(states, DT), race_metrics(states[:, perm], DT)  # b's car k = a's perm[k]
    for key in ("passes", "passes_contact", "fell_back", "passes_race_end", "behind_1m_s"):
        assert b[key] == [a[key][p] for p in perm], key
    ev = lambda m, names: sorted(
        (e["step"], names[e["passer"]], names[e["passed"]], e["kind"]) for e in m["pass_events"]
    )
    assert ev(b, perm) == ev(a, range(n_cars))
    s0, sT = states[0, :, 0], states[-1, :, 0]
    if len(set(s0)) == n_cars and len(set(sT)) == n_cars:  # no ties: indices irrelevant
        assert b["won_from_behind"] == a["won_from_behind"]


@settings(max_examples=150, deadline=None)
@given(data=st.data(), n_cars=st.integers(2, 4))
def test_passes_of_a_pair_alternate_and_net_to_its_change_of_order(data, n_cars):
    """Per pair, the counted passes (clean or through contact) change the established order,
    so they alternate in direction; their net count is the change of order between the start
    and the end whenever the last crossing held to the end for at least the hold time."""
    states = random_race(data, n_cars)
    events = pass_events(states, DT)
    s = states[:, :, 0]
    T = len(s) - 1
    for i in range(n_cars):
        for j in range(i + 1, n_cars):
            counted = [
                e
                for e in events
                if {e.passer, e.passed} == {i, j} and e.kind in ("pass", "contact")
            ]
            dirs = [1 if e.passer == i else -1 for e in counted]
            assert all(a != b for a, b in zip(dirs, dirs[1:]))
            d = s[:, i] - s[:, j]
            nz = np.flatnonzero(d)
            if not nz.size:
                assert not counted
                continue
            start, end = np.sign(d[nz[0]]), np.sign(d[nz[-1]])
            # the last step at which the order was the other one, then the first in the end's
            other = np.flatnonzero(np.sign(d) == -end)
            settled = not other.size or T + 1 - nz[nz > other[-1]][0] >= hold_steps(DT)
            if settled:
                assert sum(dirs) == (end - start) / 2


def test_metrics_of_a_real_race_are_consistent_with_its_result():
    from experiments.evaluation.race import run_race

    result, _ = run_race(
        ["mpc:zeta=1.0", "raceline", "raceline"],
        track="default",
        seed=4,
        max_cycles=60,
        order=[2, 0, 1],
        progress_bar=False,
    )
    m = result.metrics
    assert m["winner"] == int(result.order[0]) and m["front"] == 1
    summary = result.summary()
    assert summary["metrics"]["passes"] == m["passes"]
    assert "passes" in result.table()
