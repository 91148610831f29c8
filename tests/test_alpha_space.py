"""The alpha-potential on the extended policy space (q, zeta, s1, s2, s3, b): features and
networks sized by the space, models recording it, training reading it from the collection,
the alpha agent maximising over its box; mismatches named. The paper space's numbers are
unchanged (tests/test_alpha.py, tests/test_regression.py)."""

import json
import warnings

import numpy as np
import pytest

from agents import features as ff
from agents import general_features as gf
from agents.features import scale_theta, unscale_theta
from agents.mlp import MLP
from agents.potential import PotentialModel
from agents.theta import SPACES
from racing_env import make_track

TRACK = make_track("default")
PAPER, EXTENDED = SPACES["paper"], SPACES["extended"]


def _joint(rng, n, space, batch=()):
    x = np.zeros(batch + (n, 6))
    x[..., 0] = rng.uniform(0, 80, batch + (n,))
    x[..., 1] = rng.uniform(-0.2, 0.2, batch + (n,))
    x[..., 3] = rng.uniform(0.5, 3.5, batch + (n,))
    return x, rng.uniform(space.low, space.high, batch + (n, space.dim))


# ---------------------------------------------------------------------------- features
@pytest.mark.parametrize("fs", [ff, gf], ids=["fixed", "general"])
def test_extended_features_are_the_paper_layout_with_b_after_each_theta(fs):
    """Dropping the b columns of the extended features leaves the paper's features of the same
    cars exactly; the theta slots hold the scaled six parameters; sizes follow the space."""
    rng = np.random.default_rng(0)
    n = 3
    x, th6 = _joint(rng, n, EXTENDED, (4,))
    th5 = th6[..., :5]
    p6, p5 = fs.potential_features(x, th6, TRACK), fs.potential_features(x, th5, TRACK)
    v6, v5 = fs.value_features(x, th6, TRACK, 1), fs.value_features(x, th5, TRACK, 1)
    assert p6.shape == (4, fs.potential_dim(n, "extended"))
    assert v6.shape == (4, fs.value_dim(n, "extended"))
    assert p5.shape == (4, fs.potential_dim(n)) and v5.shape == (4, fs.value_dim(n))
    slots6 = fs.potential_theta_slots(n, "extended")
    assert slots6.shape == (n, 6)
    keep = np.setdiff1d(np.arange(p6.shape[-1]), slots6[:, 5])
    if fs is gf:  # empty slots are zero in both: drop every slot's b column
        per = gf.dims("extended")["slot"]
        keep = np.setdiff1d(np.arange(p6.shape[-1]), np.arange(gf.N_MAX) * per + per - 1)
    np.testing.assert_array_equal(p6[:, keep], p5)
    order = fs.progress_order(x[0])
    np.testing.assert_allclose(p6[0, slots6], scale_theta(th6[0, order]))
    # the value features: the ego's theta then each other car's, b last in each
    assert v6.shape[-1] - v5.shape[-1] == (n if fs is ff else gf.N_MAX)


def test_theta_scaling_follows_the_space_of_the_last_dimension():
    assert scale_theta(EXTENDED.low).tolist() == [-1] * 6
    assert scale_theta(EXTENDED.high).tolist() == [1] * 6
    th = np.random.default_rng(1).uniform(EXTENDED.low, EXTENDED.high, (7, 6))
    np.testing.assert_allclose(unscale_theta(scale_theta(th)), th)
    # the paper's scaling is the first five columns of the extended one
    np.testing.assert_array_equal(scale_theta(th)[:, :5], scale_theta(th[:, :5]))
    with pytest.raises(ValueError, match=r"'paper' policy space have 5 parameters.*\(7, 6\)"):
        scale_theta(th, "paper")
    with pytest.raises(ValueError, match="must have 5, 6 or 9 parameters"):
        ff.potential_features(np.zeros((3, 6)), np.zeros((3, 4)), TRACK)
    with pytest.raises(ValueError, match="'extended' policy space have 6 parameters"):
        ff.value_features(np.zeros((3, 6)), np.zeros((3, 5)), TRACK, 0, space="extended")


def test_shared_value_helpers_carry_the_space():
    """relative_to_ego and others_in_order (both feature sets' value features) keep the six
    parameters and scale them by the extended box; a space given must match the thetas."""
    rng = np.random.default_rng(2)
    x, th = _joint(rng, 3, EXTENDED, (5,))
    ego = np.full(5, 1, dtype=np.int64)
    e_state, e_theta, rel, key = ff.relative_to_ego(x, th, ego)
    np.testing.assert_array_equal(e_theta, th[:, 1])
    order = np.argsort(key, axis=-1, kind="stable")[..., :2]
    o_rel, o_state, o_theta = ff.others_in_order(x, th, rel, order, "extended")
    assert o_rel.shape == (5, 2, 1) and o_state.shape == (5, 2, 5) and o_theta.shape == (5, 2, 6)
    np.testing.assert_array_equal(
        o_theta, scale_theta(np.take_along_axis(th, order[..., None], axis=-2), "extended")
    )
    np.testing.assert_array_equal(o_theta, ff.others_in_order(x, th, rel, order)[2])
    with pytest.raises(ValueError, match="'paper' policy space have 5 parameters"):
        ff.others_in_order(x, th, rel, order, "paper")


# ---------------------------------------------------------------------------- models
def _extended_model(n=3, meta=None):
    """A potential over the extended space whose maximiser is known (as in test_alpha.py's
    synthetic model): Phi = -sum over theta columns of silu(z) + silu(-z), z = x - target."""
    D = ff.potential_dim(n, "extended")
    slots = ff.potential_theta_slots(n, "extended").ravel()
    target = np.linspace(-0.6, 0.6, len(slots))
    W1 = np.zeros((D, 2 * len(slots)))
    b1 = np.zeros(2 * len(slots))
    for k, c in enumerate(slots):
        W1[c, 2 * k], b1[2 * k] = 1.0, -target[k]
        W1[c, 2 * k + 1], b1[2 * k + 1] = -1.0, target[k]
    net = MLP([(W1, b1), (-np.ones((2 * len(slots), 1)), np.zeros(1))], np.zeros(D), np.ones(D))
    dv = ff.value_dim(n, "extended")
    value = MLP([(np.zeros((dv, 1)), np.zeros(1))], np.zeros(dv), np.ones(dv))
    meta = {
        "feature_version": ff.FEATURE_VERSION,
        "n_cars": n,
        "track": "default",
        "space": "extended",
        "theta_low": EXTENDED.low.tolist(),
        "theta_high": EXTENDED.high.tolist(),
        **(meta or {}),
    }
    return PotentialModel(value, net, meta), target


def test_an_extended_model_maximises_over_the_six_dimensional_box(tmp_path):
    model, target = _extended_model()
    assert model.space is EXTENDED
    x, _ = _joint(np.random.default_rng(2), 3, PAPER)
    theta, phi = model.maximise(x, TRACK, restarts=4, iterations=40, rng=np.random.default_rng(1))
    assert theta.shape == (3, 6)
    assert np.all(theta >= EXTENDED.low - 1e-9) and np.all(theta <= EXTENDED.high + 1e-9)
    order = np.argsort(-x[:, 0])
    np.testing.assert_allclose(scale_theta(theta[order]).ravel(), target, atol=0.05)
    assert phi == pytest.approx(model.potential(x[None], theta[None], TRACK)[0], abs=1e-9)
    ref, _ = model.maximise_reference(x, TRACK, restarts=2, iterations=2)
    assert ref.shape == (3, 6)
    # a ceiling on the ego's zeta is a (N, 6) bound; a (N, 5) one names the shape
    high = np.tile(EXTENDED.high, (3, 1))
    high[0, 1] = 0.85
    capped, _ = model.maximise(x, TRACK, restarts=4, iterations=20, high=high)
    assert capped[0, 1] <= 0.85 + 1e-12
    with pytest.raises(ValueError, match=r"high must be \(N, 6\) = \(3, 6\)"):
        model.maximise(x, TRACK, high=np.tile(PAPER.high, (3, 1)))
    # thetas of the paper's space are refused by name
    with pytest.raises(ValueError, match="'extended' policy space have 6 parameters"):
        model.potential(x[None], np.zeros((1, 3, 5)), TRACK)
    # the space round-trips through the file
    model.save(tmp_path / "m.npz")
    again = PotentialModel.load(tmp_path / "m.npz")
    assert again.space is EXTENDED and again.meta["theta_high"][-1] == 1.0


def test_a_model_without_a_space_is_the_papers_and_a_wrong_box_is_refused():
    from agents.potential import load_model

    shipped = load_model("races400")
    assert "space" not in shipped.meta and shipped.space is PAPER  # trained before spaces
    with pytest.raises(ValueError, match=r"theta box .*'extended' policy space"):
        _extended_model(meta={"theta_low": PAPER.low.tolist(), "theta_high": PAPER.high.tolist()})
    with pytest.raises(ValueError, match="policy space must be one of"):
        _extended_model(meta={"space": "wide"})


# ---------------------------------------------------------------------------- the agent
def test_alpha_takes_its_models_space_and_names_a_mismatch():
    from agents import make_agent_spec
    from agents.alpha_agent import AlphaAgent

    model, _ = _extended_model()
    agent = AlphaAgent(model=model)
    assert (
        agent.space == "extended" and AlphaAgent(model=model, space="extended").space == "extended"
    )
    with pytest.raises(ValueError, match="trained on the 'extended' policy space.*space='paper'"):
        AlphaAgent(model=model, space="paper")
    with pytest.raises(ValueError, match="trained on the 'paper' policy space.*space='extended'"):
        make_agent_spec("alpha:model=default,space=extended")
    shipped = make_agent_spec("alpha:space=extended")  # model=auto: the shipped extended model
    assert shipped.space == "extended" and shipped.auto
    assert make_agent_spec("alpha").space == "paper"
    # racing: the joint theta lives in the 6-dimensional box, the MPC drives the ego's part
    from racing_env import RacingParallelEnv

    env = RacingParallelEnv(track="default", n_cars=3, max_cycles=4)
    obs, _ = env.reset(seed=0, options={"order": [1, 0, 2]})
    agent.reset(env.track, "car_0", 0)
    for _ in range(4):
        action = agent.act(obs["car_0"])
        assert agent._theta_joint.shape == (3, 6) and np.isfinite(action).all()
        obs, *_ = env.step(
            {"car_0": action, "car_1": np.zeros(2, np.float32), "car_2": np.zeros(2, np.float32)}
        )
    assert agent.theta.as_array("extended").tolist() == pytest.approx(agent._theta_joint[0])
    assert agent.stats["theta"]["b"] == agent.theta.b and agent.blend_line is not None


# ---------------------------------------------------------------------------- end to end
TRAIN_ARGS = [
    "--value-epochs",
    "2",
    "--potential-steps",
    "40",
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
    "--rollout-pairs",
    "0",
    "--threads",
    "1",
]


@pytest.fixture(scope="module")
def extended_run(tmp_path_factory):
    """4 races of 30 steps on the extended space and a tiny potential trained on them."""
    pytest.importorskip("daqp")
    pytest.importorskip("torch")
    from experiments.cli import main

    root = tmp_path_factory.mktemp("extended")
    assert (
        main(
            [
                "collect",
                "--space",
                "extended",
                "--races",
                "4",
                "--steps",
                "30",
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
        main(["train", "--data", str(root / "data"), "--out", str(root / "model")] + TRAIN_ARGS)
        == 0
    )
    return root


def test_tiny_extended_pipeline_collect_train_race(extended_run):
    from agents.potential import load_model
    from experiments.evaluation.race import run_race

    model = load_model(extended_run / "model" / "model.npz")
    meta = model.meta
    assert model.space is EXTENDED and meta["space"] == "extended"
    assert (
        meta["theta_low"] == EXTENDED.low.tolist() and meta["theta_high"] == EXTENDED.high.tolist()
    )
    assert meta["data"]["collect"]["space"] == "extended"
    assert model.potential_net.layers[0][0].shape[0] == ff.potential_dim(3, "extended")
    assert (
        json.loads((extended_run / "model" / "train_config.json").read_text())["space"]
        == "extended"
    )
    card = (extended_run / "model" / "model_card.md").read_text()
    assert "--space extended" in card and "s3, b; the extended policy space" in card
    spec = f"alpha:space=extended,model={extended_run / 'model' / 'model.npz'}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, _ = run_race([spec, "mpc", "mpc:space=extended,b=0.5"], max_cycles=5, render=False)
    st = result.agent_stats[0]
    assert st["solves"] == 5 and np.isfinite(st["potential"])
    assert list(st["theta"]) == list(EXTENDED.names) and 0 <= st["theta"]["b"] <= 1
    # the race records the theta chosen at every step; the last one is the agent's last
    th = result.thetas[0]
    assert th.shape == (5, 6) and result.theta_names[0] == list(EXTENDED.names)
    assert np.all((EXTENDED.low <= th) & (th <= EXTENDED.high))
    assert th[-1].tolist() == list(st["theta"].values())


def test_training_names_a_space_mismatch(extended_run, tmp_path):
    from experiments.infra.parallel import Pool
    from experiments.potential.collect import CollectConfig, collect
    from experiments.potential.nets import TrainConfig
    from experiments.potential.train import train

    cfg = TrainConfig(
        value_epochs=1,
        potential_steps=10,
        value_hidden=(8,),
        potential_hidden=(8,),
        val_fraction=0.25,
        rollout_pairs=0,
        threads=1,
    )
    data = extended_run / "data"
    with pytest.raises(
        ValueError,
        match=r"holds races of the 'extended' policy space, "
        r"--space paper was asked for",
    ):
        train(data, tmp_path / "a", cfg, progress_bar=False, log=lambda *a: None, space="paper")
    assert not (tmp_path / "a").exists()
    # continuing the extended run's folder on races of the paper's space
    paper = tmp_path / "paper"
    collect(
        CollectConfig(races=2, steps=3, races_per_shard=2),
        paper,
        pool=Pool(workers=1, progress_bar=False),
    )
    with pytest.raises(
        ValueError,
        match=r"training run on the 'extended' policy space; the "
        r"races in .* are of the 'paper' space",
    ):
        train(paper, extended_run / "model", cfg, progress_bar=False, log=lambda *a: None)
    # a manifest that disagrees with its thetas
    manifest = json.loads((data / "manifest.json").read_text())
    manifest["config"].pop("space")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "manifest.json").write_text(json.dumps(manifest))
    for shard in data.glob("shard_*.npz"):
        (bad / shard.name).write_bytes(shard.read_bytes())
    with pytest.raises(
        ValueError,
        match=r"manifest says the 'paper' policy space \(5 "
        r"parameters\), the thetas have 6",
    ):
        train(bad, tmp_path / "b", cfg, progress_bar=False, log=lambda *a: None)


def test_a_resumed_training_keeps_its_training_time(extended_run, tmp_path):
    """Run again after both stages finished, ``train`` validates again but reports the
    stages' time summed over its invocations, not the resume's own few seconds."""
    import shutil

    from experiments.cli import main

    out = tmp_path / "model"
    shutil.copytree(extended_run / "model", out)
    first = json.loads((out / "metrics.json").read_text())
    stored = json.loads((out / "timing.json").read_text())["train_seconds"]
    assert stored == first["train_seconds"] > 0
    argv = ["train", "--data", str(extended_run / "data"), "--out", str(out)]
    assert main(argv + TRAIN_ARGS) == 0
    again = json.loads((out / "metrics.json").read_text())
    assert again["train_seconds"] >= first["train_seconds"]
    assert again["total_seconds"] >= again["train_seconds"]
