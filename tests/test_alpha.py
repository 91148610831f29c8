"""The alpha-potential: features, numpy networks, returns, maximisation, the pipeline end to end."""

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agents.features import (
    potential_dim,
    potential_features,
    potential_theta_slots,
    scale_theta,
    unscale_theta,
    value_dim,
    value_features,
)
from agents.mlp import MLP
from agents.reference import THETA_HIGH, THETA_LOW
from experiments.potential.nets import TrainConfig, discounted_partial_returns, split_races
from racing_env import make_track

TRACK = make_track("default")


def _joint(rng, n, batch=()):
    x = np.zeros(batch + (n, 6))
    x[..., 0] = rng.uniform(0, 80, batch + (n,))
    x[..., 1] = rng.uniform(-0.2, 0.2, batch + (n,))
    x[..., 2] = rng.uniform(-0.3, 0.3, batch + (n,))
    x[..., 3] = rng.uniform(0.5, 3.5, batch + (n,))
    x[..., 4:] = rng.normal(0, 0.2, batch + (n, 2))
    th = rng.uniform(THETA_LOW, THETA_HIGH, batch + (n, 5))
    return x, th


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(2, 5))
def test_features_are_consistent_under_reordering_of_cars(seed, n):
    rng = np.random.default_rng(seed)
    x, th = _joint(rng, n)
    perm = rng.permutation(n)
    # Phi's features: any reordering of the cars gives the same input
    np.testing.assert_allclose(
        potential_features(x[perm], th[perm], TRACK), potential_features(x, th, TRACK)
    )
    # V_i's features: reordering the cars (and following the ego) changes nothing
    ego = int(rng.integers(n))
    np.testing.assert_allclose(
        value_features(x[perm], th[perm], TRACK, int(np.argsort(perm)[ego])),
        value_features(x, th, TRACK, ego),
    )
    assert value_features(x, th, TRACK, ego).shape == (value_dim(n),)
    assert potential_features(x, th, TRACK).shape == (potential_dim(n),)


def test_value_features_see_relative_progress_on_unwrapped_s():
    """A car 1 m ahead is 1 m ahead whether or not the start/finish line lies between."""
    th = np.tile((THETA_LOW + THETA_HIGH) / 2, (2, 1))
    L = TRACK.length
    a = np.array([[L - 0.5, 0, 0, 2, 0, 0], [L + 0.5, 0, 0, 2, 0, 0]])
    b = a.copy()
    b[:, 0] -= L
    fa, fb = value_features(a, th, TRACK, 0), value_features(b, th, TRACK, 0)
    np.testing.assert_allclose(fa, fb, atol=1e-9)
    assert fa[5 + 4 + 5] == pytest.approx(1.0)  # first other car: s_j - s_i


def test_theta_slots_hold_the_scaled_thetas():
    rng = np.random.default_rng(1)
    x, th = _joint(rng, 3)
    f = potential_features(x, th, TRACK)
    order = np.argsort(-x[:, 0])
    np.testing.assert_allclose(f[potential_theta_slots(3)], scale_theta(th[order]))
    np.testing.assert_allclose(unscale_theta(scale_theta(th)), th)
    assert (
        scale_theta(THETA_LOW).tolist() == [-1] * 5 and scale_theta(THETA_HIGH).tolist() == [1] * 5
    )


def test_bad_feature_input_is_refused():
    with pytest.raises(ValueError, match=r"states must have shape \(\.\.\., N, 6\)"):
        potential_features(np.zeros((3, 5)), np.zeros((3, 5)), TRACK)
    with pytest.raises(ValueError, match="thetas must have shape"):
        value_features(np.zeros((3, 6)), np.zeros((2, 5)), TRACK, 0)


def test_numpy_network_matches_torch_and_its_input_gradient_matches_finite_differences():
    torch = pytest.importorskip("torch")
    from experiments.potential.nets import to_numpy_mlp as _to_numpy_mlp
    from experiments.potential.nets import torch_mlp as _torch_mlp

    torch.manual_seed(0)
    net = _torch_mlp(7, (16, 8), torch)
    mean, std = np.linspace(-1, 1, 7), np.linspace(0.5, 2, 7)
    mlp = _to_numpy_mlp(net, mean, std, 3.0, -1.0)
    x = np.random.default_rng(0).normal(size=(5, 7))
    with torch.no_grad():
        ref = net(torch.tensor((x - mean) / std, dtype=torch.float32))[:, 0].numpy() * 3 - 1
    np.testing.assert_allclose(mlp(x), ref, rtol=1e-4, atol=1e-5)
    y, g = mlp.value_and_input_grad(x)
    np.testing.assert_allclose(y, mlp(x), rtol=1e-6)
    eps = 1e-2
    for j in range(7):
        d = np.zeros(7)
        d[j] = eps
        fd = (mlp(x + d).astype(float) - mlp(x - d).astype(float)) / (2 * eps)
        np.testing.assert_allclose(g[:, j], fd, rtol=2e-2, atol=2e-3)
    arrays = mlp.to_arrays("p_")
    np.testing.assert_allclose(MLP.from_arrays(arrays, "p_")(x), mlp(x), rtol=1e-6)


def test_discounted_returns_by_hand():
    r = np.array([[[1.0], [2.0], [3.0]]])  # one race, 3 steps, one car
    P, tail = discounted_partial_returns(r, 0.5)
    np.testing.assert_allclose(P[0, :, 0], [1 + 0.5 * 2 + 0.25 * 3, 2 + 0.5 * 3, 3])
    np.testing.assert_allclose(tail, [0.125, 0.25, 0.5])  # gamma^(T - t) for the bootstrap


def test_race_split_holds_out_whole_races():
    tr, va = split_races(50, 0.2, 0)
    assert len(va) == 10 and len(set(tr) | set(va)) == 50 and not set(tr) & set(va)
    with pytest.raises(ValueError, match="cannot be split"):
        split_races(1, 0.5, 0)


def test_train_config_names_bad_values():
    with pytest.raises(ValueError, match="gamma must be in"):
        TrainConfig(gamma=1.0)
    with pytest.raises(ValueError, match="objective must be one of"):
        TrainConfig(objective="l1")
    with pytest.raises(ValueError, match="value_hidden"):
        TrainConfig(value_hidden=(128, 0))


def _synthetic_model(n=3):
    """A potential whose maximiser is known: Phi = -||theta_scaled - target||^2 through a
    one-hidden-layer network is not exact, so use a quadratic-like smooth MLP built by hand:
    hidden units z = +-(theta_scaled - target), SiLU, output -sum(z silu-ish)."""
    from agents.features import FEATURE_VERSION
    from agents.potential import PotentialModel

    D = potential_dim(n)
    slots = potential_theta_slots(n).ravel()
    target = np.linspace(-0.5, 0.7, len(slots))
    W1 = np.zeros((D, 2 * len(slots)))
    b1 = np.zeros(2 * len(slots))
    for k, c in enumerate(slots):  # z = +-(x_c - target_k)
        W1[c, 2 * k], b1[2 * k] = 1.0, -target[k]
        W1[c, 2 * k + 1], b1[2 * k + 1] = -1.0, target[k]
    W2 = -np.ones((2 * len(slots), 1))  # silu(z) + silu(-z) = z tanh-ish >= 0, min at 0
    net = MLP([(W1, b1), (W2, np.zeros(1))], np.zeros(D), np.ones(D))
    value = MLP(
        [(np.zeros((value_dim(n), 1)), np.zeros(1))], np.zeros(value_dim(n)), np.ones(value_dim(n))
    )
    return PotentialModel(
        value,
        net,
        {
            "feature_version": FEATURE_VERSION,
            "n_cars": n,
            "theta_low": THETA_LOW.tolist(),
            "theta_high": THETA_HIGH.tolist(),
        },
    ), target


def test_maximisation_finds_the_maximiser_within_bounds():
    model, target = _synthetic_model()
    x, _ = _joint(np.random.default_rng(0), 3)
    theta, phi = model.maximise(x, TRACK, restarts=4, iterations=40, rng=np.random.default_rng(1))
    assert np.all(theta >= THETA_LOW - 1e-9) and np.all(theta <= THETA_HIGH + 1e-9)
    order = np.argsort(-x[:, 0])
    np.testing.assert_allclose(scale_theta(theta[order]).ravel(), target, atol=0.05)
    # the result is at least as good as the warm start and as random joint thetas
    rand = np.random.default_rng(2).uniform(THETA_LOW, THETA_HIGH, (200, 3, 5))
    assert phi >= model.potential(np.repeat(x[None], 200, 0), rand, TRACK).max() - 1e-6
    _, phi_warm = model.maximise(x, TRACK, theta0=theta, restarts=1, iterations=0)
    assert phi >= phi_warm - 1e-6


def test_maximisation_under_a_zeta_ceiling_stays_in_the_lowered_box():
    """``high`` lowers one car's zeta bound: every result respects it, the ceiling binds
    where the free maximiser lies above it, and the full box as ``high`` is the plain ascent
    bit for bit."""
    model, _ = _synthetic_model()
    rng = np.random.default_rng(3)
    for k in range(5):
        x, _ = _joint(rng, 3)
        free, _ = model.maximise(x, TRACK, restarts=4, iterations=40, rng=np.random.default_rng(k))
        same = model.maximise(
            x,
            TRACK,
            restarts=4,
            iterations=40,
            rng=np.random.default_rng(k),
            high=np.tile(THETA_HIGH, (3, 1)),
        )
        assert same[0].tobytes() == free.tobytes()
        ceiling = float(np.clip(free[0, 1] - 0.05, 0.8, 1.05))
        high = np.tile(THETA_HIGH, (3, 1))
        high[0, 1] = ceiling
        capped, phi = model.maximise(
            x, TRACK, restarts=4, iterations=40, rng=np.random.default_rng(k), high=high
        )
        assert capped[0, 1] <= ceiling + 1e-12 and np.all(capped >= THETA_LOW - 1e-9)
        assert capped[0, 1] == pytest.approx(ceiling, abs=0.01)  # the ceiling binds
        assert phi == pytest.approx(model.potential(x[None], capped[None], TRACK)[0], abs=1e-6)
    with pytest.raises(ValueError, match=r"high must be \(N, 5\) = \(3, 5\)"):
        model.maximise(x, TRACK, high=np.ones((2, 5)))


def test_alpha_agent_with_a_zeta_ceiling_never_drives_above_it():
    from agents import make_agent_spec
    from racing_env import RacingParallelEnv

    env = RacingParallelEnv(track="default", n_cars=3, max_cycles=15)
    obs, _ = env.reset(seed=2, options={"order": [1, 0, 2]})
    agent = make_agent_spec("alpha:zeta_max=0.9")
    agent.reset(env.track, "car_0", 7)
    zetas = []
    for _ in range(15):
        action = agent.act(obs["car_0"])
        zetas.append(agent.theta.zeta)
        obs, *_ = env.step(
            {"car_0": action, "car_1": np.zeros(2, np.float32), "car_2": np.zeros(2, np.float32)}
        )
    assert max(zetas) <= 0.9 + 1e-12 and agent.driven_theta.zeta <= 0.9


@pytest.mark.slow
def test_tiny_pipeline_end_to_end(tmp_path):
    """collect -> train -> validate -> race the alpha agent: the learned potential beats a
    constant potential on held-out deviations, and the agent reports its potential and theta."""
    pytest.importorskip("torch")
    from agents import register_agent
    from agents.alpha_agent import AlphaAgent
    from agents.potential import load_model
    from experiments.cli import main
    from experiments.evaluation.race import run_race

    data, out = tmp_path / "races", tmp_path / "model"
    assert (
        main(
            [
                "collect",
                "--races",
                "8",
                "--steps",
                "60",
                "--shard-size",
                "4",
                "--workers",
                "1",
                "--out",
                str(data),
            ]
        )
        == 0
    )

    def train_args(folder):
        """The ``train`` command line of this test, into ``folder``."""
        return [
            "train",
            "--data",
            str(data),
            "--out",
            str(folder),
            "--value-epochs",
            "3",
            "--potential-steps",
            "150",
            "--value-hidden",
            "32",
            "32",
            "--potential-hidden",
            "64",
            "64",
            "--val-fraction",
            "0.25",
            "--rollout-pairs",
            "2",
            "--rollout-steps",
            "10",
            "--threads",
            "1",
        ]

    assert main(train_args(out)) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["gap_rel_median"] < metrics["const_rel_median"]
    assert metrics["gap_rel_p95"] < metrics["const_rel_p95"]
    assert 0 <= metrics["gap_rel_median"] <= metrics["gap_rel_p95"] <= metrics["gap_rel_max"]
    assert np.isfinite(metrics["rollout_phi_rel_median"])
    model = load_model(out / "model.npz")
    assert model.meta["config"]["gamma"] == 0.99 and model.meta["data"]["races"] == 8
    # the same data and settings in a fresh directory give the same networks, weight for weight
    again = tmp_path / "model_again"
    assert main(train_args(again)) == 0
    with np.load(out / "model.npz") as a, np.load(again / "model.npz") as b:
        assert a.files == b.files
        for k in a.files:
            if k != "meta":
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    # a rerun with the same settings resumes from the checkpoints (nothing left to train);
    # other settings in the same directory are refused
    args = train_args(out)
    assert main(args) == 0
    assert (
        json.loads((out / "metrics.json").read_text())["value_history"] == metrics["value_history"]
    )
    assert main(args[:-2] + ["--threads", "2", "--gamma", "0.98"]) == 2
    register_agent("alpha_tiny", lambda **kw: AlphaAgent(model=model, **kw))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, _ = run_race(["alpha_tiny", "mpc", "mpc:zeta=0.8"], max_cycles=20, render=False)
    st = result.agent_stats[0]
    assert np.isfinite(st["potential"]) and set(st["theta"]) == {"q", "zeta", "s1", "s2", "s3"}
    assert st["maximise_ms_median"] > 0


def test_alpha_agent_refuses_a_model_for_another_number_of_cars():
    from agents.alpha_agent import AlphaAgent

    model, _ = _synthetic_model(n=2)
    agent = AlphaAgent(model=model)
    agent.reset("default", "car_0", 0)
    obs = np.zeros(6 * 3 + 10)
    obs[3] = 1.0
    with pytest.raises(ValueError, match="trained for 2 cars, the race has 3"):
        agent.act(obs)


def _first_decision(agent, track, n):
    from racing_env import RacingParallelEnv

    env = RacingParallelEnv(track=track, n_cars=n, max_cycles=2, start="regions")
    obs, _ = env.reset(seed=0)
    agent.reset(env.track, "car_0", 0)
    a = agent.act(obs["car_0"])
    assert a.shape == (2,) and np.isfinite(a).all()
    return agent.model


def test_auto_races_the_single_track_model_where_it_was_trained_and_the_general_one_elsewhere(
    monkeypatch,
):
    import agents.potential as potential
    from agents.alpha_agent import AlphaAgent, auto_model
    from agents.potential import MODEL_DIR, SHIPPED, cached_model

    assert auto_model("default", 3) == "default"
    general = (MODEL_DIR / SHIPPED["general"]).exists()
    for track, n in (("oval", 3), ("default", 2), ("random:7", 5)):
        assert auto_model(track, n) == ("general" if general else "default")
    agent = AlphaAgent()  # model="auto", reused across races
    assert agent.model is None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert _first_decision(agent, "default", 3) is cached_model("default")
        if general:
            assert _first_decision(agent, "oval", 2) is cached_model("general")
        assert _first_decision(agent, "default", 3) is cached_model("default")
    # without the general model installed, auto falls back to the single-track one
    monkeypatch.setitem(potential.SHIPPED, "general", "not_installed.npz")
    assert auto_model("oval", 3) == "default" and auto_model("default", 5) == "default"


def test_auto_in_the_extended_space_races_the_shipped_extended_model():
    """``alpha:space=extended`` (model=auto) races the shipped extended model on the track
    and field it was trained for; elsewhere the same model (no general extended model is
    shipped), which warns on another track and refuses another field size."""
    from agents import make_agent_spec
    from agents.alpha_agent import auto_model
    from agents.potential import cached_model

    model = cached_model("extended")
    assert model.space.name == "extended" and model.meta["track"] == "default"
    assert auto_model("default", 3, "extended") == "extended"
    assert auto_model("oval", 3, "extended") == "extended"
    agent = make_agent_spec("alpha:space=extended")
    assert _first_decision(agent, "default", 3) is model
    assert agent._theta_joint.shape == (3, 6)
    with pytest.warns(UserWarning, match="trained on track 'default', racing on 'oval'"):
        _first_decision(make_agent_spec("alpha:space=extended"), "oval", 3)
    with pytest.raises(ValueError, match="trained for 3 cars, the race has 2"):
        _first_decision(make_agent_spec("alpha:space=extended"), "default", 2)


def test_shipped_models_load_and_race():
    from agents.potential import MODEL_DIR, SHIPPED, PotentialModel, load_model
    from experiments.evaluation.race import run_race

    shipped = [n for n, f in SHIPPED.items() if (MODEL_DIR / f).exists()]
    assert "races400" in shipped
    for name in shipped:
        m = load_model(name)
        assert m.meta["metrics"]["gap_rel_p95"] < 0.10
        if name.endswith("general"):
            assert m.general and m.trained_cars == (2, 6)
        else:
            assert not m.general and m.n_cars == 3
        extended = name.startswith(("extended", "fullsize"))
        space = "wake" if name.endswith("_wake") else "extended" if extended else "paper"
        assert m.space.name == space
        full = name.startswith("fullsize")
        assert m.vehicle_class == ("fullsize" if full else "orca")
        assert m.zeta_ceiling == (1.0 if full else None)
    m = load_model("races400")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result, _ = run_race(
            ["alpha:model=races400", "mpc", "mpc:zeta=0.8"], max_cycles=15, render=False
        )
    assert result.agent_stats[0]["solves"] == 15 and np.isfinite(result.progress).all()
    meta = {**m.meta, "feature_version": -1}
    with pytest.raises(ValueError, match="feature version -1"):
        PotentialModel(m.value_net, m.potential_net, meta)
    assert m.meta["theta_low"] == THETA_LOW.tolist() and m.meta["theta_high"] == THETA_HIGH.tolist()
    other_box = {**m.meta, "theta_high": (THETA_HIGH + [0, 0.05, 0, 0, 0]).tolist()}
    with pytest.raises(ValueError, match="theta box"):
        PotentialModel(m.value_net, m.potential_net, other_box)


def test_restricted_network_matches_the_full_one_for_any_layer_sizes():
    """MLP.restricted (the ascent's evaluator over the theta columns) gives the full
    network's value and input gradient on those columns, for any depth and widths."""
    rng = np.random.default_rng(3)
    for hidden in ((), (7,), (16, 9), (12, 5, 8)):
        dims = (11,) + hidden + (1,)
        layers = [
            (rng.normal(size=(a, b)) / np.sqrt(a), rng.normal(size=b) * 0.1)
            for a, b in zip(dims[:-1], dims[1:])
        ]
        net = MLP(layers, rng.normal(size=11), rng.uniform(0.5, 2, 11), 2.5, -0.3)
        x = rng.normal(size=11)
        free = np.array([9, 2, 5])
        Z = rng.uniform(-1, 1, (4, 3))
        X = np.repeat(x[None], 4, 0)
        X[:, free] = Z
        y, g = net.value_and_input_grad(X)
        sub = net.restricted(x, free)
        y2, g2 = sub.value_and_input_grad(Z)
        np.testing.assert_allclose(y2, y, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(g2, g[:, free], rtol=1e-4, atol=1e-5)
        np.testing.assert_allclose(sub(Z), y, rtol=1e-5, atol=1e-5)
        assert g2.shape == (4, 3) and y2.shape == (4,)


def test_maximise_beats_the_reference_from_a_cold_start_and_keeps_a_warm_start():
    """The shipped model: the agent's cold start (32 x 12) finds a higher Phi than the first
    release's 4 x 6 on every sampled state, and a warm-started ascent never ends below its
    warm start."""
    from agents.potential import cached_model

    model = cached_model("default")
    rng = np.random.default_rng(5)
    for k in range(6):
        x, _ = _joint(rng, 3)
        th, phi = model.maximise(x, TRACK, restarts=32, iterations=12, rng=np.random.default_rng(k))
        _, phi_ref = model.maximise_reference(
            x, TRACK, restarts=4, iterations=6, rng=np.random.default_rng(k)
        )
        assert phi > phi_ref
        assert phi == pytest.approx(model.potential(x[None], th[None], TRACK)[0], abs=1e-4)
        warm = rng.uniform(THETA_LOW, THETA_HIGH, (3, 5))
        _, phi_warm = model.maximise(x, TRACK, warm, rng=np.random.default_rng(k))
        assert phi_warm >= model.potential(x[None], warm[None], TRACK)[0] - 1e-4


_RACE_SCRIPT = """
import sys, warnings
import numpy as np
warnings.simplefilter("ignore")
from experiments.evaluation.race import run_race
result, _ = run_race(["alpha", "mpc:zeta=0.85", "mpc:zeta=0.8"], seed=0, max_cycles=60,
                     progress_bar=False)
np.save(sys.argv[1], result.states)
"""


@pytest.mark.slow
def test_a_race_with_the_alpha_agent_is_identical_with_1_and_2_threads(tmp_path):
    """The same race in fresh processes with 1 and 2 BLAS/OpenMP/numba threads: the same
    states bit for bit (the agent's decisions do not depend on the thread count)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    states = []
    for n in (1, 2):
        env = {
            **os.environ,
            "OPENBLAS_NUM_THREADS": str(n),
            "OMP_NUM_THREADS": str(n),
            "MKL_NUM_THREADS": str(n),
            "NUMBA_NUM_THREADS": str(n),
            "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]),
        }
        out = tmp_path / f"states_{n}.npy"
        subprocess.run(
            [sys.executable, "-c", _RACE_SCRIPT, str(out)],
            env=env,
            cwd=root,
            check=True,
            timeout=300,
        )
        states.append(np.load(out))
    assert states[0].shape == (61, 3, 6)
    assert states[0].tobytes() == states[1].tobytes()


def test_the_shipped_model_card_is_laid_out_from_the_shipped_models():
    """`python -m experiments.potential.model_card` writes MODEL_CARD.md from the models' metadata;
    the committed card is that output, so it cannot drift from the models."""
    from agents.potential import MODEL_DIR
    from experiments.potential.model_card import card

    assert (MODEL_DIR / "MODEL_CARD.md").read_text() == card()


def test_a_cards_suite_command_gives_back_the_options_of_its_suite():
    from experiments.potential.model_card import suite_command

    c = {
        "ego": "alpha",
        "control": "mpc:theta=best",
        "tracks": ["default"],
        "scenarios": ["pass"],
        "races": 4,
        "steps": 50,
        "seed": 1,
        "zeta_max": 0.94,
        "pass_opponents": "raceline",
    }
    assert "--pass-opponents" not in suite_command(c, "out")
    cmd = suite_command({**c, "pass_opponents": "raceline:grip=0.85"}, "out")
    assert cmd.endswith("--pass-opponents raceline:grip=0.85 --out out")
    assert "--zeta-max 0.97" in suite_command({**c, "scenarios": ["defend"], "zeta_max": 0.97}, "o")


def test_a_model_card_says_how_its_collection_drew_the_paces():
    from experiments.potential.card_lines import pace_text

    assert pace_text({}) == pace_text({"pace": "box"}) == ""
    assert pace_text({"pace": "close"}) == ", zeta close to the race's own, drawn over the box"
    assert "within 0.08" in pace_text({"pace": "spread"})
    assert "slowest car in front" not in pace_text({"pace": "spread"})
    assert pace_text({"pace": "overtake"}).endswith(
        "within 0.08 of the race's own, drawn over the box, the slowest car in front"
    )
