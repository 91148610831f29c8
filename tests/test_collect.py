"""Race data collection: schema, determinism across worker counts, resume after a kill."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("daqp")

from experiments.cli import main  # noqa: E402
from experiments.infra.parallel import Pool  # noqa: E402
from experiments.potential.collect import (
    CollectConfig,
    collect,
    load_races,
    rollout_from_state,  # noqa: E402
    simulate_shard,
    write_shard,
)

CFG = CollectConfig(races=4, n_cars=3, steps=15, seed=7, races_per_shard=2)


def test_collect_writes_shards_with_the_documented_schema(tmp_path):
    summary = collect(CFG, tmp_path, pool=Pool(workers=1, progress_bar=False))
    assert summary["simulated"] == 4
    data = load_races(tmp_path)
    assert data["states"].shape == (4, 16, 3, 6) and data["states"].dtype == np.float32
    assert data["thetas"].shape == (4, 3, 5) and data["rewards"].shape == (4, 15, 3)
    assert data["race_index"].tolist() == [0, 1, 2, 3]
    assert sorted(data["start_order"][0].tolist()) == [0, 1, 2]
    # rewards are the per-step change of s_i - max_{j != i} s_j of the stored states
    s = data["states"][..., 0].astype(float)
    lead = np.stack([np.delete(s, i, axis=2).max(axis=2) for i in range(3)], axis=2)
    np.testing.assert_allclose(data["rewards"], np.diff(s - lead, axis=1), atol=1e-4)
    from agents.reference import THETA_HIGH, THETA_LOW

    assert np.all(data["thetas"] >= THETA_LOW - 1e-6) and np.all(
        data["thetas"] <= THETA_HIGH + 1e-6
    )
    assert json.loads((tmp_path / "manifest.json").read_text())["config"]["seed"] == 7


def test_same_seed_same_data_with_any_worker_count(tmp_path):
    collect(CFG, tmp_path / "one", pool=Pool(workers=1, progress_bar=False))
    collect(CFG, tmp_path / "two", pool=Pool(workers=2, progress_bar=False))
    a, b = load_races(tmp_path / "one"), load_races(tmp_path / "two")
    for key in ("states", "thetas", "rewards", "start_order"):
        np.testing.assert_array_equal(a[key], b[key])


def test_a_killed_run_resumes_without_losing_finished_races(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    # a run killed after its first shard: that shard finished, the next one half written
    write_shard(simulate_shard(CFG, 0), 0, out)
    (out / "shard_00001.npz").write_bytes(b"truncated")
    summary = collect(CFG, out, pool=Pool(workers=1, progress_bar=False))
    assert summary["resumed"] == 2 and summary["simulated"] == 2
    assert load_races(out)["race_index"].tolist() == [0, 1, 2, 3]


def test_manifest_mismatch_is_refused(tmp_path):
    collect(CFG, tmp_path, pool=Pool(workers=1, progress_bar=False))
    with pytest.raises(ValueError, match="another configuration"):
        collect(
            CollectConfig(**{**CFG.__dict__, "seed": 8}),
            tmp_path,
            pool=Pool(workers=1, progress_bar=False),
        )


def test_collect_command(tmp_path, capsys):
    assert (
        main(
            [
                "collect",
                "--races",
                "2",
                "--steps",
                "5",
                "--shard-size",
                "1",
                "--workers",
                "1",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    assert "2 races simulated" in capsys.readouterr().out


@pytest.mark.slow
def test_ray_backend_gives_the_same_data_as_the_local_pool(tmp_path):
    pytest.importorskip("ray")
    collect(CFG, tmp_path / "local", pool=Pool(workers=1, progress_bar=False))
    collect(CFG, tmp_path / "ray", pool=Pool(workers=2, progress_bar=False, backend="ray"))
    a, b = load_races(tmp_path / "local"), load_races(tmp_path / "ray")
    for key in ("states", "thetas", "rewards", "start_order", "race_index"):
        np.testing.assert_array_equal(a[key], b[key])


def test_unknown_backend_is_refused(tmp_path):
    with pytest.raises(ValueError, match="backend must be 'local' or 'ray', got 'spark'"):
        collect(CFG, tmp_path, pool=Pool(backend="spark"))


def test_rollout_from_a_stored_state_continues_the_race(tmp_path):
    """Replaying a stored race from its step-5 state with the same thetas gives rewards of the
    same kind: finite, consistent with the states it returns (the MPCs restart cold, so not
    the identical trajectory)."""
    collect(
        CollectConfig(races=1, n_cars=3, steps=10, seed=3, races_per_shard=1),
        tmp_path,
        pool=Pool(workers=1, progress_bar=False),
    )
    d = load_races(tmp_path)
    states, rewards = rollout_from_state("default", d["states"][0, 5], d["thetas"][0], 8)
    assert states.shape == (9, 3, 6) and rewards.shape == (8, 3)
    np.testing.assert_allclose(states[0], d["states"][0, 5])
    s = states[..., 0]
    lead = np.stack([np.delete(s, i, axis=1).max(axis=1) for i in range(3)], axis=1)
    np.testing.assert_allclose(rewards, np.diff(s - lead, axis=0), atol=1e-9)
    assert np.all(np.diff(s, axis=0) > 0)  # every car keeps moving forward


def test_an_extended_close_collection_draws_six_parameters_and_starts_close(tmp_path):
    from agents.reference import EXTENDED_HIGH, EXTENDED_LOW

    cfg = CollectConfig(
        races=2, n_cars=3, steps=5, seed=7, races_per_shard=2, space="extended", start="close"
    )
    collect(cfg, tmp_path, pool=Pool(workers=1, progress_bar=False))
    data = load_races(tmp_path)
    th = data["thetas"]
    assert th.shape == (2, 3, 6)
    assert np.all(th >= EXTENDED_LOW - 1e-6) and np.all(th <= EXTENDED_HIGH + 1e-6)
    s0 = data["states"][:, 0, :, 0]
    assert np.ptp(s0, axis=1).max() <= 3 * 0.2 + 2 * 0.1 + 1e-6  # three 0.2 m regions, 0.1 m apart
    paper = load_races_of(
        CollectConfig(races=2, n_cars=3, steps=5, seed=7, races_per_shard=2), tmp_path / "paper"
    )
    assert np.ptp(paper["states"][:, 0, :, 0], axis=1).min() > 0.6  # the paper's 0.6 m gaps


def load_races_of(cfg, out):
    collect(cfg, out, pool=Pool(workers=1, progress_bar=False))
    return load_races(out)


def test_collect_config_names_bad_space_and_start():
    with pytest.raises(ValueError, match="policy space must be one of"):
        CollectConfig(space="wide")
    with pytest.raises(ValueError, match=r"start must be one of \['close', 'paper'\], got 'near'"):
        CollectConfig(start="near")
    with pytest.raises(
        ValueError,
        match=r"pace must be one of \['box', 'close', 'spread', 'overtake'\], got 'even'",
    ):
        CollectConfig(pace="even")


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), space=st.sampled_from(["paper", "extended"]))
def test_close_paces_keep_every_zeta_in_the_box_and_within_the_spread(seed, space):
    from agents.theta import policy_space
    from experiments.potential.collect import PACE_SPREAD, close_paces

    box = policy_space(space)
    rng = np.random.default_rng(seed)
    thetas = np.array([box.sample(rng) for _ in range(4)])
    out = close_paces(thetas, box, rng)
    z = box.names.index("zeta")
    assert np.all(out[:, z] >= box.low[z]) and np.all(out[:, z] <= box.high[z])
    assert np.ptp(out[:, z]) <= 2 * PACE_SPREAD
    others = [i for i in range(box.dim) if i != z]
    np.testing.assert_array_equal(out[:, others], thetas[:, others])  # only zeta changes


def test_a_close_pace_collection_differs_from_the_box_only_in_zeta(tmp_path):
    kw = dict(races=2, n_cars=3, steps=3, seed=5, races_per_shard=2, space="extended")
    box = load_races_of(CollectConfig(**kw), tmp_path / "box")
    close = load_races_of(CollectConfig(pace="close", **kw), tmp_path / "close")
    from agents.theta import policy_space
    from experiments.potential.collect import PACE_SPREAD

    z = policy_space("extended").names.index("zeta")
    assert np.ptp(close["thetas"][:, :, z], axis=1).max() <= 2 * PACE_SPREAD + 1e-6
    assert np.ptp(box["thetas"][:, :, z], axis=1).max() > 2 * PACE_SPREAD  # seed 5: a wide draw
    np.testing.assert_array_equal(np.delete(close["thetas"], z, 2), np.delete(box["thetas"], z, 2))
    np.testing.assert_array_equal(close["states"][:, 0], box["states"][:, 0])  # same starts


def test_an_overtake_collection_deals_the_spread_paces_slowest_first(tmp_path):
    """``pace="overtake"``: the zetas of ``"spread"`` (within 0.08 of the race's), dealt so
    that progress order at the start is the reverse of pace order (the slowest car in front);
    the other parameters are those of the same race's spread draw, dealt with their zeta."""
    from agents.theta import policy_space
    from experiments.potential.collect import PACE_SPREADS

    kw = dict(races=3, n_cars=3, steps=3, seed=5, races_per_shard=3, space="extended")
    kw["start"] = "close"
    spread = load_races_of(CollectConfig(pace="spread", **kw), tmp_path / "spread")
    over = load_races_of(CollectConfig(pace="overtake", **kw), tmp_path / "overtake")
    z = policy_space("extended").names.index("zeta")
    assert np.ptp(spread["thetas"][:, :, z], axis=1).max() <= 2 * PACE_SPREADS["spread"] + 1e-6
    np.testing.assert_array_equal(over["states"][:, 0], spread["states"][:, 0])  # same starts
    for r in range(3):
        front_to_back = np.argsort(-over["states"][r, 0, :, 0])
        assert np.all(np.diff(over["thetas"][r, front_to_back, z]) >= 0)
        # the same thetas as the spread race, only dealt to other cars
        key = lambda a: a[np.lexsort(a.T[::-1])]
        np.testing.assert_array_equal(key(over["thetas"][r]), key(spread["thetas"][r]))
