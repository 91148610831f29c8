"""The alpha-potential pipeline at full size: ``alpha-racer collect --vehicle-class fullsize``
races full-size cars on a full-scale circuit from start regions scaled to the car, below the
class's zeta ceiling, in folders that cannot be resumed in another class or wake; training
builds the collection's track, rollouts and model at its class; the 1:43 collection stays as
it always was."""

import json

import numpy as np
import pytest

pytest.importorskip("daqp")

from experiments.cli import main  # noqa: E402
from experiments.infra.parallel import Pool  # noqa: E402
from experiments.potential.collect import (  # noqa: E402
    START_REGIONS,
    CollectConfig,
    _env_kwargs,
    _race_draws,
    collect,
    collection_space,
    load_races,
    rollout_from_state,
    shard_is_complete,
    shard_path,
)
from racing_env.scaling import scaled_configs  # noqa: E402
from racing_env.tracks import make_track  # noqa: E402

STEPS = 40
FULLSIZE = CollectConfig(
    races=2,
    n_cars=3,
    steps=STEPS,
    seed=1,
    races_per_shard=2,
    track="tumftm:Monza",
    vehicle_class="fullsize",
)
POOL = Pool(workers=1, progress_bar=False)


@pytest.fixture(scope="module")
def fullsize_run(tmp_path_factory):
    """A 2-race, 40-step full-size collection on Monza (one shard)."""
    out = tmp_path_factory.mktemp("fullsize") / "data"
    summary = collect(FULLSIZE, out, POOL)
    assert summary["simulated"] == 2
    return out


def test_a_fullsize_collection_races_at_full_scale(fullsize_run):
    data = load_races(fullsize_run)
    states, thetas = data["states"].astype(float), data["thetas"]
    assert states.shape == (2, STEPS + 1, 3, 6) and thetas.shape == (2, 3, 5)
    # start regions: the paper's 0.4 m / 0.6 m at 1:43, times the length ratio (4.7 / 0.12)
    start = scaled_configs("fullsize").start
    k_len = 4.7 / 0.12
    length, gap = START_REGIONS["paper"]
    assert _env_kwargs(FULLSIZE)["start"].region_length == pytest.approx(length * k_len)
    assert _env_kwargs(FULLSIZE)["start"].region_gap == pytest.approx(gap * k_len)
    for r in range(2):
        for car, region in enumerate(data["start_order"][r]):
            front = start.s0 - region * (length + gap) * k_len
            assert front - length * k_len - 1e-3 <= states[r, 0, car, 0] <= front + 1e-3
        # cars of neighbouring regions start at least one scaled gap (23.5 m) apart
        s0 = np.sort(states[r, 0, :, 0])
        assert np.all(np.diff(s0) >= gap * k_len - 1e-3)
    # the track is Monza at full scale (5.8 km, 7-12 m wide): every car on it, from rest
    track = make_track("tumftm:Monza", vehicle_class="fullsize")
    assert track.length > 5000
    n = states[..., 1]
    assert np.all(np.abs(n) <= 7.0)
    assert np.all(states[:, 0, :, 3] == 0.0)  # StartConfig.speed: standing starts
    # after 4 s a full-size car is far beyond the 1:43 car's top speed (4.2 m/s), below its own
    vx_end = states[:, -1, :, 3]
    assert np.all(vx_end > 10.0) and np.all(vx_end < 67.0)
    driven = states[:, -1, :, 0] - states[:, 0, :, 0]
    assert np.all(driven > 20.0) and np.all(driven < 4 * 67.0)
    # per step a car moves about vx * dt (0.1 s): positions consistent with the speeds
    ds = np.diff(states[..., 0], axis=1)
    v_mid = 0.5 * (states[:, 1:, :, 3] + states[:, :-1, :, 3])
    np.testing.assert_allclose(ds, 0.1 * v_mid, atol=0.25)
    # zeta drawn below the class's ceiling, the rest of the box as always
    assert np.all(thetas[..., 1] <= 1.0 + 1e-6) and np.all(thetas[..., 1] >= 0.8 - 1e-6)
    assert data["fallbacks"].max() == 0


def test_a_fullsize_race_in_the_shard_is_the_race_run_alone(fullsize_run):
    """The shard's lockstep batch and the env run alone race the same full-size race."""
    from experiments.potential.collect import simulate_race

    alone = simulate_race(FULLSIZE, 1)
    data = load_races(fullsize_run)
    for key in ("states", "rewards", "thetas", "start_order", "fallbacks"):
        assert np.array_equal(alone[key], data[key][1]), key


def test_the_manifest_and_shards_record_the_class_and_wake(fullsize_run):
    config = json.loads((fullsize_run / "manifest.json").read_text())["config"]
    assert config["vehicle_class"] == "fullsize" and config["wake"] == 1.0
    with np.load(shard_path(fullsize_run, 0)) as z:
        assert str(z["vehicle_class"]) == "fullsize" and float(z["wake"]) == 1.0


def test_a_fullsize_folder_is_not_resumed_in_another_class_or_wake(fullsize_run, tmp_path):
    # the same races at 1:43 (Monza exists at 1:43 too) or without the wake: refused
    for other in (
        CollectConfig(**{**FULLSIZE.__dict__, "vehicle_class": "orca", "wake": None}),
        CollectConfig(**{**FULLSIZE.__dict__, "wake": 0.0}),
    ):
        with pytest.raises(ValueError, match="another configuration"):
            collect(other, fullsize_run, POOL)
        # and shard by shard: a full-size shard is not a complete shard of the other run
        assert not shard_is_complete(shard_path(fullsize_run, 0), other, 0)
    assert shard_is_complete(shard_path(fullsize_run, 0), FULLSIZE, 0)
    # an untagged shard (as the 1:43 collections write them) is not a full-size shard
    untagged = tmp_path / "shard_00000.npz"
    with np.load(shard_path(fullsize_run, 0)) as z:
        np.savez(untagged, **{k: z[k] for k in z.files if k not in ("vehicle_class", "wake")})
    assert not shard_is_complete(untagged, FULLSIZE, 0)
    orca = CollectConfig(**{**FULLSIZE.__dict__, "vehicle_class": "orca", "wake": None})
    assert shard_is_complete(untagged, orca, 0)
    # a shard whose class is not its manifest's is refused when loading
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    (mixed / "manifest.json").write_text((fullsize_run / "manifest.json").read_text())
    (mixed / "shard_00000.npz").write_bytes(untagged.read_bytes())
    with pytest.raises(ValueError, match=r"'orca' class with wake 0, the manifest says 'fullsize'"):
        load_races(mixed)


def test_bad_class_and_wake_are_named():
    with pytest.raises(
        ValueError,
        match=r"CollectConfig\.vehicle_class must be one of orca, fullsize, got 'f1'",
    ):
        CollectConfig(vehicle_class="f1")
    for wake in (-1.0, float("nan"), "1", True):
        with pytest.raises(
            ValueError, match=rf"CollectConfig\.wake must be a finite number >= 0, got {wake!r}"
        ):
            CollectConfig(vehicle_class="fullsize", track="tumftm:Monza", wake=wake)
    assert CollectConfig().wake == 0.0 and CollectConfig(vehicle_class="fullsize").wake == 1.0
    assert CollectConfig(vehicle_class="fullsize", wake=0.5).wake == 0.5


def test_a_track_of_another_class_fails_before_anything_is_written(tmp_path):
    cfg = CollectConfig(races=1, steps=2, races_per_shard=1, vehicle_class="fullsize")
    with pytest.raises(ValueError, match=r"built-in track 'default' is sized for the 'orca'"):
        collect(cfg, tmp_path / "x", POOL)
    assert not (tmp_path / "x").exists()


def test_the_command_line_collects_at_full_size_on_monza_by_default(tmp_path, capsys):
    out = tmp_path / "cli"
    argv = ["collect", "--races", "1", "--steps", "3", "--shard-size", "1", "--workers", "1"]
    assert main([*argv, "--vehicle-class", "fullsize", "--wake", "0.5", "--out", str(out)]) == 0
    config = json.loads((out / "manifest.json").read_text())["config"]
    assert (config["track"], config["vehicle_class"], config["wake"]) == (
        "tumftm:Monza",
        "fullsize",
        0.5,
    )
    capsys.readouterr()
    # a bad wake, a family collection of another class: one-line errors naming the values
    assert main([*argv, "--vehicle-class", "fullsize", "--wake", "-2", "--out", str(out)]) == 2
    assert "wake must be a finite number >= 0, got -2.0" in capsys.readouterr().err
    assert main([*argv, "--cars", "2-3", "--vehicle-class", "fullsize", "--out", str(out)]) == 2
    assert "family collection" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*argv, "--vehicle-class", "f1", "--out", str(out)])
    assert "invalid choice: 'f1'" in capsys.readouterr().err


def test_the_fullsize_zeta_ceiling_only_rescales_zeta():
    """The full-size draws use the same random numbers as the 1:43 ones: every parameter but
    zeta is the same, and zeta is the same quantile of [0.8, 1.0] as of the box's [0.8, 1.05]."""
    from agents.theta import SPACES

    assert collection_space("paper", "orca") is SPACES["paper"]
    box = collection_space("extended", "fullsize")
    assert box.high[1] == 1.0 and box.low[1] == 0.8 and box.name == "extended"
    np.testing.assert_array_equal(np.delete(box.high, 1), np.delete(SPACES["extended"].high, 1))
    for pace in ("box", "close", "overtake"):
        kw = dict(races=8, seed=3, space="extended", pace=pace)
        orca = CollectConfig(**kw)
        full = CollectConfig(**kw, vehicle_class="fullsize", track="tumftm:Monza")
        for i in range(8):
            _, order_o, seed_o, th_o = _race_draws(orca, i)
            _, order_f, seed_f, th_f = _race_draws(full, i)
            assert seed_o == seed_f and np.array_equal(order_o, order_f)
            assert np.all((th_f[:, 1] >= 0.8) & (th_f[:, 1] <= 1.0))
            if pace == "box":
                np.testing.assert_array_equal(np.delete(th_f, 1, 1), np.delete(th_o, 1, 1))
                np.testing.assert_allclose((th_f[:, 1] - 0.8) / 0.2, (th_o[:, 1] - 0.8) / 0.25)


def test_the_orca_collection_is_the_papers():
    """The 1:43 class: the env keywords, draws, manifest and shard tags of today's code."""
    from dataclasses import asdict

    from agents.reference import Theta
    from experiments.infra.artifacts import manifest_config
    from experiments.potential.collect import ADDED_FIELDS, class_tag
    from racing_env import StartConfig

    cfg = CollectConfig(races=4, steps=15, seed=7, start_jitter=0.5, start="close")
    assert _env_kwargs(cfg) == {
        "track": "default",
        "n_cars": 3,
        "max_cycles": 15,
        "start": StartConfig(mode="regions", lateral_jitter=0.5, region_length=0.2, region_gap=0.1),
    }
    assert class_tag(cfg) == {}
    stored = manifest_config(cfg, ADDED_FIELDS)
    assert "vehicle_class" not in stored and "wake" not in stored
    assert set(asdict(cfg)) - set(stored) == {"space", "pace", "vehicle_class", "wake"}
    # the paper's draws are Theta.sample's
    ref = np.random.default_rng(np.random.SeedSequence(0).spawn(1)[0])
    ref.permutation(3), ref.integers(2**31)
    paper = [Theta.sample(ref).as_array() for _ in range(3)]
    np.testing.assert_array_equal(_race_draws(CollectConfig(), 0)[3], paper)


def test_rollouts_race_the_collections_class(fullsize_run):
    data = load_races(fullsize_run)
    state, thetas = data["states"][0, 20], data["thetas"][0]
    states, rewards = rollout_from_state("tumftm:Monza", state, thetas, 5, "fullsize", 1.0)
    np.testing.assert_allclose(states[0], state)
    s = states[..., 0]
    lead = np.stack([np.delete(s, i, axis=1).max(axis=1) for i in range(3)], axis=1)
    np.testing.assert_allclose(rewards, np.diff(s - lead, axis=0), atol=1e-9)
    # full-size cars at their own speeds: more than the 1:43 car's top speed allows per step
    # (0.42 m), about vx * dt, on Monza at full scale (5.8 km; at 1:43 it is 134 m long)
    ds = np.diff(s, axis=0)
    assert np.all(ds > 0.5)
    np.testing.assert_allclose(ds, 0.05 * (states[1:, :, 3] + states[:-1, :, 3]), atol=0.1)
    assert np.all(np.abs(states[..., 1]) <= 7.0)


def test_training_a_fullsize_collection_gives_a_fullsize_model(fullsize_run, tmp_path, monkeypatch):
    pytest.importorskip("torch")
    import experiments.potential.validation as validation
    from agents.alpha_agent import AlphaAgent
    from agents.potential import load_model
    from experiments.potential.nets import TrainConfig
    from experiments.potential.train import train

    jobs_run = []

    def in_process(jobs, threads, progress_bar):  # the paired rollouts, without a pool
        jobs_run.extend(jobs)
        return [validation.discounted_rollout(*job) for job in jobs]

    monkeypatch.setattr(validation, "paired_rollouts", in_process)
    cfg = TrainConfig(
        value_epochs=1,
        potential_steps=30,
        potential_batch=64,
        value_hidden=(8,),
        potential_hidden=(8,),
        val_fraction=0.5,
        val_pairs=200,
        rollout_pairs=1,
        rollout_steps=3,
        threads=1,
    )
    train(fullsize_run, tmp_path / "model", cfg, progress_bar=False, log=lambda *a: None)
    # the paired rollouts raced full-size cars with the wake on Monza
    assert [job[0] for job in jobs_run] == ["tumftm:Monza"] * 2
    assert [job[6:] for job in jobs_run] == [("fullsize", 1.0)] * 2
    model = load_model(tmp_path / "model" / "model.npz")
    assert model.vehicle_class == "fullsize" and model.meta["wake"] == 1.0
    card = (tmp_path / "model" / "model_card.md").read_text()
    assert "--vehicle-class fullsize --wake 1.0" in card and "zeta at most 1" in card
    # the alpha agent races it on full-size tracks only
    agent = AlphaAgent(model=model)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "trained on 'tumftm:Monza', racing on 'Monza'"
        agent.reset(make_track("tumftm:Monza", vehicle_class="fullsize"), "car_0", 0)
    with pytest.raises(ValueError, match=r"trained for the 'fullsize' vehicle class; track"):
        agent.reset(make_track("tumftm:Monza"), "car_0", 0)
    # its maximisation keeps every car's zeta under the races' ceiling (the box goes to 1.05)
    from racing_env import RacingParallelEnv

    assert model.zeta_ceiling == 1.0 and model.space.high[1] > 1.0
    env = RacingParallelEnv(track="tumftm:Monza", n_cars=3, vehicle_class="fullsize")
    obs, _ = env.reset(seed=0)
    agent = AlphaAgent(model=model)
    agent.reset(env.track, "car_0", 0)
    agent.act(obs["car_0"])
    assert agent._theta_joint is not None and np.all(agent._theta_joint[:, 1] <= 1.0)
    # the analyses race at 1:43: refused, not silently wrong
    from experiments.analysis.nash import AnalyzeConfig, analyze

    path = str(tmp_path / "model" / "model.npz")
    with pytest.raises(ValueError, match=r"trained for the 'fullsize' class"):
        analyze(AnalyzeConfig(model=path), tmp_path / "analysis", pool=POOL)


def test_the_feature_preview_is_in_car_lengths_and_the_papers_at_1_43():
    from agents.features import PREVIEW, curvature_preview, preview_distances

    orca, full = make_track("default"), make_track("tumftm:Monza", vehicle_class="fullsize")
    assert preview_distances(orca) is PREVIEW
    np.testing.assert_allclose(preview_distances(full), PREVIEW * 4.7 / 0.12)
    s = np.array([10.0, 2000.0])
    np.testing.assert_array_equal(
        curvature_preview(full, s), full.interp(full.kappa, s[:, None] + PREVIEW * 4.7 / 0.12)
    )
    s = np.array([1.0, 20.0])
    np.testing.assert_array_equal(
        curvature_preview(orca, s), orca.interp(orca.kappa, s[:, None] + PREVIEW)
    )
