"""The track-general, field-size-general alpha-potential: features, family collection,
training on it, racing any N, the held-out report; and the single-track path unchanged."""

import importlib.util
import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents import general_features as gf
from agents.feature_sets import feature_set
from agents.features import scale_theta
from agents.reference import THETA_HIGH, THETA_LOW
from experiments.infra.parallel import Pool
from experiments.potential.family import (
    FamilyConfig,
    collect_family,
    expand_tracks,
    load_family,
    parse_cars,
    simulate_family_shard,
)
from racing_env import make_track

TRACK = make_track("default")
needs_mpc = pytest.mark.skipif(
    importlib.util.find_spec("daqp") is None, reason="the MPC agents need daqp"
)


# ---------------------------------------------------------------------------- features
@st.composite
def fields(draw):
    """A field of 2..8 cars with many ties (shared s, n, thetas), a permutation and an ego."""
    n = draw(st.integers(2, gf.N_MAX))
    tie_or = lambda values, lo, hi: st.one_of(
        st.sampled_from(values), st.floats(lo, hi, allow_nan=False)
    )
    x = np.zeros((n, 6))
    th = np.zeros((n, 5))
    shared = [np.array([50.0, 0.9, 0.1, 5.0, 1.0]), np.array([300.0, 1.0, 0.2, 12.0, 4.0])]
    for k in range(n):
        x[k] = [
            draw(tie_or([10.0, 12.5], 0.0, 80.0)),
            draw(tie_or([0.0, 0.1], -0.2, 0.2)),
            draw(tie_or([0.0], -0.3, 0.3)),
            draw(tie_or([2.0], 0.0, 3.5)),
            draw(tie_or([0.0], -0.2, 0.2)),
            draw(tie_or([0.0], -1.0, 1.0)),
        ]
        if draw(st.booleans()):
            th[k] = shared[draw(st.integers(0, 1))]
        else:
            th[k] = [draw(st.floats(lo, hi)) for lo, hi in zip(THETA_LOW, THETA_HIGH)]
    perm = np.array(draw(st.permutations(range(n))))
    return x, th, perm, draw(st.integers(0, n - 1))


@settings(max_examples=150, deadline=None)
@given(field=fields())
def test_general_features_are_exactly_invariant_to_reordering_of_the_cars(field):
    """Any reordering of the cars (following the ego) gives the same features bit for bit,
    ties in progress and in the rest of the state included."""
    x, th, perm, ego = field
    np.testing.assert_array_equal(
        gf.potential_features(x[perm], th[perm], TRACK), gf.potential_features(x, th, TRACK)
    )
    np.testing.assert_array_equal(
        gf.value_features(x[perm], th[perm], TRACK, int(np.argsort(perm)[ego])),
        gf.value_features(x, th, TRACK, ego),
    )
    assert gf.value_features(x, th, TRACK, ego).shape == (gf.VALUE_DIM,)
    assert gf.potential_features(x, th, TRACK).shape == (gf.POTENTIAL_DIM,)


def _field(rng, n):
    x = np.zeros((n, 6))
    x[:, 0] = rng.uniform(0, 30, n)
    x[:, 1] = rng.uniform(-0.2, 0.2, n)
    x[:, 3] = rng.uniform(0.5, 3.0, n)
    return x, rng.uniform(THETA_LOW, THETA_HIGH, (n, 5))


def test_padding_marks_the_field_and_leaves_empty_slots_zero():
    rng = np.random.default_rng(0)
    for n in range(2, gf.N_MAX + 1):
        x, th = _field(rng, n)
        p = gf.potential_features(x, th, TRACK).reshape(gf.N_MAX, gf.SLOT_DIM)
        assert p[:, 0].tolist() == [1.0] * n + [0.0] * (gf.N_MAX - n)  # presence
        assert not p[n:].any()
        order = np.argsort(-x[:, 0])
        np.testing.assert_array_equal(p[:n, 1], x[order, 0] - x[order, 0].mean())
        # the theta slots hold the scaled thetas in progress order (the ascent's columns)
        flat = p.ravel()
        np.testing.assert_allclose(flat[gf.potential_theta_slots(n)], scale_theta(th[order]))
        v = gf.value_features(x, th, TRACK, 0)[gf.EGO_DIM :].reshape(gf.N_MAX - 1, gf.OTHER_DIM)
        assert v[:, 0].tolist() == [1.0] * (n - 1) + [0.0] * (gf.N_MAX - n)
        assert not v[n - 1 :].any()


def test_a_car_added_behind_the_field_changes_only_its_own_slot_and_the_pack_mean():
    """A 2-car field and the same field with a third car far behind: the ego's block and its
    first neighbour's slot are the same; the potential's slots differ only in the progress
    relative to the field's mean and in the new car's slot."""
    rng = np.random.default_rng(1)
    x2, th2 = _field(rng, 2)
    x3 = np.vstack([x2, [x2[:, 0].min() - 5.0, 0.05, 0.0, 1.5, 0.0, 0.0]])
    th3 = np.vstack([th2, rng.uniform(THETA_LOW, THETA_HIGH, 5)])
    leader = int(np.argmax(x2[:, 0]))
    v2, v3 = gf.value_features(x2, th2, TRACK, leader), gf.value_features(x3, th3, TRACK, leader)
    k = gf.EGO_DIM + gf.OTHER_DIM
    np.testing.assert_array_equal(v2[:k], v3[:k])
    assert not v2[k:].any() and v3[k] == 1.0
    p2 = gf.potential_features(x2, th2, TRACK).reshape(gf.N_MAX, gf.SLOT_DIM)
    p3 = gf.potential_features(x3, th3, TRACK).reshape(gf.N_MAX, gf.SLOT_DIM)
    same = np.r_[0, 2 : gf.SLOT_DIM]
    np.testing.assert_array_equal(p2[:2][:, same], p3[:2][:, same])
    assert not p2[2].any() and p3[2, 0] == 1.0


def test_local_track_matches_the_tracks_own_lookups_for_a_mix_of_tracks():
    names = ["default", "oval", "random:3"]
    ts = gf.TrackSet(names)
    rng = np.random.default_rng(2)
    s = rng.uniform(-60, 120, 200)
    ids = rng.integers(0, 3, 200)
    got = gf.local_track(ts, s, ids)
    for k, name in enumerate(names):
        t = make_track(name)
        m = ids == k
        kappa = t.interp(t.kappa, s[m, None] + gf.PREVIEW)
        wl, wr = t.widths(s[m])
        np.testing.assert_array_equal(got[m], np.column_stack([kappa, wl, wr]))
    # features of a mix of tracks are those of each track on its own
    x, th = _field(rng, 3)
    X = np.repeat(x[None], 3, 0)
    TH = np.repeat(th[None], 3, 0)
    mixed = gf.potential_features(X, TH, ts, track_id=np.arange(3))
    for k, name in enumerate(names):
        np.testing.assert_array_equal(mixed[k], gf.potential_features(x, th, name))


def test_a_track_named_otherwise_than_its_spec_is_rebuilt_from_its_spec(tmp_path):
    """A TUMFTM circuit ('tumftm:Spa' is named 'Spa') or a CSV track (named by its stem): the
    training data, the rollouts and the model's list of training tracks use the spec."""
    from experiments.potential.family import RaceGroup
    from experiments.potential.train_general import FamilyData

    a = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    csv = tmp_path / "ring.csv"
    rows = np.column_stack(
        [12 * np.cos(a), 8 * np.sin(a), np.full_like(a, 0.3), np.full_like(a, 0.3)]
    )
    np.savetxt(csv, rows, delimiter=",", header="x_m,y_m,w_tr_right_m,w_tr_left_m")
    ts = gf.TrackSet([str(csv), "oval"])
    assert ts.names == ["ring", "oval"] and ts.specs == [str(csv), "oval"]
    z = np.zeros
    groups = [
        RaceGroup(str(csv), 2, z((1, 3, 2, 6)), z((1, 2, 5)), z((1, 2, 2)), np.arange(1)),
        RaceGroup("oval", 2, z((1, 3, 2, 6)), z((1, 2, 5)), z((1, 2, 2)), np.arange(1, 2)),
    ]
    data = FamilyData(groups)
    assert [data.track_spec(r) for r in (0, 1)] == [str(csv), "oval"]
    assert make_track(data.track_spec(0)).length == pytest.approx(make_track(str(csv)).length)


def test_bad_general_feature_input_names_the_value():
    x, th = _field(np.random.default_rng(3), 9)
    with pytest.raises(ValueError, match="take 2..8 cars, got 9"):
        gf.potential_features(x, th, TRACK)
    with pytest.raises(ValueError, match="take 2..8 cars, got 1"):
        gf.value_features(x[:1], th[:1], TRACK, 0)
    with pytest.raises(ValueError, match="ego must be in 0..2, got 3..3"):
        gf.value_features(x[:3], th[:3], TRACK, 3)
    with pytest.raises(ValueError, match="needs track_id"):
        gf.potential_features(x[:3], th[:3], gf.TrackSet(["default", "oval"]))
    with pytest.raises(ValueError, match="track_id must be in 0..1, got 0..2"):
        gf.potential_features(
            np.repeat(x[None, :3], 3, 0),
            np.repeat(th[None, :3], 3, 0),
            gf.TrackSet(["default", "oval"]),
            track_id=[0, 1, 2],
        )
    with pytest.raises(ValueError, match="unknown feature set 'nope'"):
        feature_set("nope")


# ---------------------------------------------------------------------------- single track
#: The shipped models at one joint state: V_i for each car, Phi, and the warm-started
#: maximisation's Phi and theta. Pinned once the general features existed, so that the `fixed`
#: feature set keeps giving these values; re-pinned when the models are retrained (last: on
#: the 4000 races of the MPC whose plans follow their own progress and iterate to convergence).
_X = np.array(
    [
        [12.0, 0.05, 0.02, 2.1, 0.01, 0.1],
        [12.6, -0.08, -0.03, 2.3, -0.02, -0.2],
        [11.2, 0.12, 0.0, 1.9, 0.0, 0.05],
    ]
)
_TH = np.array(
    [[50.0, 0.95, 0.1, 5.0, 1.0], [200.0, 0.85, 0.25, 12.0, 3.0], [10.0, 1.02, 0.05, 1.0, 0.5]]
)
_BEFORE = {
    "default": (
        [0.16839522716655908, -4.405164011712084, 0.7717789664112605],
        -1.710451204749603,
        5.300439784261073,
        [
            [13.170837, 1.027829, 0.240672, 12.493231, 0.0],
            [5.0, 1.037214, 0.3, 20.0, 0.0],
            [5.0, 1.022991, 0.3, 7.31694, 0.0],
        ],
    ),
    "gamma0.98": (
        [0.5190301529330071, -1.7564525918005214, 0.4781909482964457],
        -0.2979956591933153,
        2.709401296814164,
        [
            [13.632359, 1.017526, 0.12767, 11.533681, 0.0],
            [5.0, 1.038767, 0.254398, 5.60346, 0.0],
            [5.0, 1.016015, 0.228027, 10.198743, 0.0],
        ],
    ),
    "gamma0.995": (
        [-0.8773328968722527, -8.268218977618725, 1.6381018546077508],
        -2.6157262362526126,
        11.531698017884992,
        [
            [36.997313, 1.032959, 0.232951, 5.734792, 0.0],
            [5.0, 1.04035, 0.243239, 9.361048, 0.0],
            [5.0, 1.021922, 0.3, 15.875588, 0.829155],
        ],
    ),
    "races400": (
        [-1.1512252007589556, -4.401455000919139, 0.6743199559792878],
        -0.18465572936490204,
        7.262699837390528,
        [
            [277.325297, 1.034727, 0.250315, 20.0, 3.298706],
            [5.0, 1.05, 0.283824, 5.695956, 4.958773],
            [5.0, 1.022082, 0.3, 0.5, 4.736143],
        ],
    ),
}


@pytest.mark.parametrize("name", sorted(_BEFORE))
def test_shipped_single_track_models_give_the_values_they_gave_before(name):
    from agents.potential import load_model

    m = load_model(name)
    assert not m.general and m.features.name == "fixed" and m.n_cars == 3
    v, phi, phi_max, theta = _BEFORE[name]
    got_v = m.value(np.repeat(_X[None], 3, 0), np.repeat(_TH[None], 3, 0), TRACK, np.arange(3))
    np.testing.assert_allclose(got_v, v, rtol=1e-5, atol=1e-5)
    assert m.potential(_X[None], _TH[None], TRACK)[0] == pytest.approx(phi, rel=1e-5, abs=1e-5)
    th, p = m.maximise(
        _X, TRACK, theta0=_TH, restarts=4, iterations=3, rng=np.random.default_rng(0)
    )
    assert p == pytest.approx(phi_max, rel=1e-5, abs=1e-5)
    np.testing.assert_allclose(th, theta, rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="trained for 3 cars, got states of 4"):
        m.potential(np.zeros((1, 4, 6)), np.zeros((1, 4, 5)), TRACK)


# ---------------------------------------------------------------------------- collection
def test_track_and_field_specs():
    assert expand_tracks(["default", "random:3-5"]) == [
        "default",
        "random:3",
        "random:4",
        "random:5",
    ]
    assert parse_cars("2-4") == (2, 3, 4) and parse_cars("5,2") == (2, 5) and parse_cars(3) == (3,)
    with pytest.raises(ValueError, match=r"cars '1-9': every field size must be in 2..8, got 1, 9"):
        parse_cars("1-9")
    with pytest.raises(ValueError, match="expected a number, a range A-B or a list"):
        parse_cars("two")
    with pytest.raises(ValueError, match="random:A-B with integer seeds"):
        expand_tracks(["random:9-3"])
    with pytest.raises(ValueError, match="'random:4' is listed twice"):
        expand_tracks(["random:3-5", "random:4"])


def test_shards_are_dealt_evenly_over_tracks_and_field_sizes_from_the_seed():
    cfg = FamilyConfig(
        races=200, tracks=("default", "oval", "random:0-4"), cars=(2, 3, 4, 5, 6), races_per_shard=2
    )
    a = cfg.assignments()
    assert len(a) == 100 and a == FamilyConfig(**{**cfg.__dict__}).assignments()
    tracks = [t for t, _ in a]
    counts = [tracks.count(t) for t in cfg.track_list]
    assert max(counts) - min(counts) <= 1 and sum(counts) == 100
    assert [n for _, n in a].count(2) == 20 and {n for _, n in a} == {2, 3, 4, 5, 6}
    other = FamilyConfig(**{**cfg.__dict__, "seed": 1}).assignments()
    assert other != a
    # a shard's assignment depends on its index, not on how many shards follow it
    assert FamilyConfig(**{**cfg.__dict__, "races": 20}).assignments() == a[:10]


TINY_FAMILY = FamilyConfig(
    races=4, tracks=("default", "random:3"), cars=(2, 3), steps=10, races_per_shard=1
)


@needs_mpc
def test_family_collection_is_the_same_with_1_and_2_workers_and_records_each_shard(tmp_path):
    collect_family(TINY_FAMILY, tmp_path / "one", pool=Pool(workers=1, progress_bar=False))
    collect_family(TINY_FAMILY, tmp_path / "two", pool=Pool(workers=2, progress_bar=False))
    m1 = json.loads((tmp_path / "one" / "manifest.json").read_text())
    assert m1 == json.loads((tmp_path / "two" / "manifest.json").read_text())
    assert m1["schema_version"] == 2 and m1["kind"] == "family" and len(m1["shards"]) == 4
    for entry in m1["shards"]:
        k = entry["shard"]
        with (
            np.load(tmp_path / "one" / f"shard_{k:05d}.npz") as a,
            np.load(tmp_path / "two" / f"shard_{k:05d}.npz") as b,
        ):
            assert a.files == b.files
            for key in a.files:
                assert a[key].tobytes() == b[key].tobytes(), key
            assert str(a["track"]) == entry["track"] and int(a["n_cars"]) == entry["n_cars"]
            assert a["states"].shape == (1, 11, entry["n_cars"], 6)
    groups, _ = load_family(tmp_path / "one")
    assert sum(len(g.states) for g in groups) == 4
    assert sorted(int(i) for g in groups for i in g.race_index) == [0, 1, 2, 3]


@needs_mpc
@pytest.mark.slow
def test_ray_backend_gives_the_same_family_data_as_the_local_pool(tmp_path):
    pytest.importorskip("ray")
    collect_family(TINY_FAMILY, tmp_path / "local", pool=Pool(workers=1, progress_bar=False))
    collect_family(
        TINY_FAMILY, tmp_path / "ray", pool=Pool(workers=2, progress_bar=False, backend="ray")
    )
    for k in range(TINY_FAMILY.n_shards):
        with (
            np.load(tmp_path / "local" / f"shard_{k:05d}.npz") as a,
            np.load(tmp_path / "ray" / f"shard_{k:05d}.npz") as b,
        ):
            for key in a.files:
                assert a[key].tobytes() == b[key].tobytes(), key


@needs_mpc
def test_a_family_race_is_the_single_track_race_of_the_same_seed_and_index():
    from experiments.potential.collect import CollectConfig, simulate_race

    shard = simulate_family_shard(TINY_FAMILY, 2)
    track, n = TINY_FAMILY.assignment(2)
    single = simulate_race(CollectConfig(races=4, n_cars=n, steps=10, track=track, seed=0), 2)
    assert shard["states"][0].tobytes() == single["states"].tobytes()
    assert shard["thetas"][0].tobytes() == single["thetas"].tobytes()


@needs_mpc
def test_an_extended_close_family_race_is_the_single_track_race_and_the_paper_manifest_keeps_its_keys():
    from dataclasses import replace

    from experiments.potential.collect import CollectConfig, simulate_race

    # the paper's family records no new keys, so folders written before space/start/pace resume
    assert {"space", "start", "pace"}.isdisjoint(TINY_FAMILY.manifest()["config"])
    ext = replace(TINY_FAMILY, space="extended", start="close", pace="close")
    assert ext.manifest()["config"]["space"] == "extended"
    shard = simulate_family_shard(ext, 1)
    track, n = ext.assignment(1)
    single = simulate_race(
        CollectConfig(
            races=4, n_cars=n, steps=10, track=track, space="extended", start="close", pace="close"
        ),
        1,
    )
    assert shard["thetas"].shape == (1, n, 6)
    assert shard["states"][0].tobytes() == single["states"].tobytes()
    assert shard["thetas"][0].tobytes() == single["thetas"].tobytes()
    with pytest.raises(ValueError, match="start must be one of"):
        replace(TINY_FAMILY, start="far")


@needs_mpc
def test_a_killed_family_collection_resumes_and_a_bad_track_fails_before_any_race(tmp_path):
    from experiments.infra.artifacts import write_npz

    out = tmp_path / "run"
    out.mkdir()
    write_npz(out / "shard_00000.npz", schema_version=2, **simulate_family_shard(TINY_FAMILY, 0))
    (out / "shard_00001.npz").write_bytes(b"truncated")
    s = collect_family(TINY_FAMILY, out, pool=Pool(workers=1, progress_bar=False))
    assert s["resumed"] == 1 and s["simulated"] == 3
    assert sum(len(g.states) for g in load_family(out)[0]) == 4
    (out / "shard_00003.npz").unlink()  # training refuses an unfinished collection
    with pytest.raises(
        ValueError, match="1 of 4 shards missing .*run the same alpha-racer collect"
    ):
        load_family(out)
    bad = FamilyConfig(races=2, tracks=("default", "nosuch"), cars=(2,), steps=5)
    with pytest.raises(ValueError, match="track spec 'nosuch'"):
        collect_family(bad, tmp_path / "bad", pool=Pool(workers=1, progress_bar=False))
    assert not (tmp_path / "bad").exists()


@needs_mpc
def test_a_single_track_collection_keeps_its_schema_and_loads_as_one_group(tmp_path):
    from experiments.cli import main

    assert (
        main(
            [
                "collect",
                "--races",
                "2",
                "--steps",
                "5",
                "--cars",
                "3",
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
    meta = json.loads((tmp_path / "manifest.json").read_text())
    assert set(meta) == {"schema_version", "config", "provenance"} and meta["schema_version"] == 1
    assert set(meta["config"]) == {
        "races",
        "n_cars",
        "steps",
        "track",
        "seed",
        "races_per_shard",
        "start_jitter",
    }
    with np.load(tmp_path / "shard_00000.npz") as z:
        assert set(z.files) == {
            "schema_version",
            "states",
            "thetas",
            "rewards",
            "race_index",
            "start_order",
            "fallbacks",
        }
    groups, _ = load_family(tmp_path)
    assert [(g.track, g.n_cars, len(g.states)) for g in groups] == [("default", 3, 2)]


# ---------------------------------------------------------------------------- training
TRAIN_ARGS = [
    "--value-epochs",
    "2",
    "--potential-steps",
    "60",
    "--potential-batch",
    "256",
    "--value-hidden",
    "16",
    "16",
    "--potential-hidden",
    "32",
    "32",
    "--val-fraction",
    "0.25",
    "--threads",
    "1",
]


@pytest.fixture(scope="module")
def general_model(tmp_path_factory):
    """A tiny general model: 8 races of 40 steps on default and random:3 with 2 and 3 cars."""
    pytest.importorskip("daqp")
    pytest.importorskip("torch")
    from experiments.cli import main

    root = tmp_path_factory.mktemp("general")
    assert (
        main(
            [
                "collect",
                "--tracks",
                "default",
                "random:3",
                "--cars",
                "2-3",
                "--races",
                "8",
                "--steps",
                "40",
                "--shard-size",
                "2",
                "--workers",
                "1",
                "--out",
                str(root / "data"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "train",
                "--data",
                str(root / "data"),
                "--out",
                str(root / "model"),
                "--rollout-pairs",
                "1",
                "--rollout-steps",
                "5",
            ]
            + TRAIN_ARGS
        )
        == 0
    )
    return root


def test_training_on_a_family_gives_a_general_model_with_per_field_validation(general_model):
    from agents.potential import load_model

    model = load_model(general_model / "model" / "model.npz")
    meta = model.meta
    assert model.general and meta["feature_set"] == "general" and meta["n_cars_range"] == [2, 3]
    assert sorted(meta["tracks"]) == ["default", "random:3"] and meta["data"]["races"] == 8
    assert meta["config"]["potential_batch"] == 256 and meta["config"]["potential_steps"] == 60
    m = json.loads((general_model / "model" / "metrics.json").read_text())
    assert set(m["by_cars"]) == {"2", "3"} and m["value_range"] > 0
    for s in list(m["by_cars"].values()) + [m]:
        assert 0 <= s["gap_rel_median"] <= s["gap_rel_p95"] <= s["gap_rel_max"] < np.inf
    assert np.isfinite(m["rollout_phi_rel_median"])
    assert "| 2 |" in (general_model / "model" / "model_card.md").read_text()
    # any field of 2..8 cars: finite values, thetas within the box
    rng = np.random.default_rng(0)
    for n in (2, 5, 8):
        x, th = _field(rng, n)
        assert np.isfinite(model.value(x[None], th[None], "oval", np.array([0]))).all()
        theta, phi = model.maximise(x, make_track("oval"), restarts=3, iterations=2)
        assert theta.shape == (n, 5) and np.isfinite(phi)
        assert np.all(theta >= THETA_LOW - 1e-9) and np.all(theta <= THETA_HIGH + 1e-9)
    with pytest.raises(ValueError, match="takes 2..8 cars, got states of 9"):
        model.potential(np.zeros((1, 9, 6)), np.zeros((1, 9, 5)), TRACK)


def test_the_same_family_data_and_config_give_the_same_general_model(general_model, tmp_path):
    from experiments.cli import main

    assert (
        main(
            [
                "train",
                "--data",
                str(general_model / "data"),
                "--out",
                str(tmp_path),
                "--rollout-pairs",
                "0",
            ]
            + TRAIN_ARGS
        )
        == 0
    )
    with np.load(general_model / "model" / "model.npz") as a, np.load(tmp_path / "model.npz") as b:
        for key in a.files:
            if key != "meta":
                assert a[key].tobytes() == b[key].tobytes(), key


@pytest.mark.parametrize("agents,track", [(2, "random:10000"), (4, "default")])
def test_a_general_model_races_any_field_size(general_model, agents, track):
    from experiments.evaluation.race import run_race

    spec = f"alpha:model={general_model / 'model' / 'model.npz'}"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result, _ = run_race(
            [spec] + ["mpc"] * (agents - 1), track=track, max_cycles=25, progress_bar=False
        )
    assert np.isfinite(result.states).all() and np.isfinite(result.progress).all()
    st0 = result.agent_stats[0]
    assert np.isfinite(st0["potential"]) and st0["solves"] == 25
    outside = [w for w in caught if "trained on fields of 2..3 cars" in str(w.message)]
    assert bool(outside) == (agents == 4)


@needs_mpc
def test_model_general_is_refused_with_how_to_train_it_when_missing(monkeypatch, tmp_path):
    import agents.potential as potential
    from agents import make_agent_spec

    monkeypatch.setattr(potential, "MODEL_DIR", tmp_path)
    monkeypatch.setattr(potential, "_LOADED", {})
    with pytest.raises(ValueError, match=r"'general' is missing .*alpha-racer collect --tracks"):
        make_agent_spec("alpha:model=general")


# ---------------------------------------------------------------------------- the report
@pytest.mark.slow
def test_the_report_measures_on_held_out_tracks_and_resumes(general_model, tmp_path, monkeypatch):
    from agents.best_theta import TABLE_ENV_VAR, lookup
    from experiments.analysis.general import (
        GeneralReportConfig,
        default_heldout_tracks,
        general_report,
    )

    monkeypatch.setenv(TABLE_ENV_VAR, str(tmp_path / "best_fixed_theta.json"))  # empty table
    path = str(general_model / "model" / "model.npz")
    cfg = GeneralReportConfig(
        model=path,
        tracks=("random:10000",),
        gap_cars=(2, 3),
        gap_races=1,
        gap_pairs=300,
        bench_cars=(2,),
        default_races=3,
        steps=15,
        control_thetas=2,
        control_races=3,
    )
    s = general_report(cfg, tmp_path, pool=Pool(workers=1, progress_bar=False))
    # the control: the best fixed theta on the held-out track, selected first into control/
    sel = json.loads((tmp_path / "control" / "random_10000" / "selection.json").read_text())
    assert (
        lookup("random:10000")["theta"]
        == sel["winner"]["theta"]
        == s["best_fixed_theta"]["random:10000"]["theta"]
    )
    egos = {
        role: json.loads(
            (tmp_path / "bench" / "random_10000_2cars" / role / "manifest.json").read_text()
        )["config"]["ego"]
        for role in ("alpha", "control", "mpc_default")
    }
    assert egos == {
        "alpha": f"alpha:model={path}",
        "control": "mpc:theta=best",
        "mpc_default": "mpc",
    }
    assert set(s["gap"]["by_cars"]) == {"2", "3"}
    for g in s["gap"]["by_cars"].values():
        assert g["races"] == 1 and g["tracks"] == ["random:10000"]
        assert 0 <= g["gap_rel_median"] <= g["gap_rel_p95"] and np.isfinite(g["const_rel_p95"])
    f = s["field"]["2"]
    assert f["alpha"]["races"] == f["control"]["races"] == f["mpc_default"]["races"] == 2
    assert f["chance"] == 0.5
    assert f["by_track"]["random:10000"]["races"] == 2
    # wins by start order: one race from R1, one from behind, and they add up to the wins
    for role in ("alpha", "control", "mpc_default"):
        b = f["by_start"][role]
        assert b["front"]["races"] == b["behind"]["races"] == 1
        assert b["front"]["wins"] + b["behind"]["wins"] == f[role]["wins"]
    d = s["default"]["general"]
    assert sum(w["wins"] for w in d["wins"].values()) == 3
    text = (tmp_path / "summary.md").read_text()
    for part in (
        "## Approximation gap",
        "against the best fixed theta",
        "against the single-track `default` model",
        "The same wins by start order",
    ):
        assert part in text
    lines = (tmp_path / "bench" / "random_10000_2cars" / "alpha" / "races.jsonl").read_text()
    again = general_report(
        cfg, tmp_path, pool=Pool(workers=1, progress_bar=False)
    )  # nothing left to race
    assert (
        tmp_path / "bench" / "random_10000_2cars" / "alpha" / "races.jsonl"
    ).read_text() == lines
    assert again["gap"] == s["gap"] and again["field"] == s["field"]
    # a report made before --control existed keeps its manifest (and so resumes)
    assert "control" not in json.loads((tmp_path / "manifest.json").read_text())["config"]
    with pytest.raises(ValueError, match=r"\['random:3'\] were used to train the model"):
        general_report(
            GeneralReportConfig(model=path, tracks=("random:3",)),
            tmp_path / "x",
            pool=Pool(workers=1, progress_bar=False),
        )
    held = default_heldout_tracks(["default", "random:10003", "tumftm:Monza"])
    assert "random:10000" in held and "random:10003" not in held and "tumftm:Monza" not in held
    with pytest.raises(ValueError, match="single-track model"):
        general_report(GeneralReportConfig(model="races400"), tmp_path / "y", pool=Pool(workers=1))


@needs_mpc
@pytest.mark.slow
def test_an_extended_general_model_is_collected_trained_and_reported_in_its_space(tmp_path):
    """The extended space end to end at a tiny scale: a family collection with close starts
    and paces, a general model of six-parameter thetas, and the report on a held-out track,
    whose held-out races, control and single-track opponents are the extended space's."""
    pytest.importorskip("torch")
    from agents.potential import load_model
    from experiments.analysis.general import ROLES, GeneralReportConfig, general_report
    from experiments.cli import main

    data, model_dir = tmp_path / "data", tmp_path / "model"
    collect = ["collect", "--tracks", "default", "random:3", "--cars", "2-3", "--races", "8"]
    collect += ["--steps", "40", "--shard-size", "2", "--workers", "1", "--out", str(data)]
    collect += ["--space", "extended", "--start", "close", "--pace", "close"]
    assert main(collect) == 0
    manifest = json.loads((data / "manifest.json").read_text())
    assert manifest["kind"] == "family" and manifest["config"]["space"] == "extended"
    train = ["train", "--data", str(data), "--out", str(model_dir), "--rollout-pairs", "1"]
    assert main(train + ["--rollout-steps", "5"] + TRAIN_ARGS) == 0
    path = str(model_dir / "model.npz")
    model = load_model(path)
    assert model.general and model.space.name == "extended" and model.space.dim == 6
    control = "mpc:space=extended,q=5,zeta=1.05,s1=0.3,s2=0.5,s3=0,b=1"
    cfg = GeneralReportConfig(
        model=path,
        tracks=("random:10000",),
        gap_cars=(2,),
        gap_races=1,
        gap_pairs=200,
        bench_cars=(2,),
        default_races=3,
        steps=15,
        control=control,
    )
    s = general_report(cfg, tmp_path / "report", pool=Pool(workers=1, progress_bar=False))
    out = tmp_path / "report"
    assert s["space"] == "extended" and s["control"] == control and s["best_fixed_theta"] == {}
    assert not (out / "control").exists()  # a given control selects nothing
    held = json.loads((out / "heldout" / "manifest.json").read_text())["config"]
    assert (held["space"], held["start"], held["pace"]) == ("extended", "close", "close")
    with np.load(out / "heldout" / "shard_00000.npz") as z:
        assert z["thetas"].shape[-1] == 6
    bench = out / "bench" / "random_10000_2cars"
    ego = {r: json.loads((bench / r / "manifest.json").read_text())["config"]["ego"] for r in ROLES}
    assert ego == {"alpha": f"alpha:model={path}", "control": control, "mpc_default": "mpc"}
    opponents = json.loads((out / "default" / "control" / "manifest.json").read_text())["config"]
    assert opponents["ego"] == opponents["opponents"] == "alpha:model=extended"
    assert json.loads((out / "manifest.json").read_text())["config"]["control"] == control
    assert f"`{control}` as ego on every track" in (out / "summary.md").read_text()
