"""PPO self-play for the full-size class: the config's class, wake and track, every race of a
run in that class (learning env for each vec env, behaviour cloning, solo evaluation, MPC
reference), the checkpoint's metadata, the ``ppo`` agent racing it on a full-size circuit,
and the refusals of a track of another class."""

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

import racing_env
import racing_env.vec_env
from agents.ppo_agent import PPOAgent, adapt_observation, default_checkpoint, read_checkpoint_meta
from experiments.cli import main
from experiments.learning.config import SelfPlayConfig, SelfPlayState, race_config
from experiments.learning.envs import evaluate_solo, make_learning_env, make_opponents
from experiments.learning.imitation import _alone_view, alone_envs
from experiments.learning.selfplay import _behaviour_cloned_init
from racing_env import RaceConfig, StartConfig
from racing_env.class_config import race_config_for
from racing_env.controllers import RacelineFollower
from racing_env.tracks import make_track
from racing_env.vec_env import HeadToHeadVecEnv

torch.set_num_threads(1)

TINY_ARGS = [
    "--cars",
    "2",
    "--cycles",
    "1",
    "--steps-per-turn",
    "128",
    "--envs",
    "2",
    "--n-steps",
    "64",
    "--batch-size",
    "64",
    "--epochs",
    "1",
    "--race-steps",
    "40",
    "--eval-races",
    "1",
    "--init",
    "bc",
    "--bc-steps",
    "96",
]


# ---------------------------------------------------------------------- the config
def test_fullsize_config_takes_the_class_circuit_and_wake():
    cfg = SelfPlayConfig(vehicle_class="fullsize")
    assert (cfg.track, cfg.wake) == ("tumftm:Monza", 1.0)
    rc = race_config(cfg)
    full = race_config_for("fullsize")
    assert rc.vehicle_class == "fullsize" and rc.wake == 1.0
    assert rc == full.with_(n_cars=3, max_cycles=500, start=replace(full.start, mode="regions"))
    assert race_config(SelfPlayConfig(vehicle_class="fullsize", wake=0.5)).wake == 0.5
    other = SelfPlayConfig(vehicle_class="fullsize", track="tumftm:Spa", wake=0.0)
    assert (other.track, other.wake) == ("tumftm:Spa", 0.0)
    d = cfg.to_dict()
    assert (d["vehicle_class"], d["wake"], d["track"]) == ("fullsize", 1.0, "tumftm:Monza")
    assert SelfPlayConfig.from_dict(d) == cfg


@pytest.mark.parametrize("start", ["regions", "grid", "random"])
def test_orca_races_are_the_paper_races_as_before(start):
    cfg = SelfPlayConfig(n_cars=2, max_cycles=77, start=start)
    assert cfg.wake == 0.0 and cfg.track == "default"
    old = RaceConfig(n_cars=2, max_cycles=77, start=StartConfig(mode=start))
    assert race_config(cfg) == old and race_config(cfg).to_dict() == old.to_dict()
    # an ORCA run's config (config.json, checkpoints) keeps the keys it always had
    assert not {"vehicle_class", "wake"} & set(cfg.to_dict())
    assert SelfPlayConfig(wake=0.5).to_dict()["wake"] == 0.5  # a wake is recorded


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"vehicle_class": "kart"}, "vehicle_class must be one of orca, fullsize, got 'kart'"),
        ({"wake": -1.0}, "wake must be a finite number >= 0, got -1.0"),
        ({"wake": "strong"}, "wake must be a finite number >= 0, got 'strong'"),
        (
            {"vehicle_class": "fullsize", "track": "oval"},
            "track 'oval' is a 1:43 track of the 'orca' class; vehicle_class 'fullsize' races "
            "on full-scale circuits",
        ),
    ],
)
def test_bad_class_wake_or_track_is_refused_naming_it(kw, match):
    with pytest.raises(ValueError, match=match):
        SelfPlayConfig(**kw)


def test_cli_refuses_a_1_43_track_at_full_size(tmp_path, capsys):
    out = tmp_path / "run"
    args = ["selfplay", "--out", str(out), "--vehicle-class", "fullsize", "--track", "oval"]
    assert main(args) == 2
    assert "track 'oval' is a 1:43 track" in capsys.readouterr().err
    assert not out.exists()


# ---------------------------------------------------------------------- the races
@pytest.mark.parametrize("vec_env", ["batched", "dummy", "subproc"])
def test_learning_env_races_full_size_cars_with_the_wake(vec_env):
    cfg = SelfPlayConfig(
        vehicle_class="fullsize", n_cars=2, n_envs=2, max_cycles=30, vec_env=vec_env
    )
    opps, names = make_opponents(cfg, None, SelfPlayState.new(cfg), 0)
    assert names == ["raceline:grip=0.75"]
    env = make_learning_env(cfg, opps, seed=5)
    ref = HeadToHeadVecEnv(
        2,
        opponents=make_opponents(cfg, None, SelfPlayState.new(cfg), 0)[0],
        track="tumftm:Monza",
        vehicle_class="fullsize",
        wake=1.0,
        max_cycles=30,
    )
    ref.seed(5)
    assert ref.track.vehicle_class == "fullsize" and ref.config.wake == 1.0
    try:
        np.testing.assert_array_equal(env.reset(), ref.reset())
        act = np.full((2, 2), [0.6, 0.05], np.float32)
        for _ in range(5):
            o1, r1, *_ = env.step(act)
            o2, r2, *_ = ref.step(act)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_allclose(r1, r2, rtol=0, atol=1e-6)
    finally:
        env.close()


# ---------------------------------------------------------------------- a tiny run
@pytest.fixture(scope="module")
def fullsize_run(tmp_path_factory):
    """A tiny full-size run through the CLI (behaviour-cloned start, the MPC reference), with
    the class and wake of every env it built."""
    built = []
    mp = pytest.MonkeyPatch()

    class SpyVecEnv(HeadToHeadVecEnv):
        def _set_up(self):
            built.append(("vec", self.config.vehicle_class, self.config.wake, self.track.name))
            super()._set_up()

    class SpyParallelEnv(racing_env.RacingParallelEnv):
        def _set_agents(self):
            built.append(("solo", self.config.vehicle_class, self.config.wake, self.track.name))
            super()._set_agents()

    mp.setattr(racing_env.vec_env, "HeadToHeadVecEnv", SpyVecEnv)
    mp.setattr(racing_env, "RacingParallelEnv", SpyParallelEnv)
    out = tmp_path_factory.mktemp("fullsize") / "run"
    try:
        code = main(["selfplay", "--out", str(out), "--vehicle-class", "fullsize"] + TINY_ARGS)
    finally:
        mp.undo()
    assert code == 0
    return out, built


@pytest.mark.slow
def test_fullsize_selfplay_trains_in_the_class_and_records_it(fullsize_run):
    out, built = fullsize_run
    # the BC model's env, the DAgger envs (races with the others, races alone), the learning
    # env of each of 2 turns; the solo races of the MPC reference, the BC start and each turn
    assert [b[0] for b in built].count("vec") == 5 and [b[0] for b in built].count("solo") == 4
    assert {b[1:] for b in built} == {("fullsize", 1.0, "Monza")}
    for name in ("best.zip", "final/car_1.zip", "checkpoints/bc_init.zip"):
        meta = read_checkpoint_meta(out / name)
        assert (meta["vehicle_class"], meta["wake"], meta["track"]) == (
            "fullsize",
            1.0,
            "tumftm:Monza",
        )
        assert meta["selfplay_config"]["vehicle_class"] == "fullsize"
        assert meta["race_config"]["wake"] == 1.0 and meta["race_config"]["vehicle"]["m"] > 100
    assert json.loads((out / "config.json").read_text())["config"]["vehicle_class"] == "fullsize"
    state = json.loads((out / "state.json").read_text())
    assert state["mpc_reference"]["distance_m"] > 10.0  # full-size metres in 4 s
    assert all(e["distance_vs_mpc"] is not None for e in state["evals"])
    card = (out / "MODEL_CARD.md").read_text()
    assert "--vehicle-class fullsize" in card and "(fullsize class, wake 1)" in card
    assert "--track" not in card and "--wake" not in card  # the class's own


@pytest.mark.slow
def test_fullsize_checkpoint_races_on_a_full_size_circuit(fullsize_run, tmp_path):
    out = fullsize_run[0]
    race = tmp_path / "race"
    argv = ["race", "--vehicle-class", "fullsize", "--track", "tumftm:Monza", "--agents"]
    argv += [f"ppo:checkpoint={out / 'best.zip'}", "raceline", "--steps", "20"]
    assert main(argv + ["--no-animation", "--out", str(race)]) == 0
    result = json.loads((race / "result.json").read_text())
    assert len(result["progress_m"]) == 2 and result["progress_m"][0] > 1.0


@pytest.mark.slow
def test_fullsize_checkpoint_refuses_a_1_43_track(fullsize_run, tmp_path, capsys):
    agent = PPOAgent(checkpoint=fullsize_run[0] / "best.zip")
    assert agent.vehicle_class == "fullsize"
    with pytest.raises(
        ValueError,
        match="trained for the 'fullsize' vehicle class; track 'default' is sized for the "
        "'orca' class",
    ):
        agent.reset(make_track("default"), "car_0", 0)
    argv = ["race", "--agents", f"ppo:checkpoint={fullsize_run[0] / 'best.zip'}", "raceline"]
    assert main(argv + ["--steps", "20", "--no-animation", "--out", str(tmp_path / "r")]) == 2
    assert "trained for the 'fullsize' vehicle class" in capsys.readouterr().err


def test_orca_checkpoint_refuses_a_full_size_track():
    agent = PPOAgent(checkpoint=default_checkpoint())
    assert agent.vehicle_class == "orca"
    with pytest.raises(
        ValueError,
        match=r"trained for the 'orca' vehicle class; track 'Monza' is sized for the "
        r"'fullsize' class\. Train a policy on races of the 'fullsize' class \(alpha-racer "
        r"selfplay --vehicle-class fullsize\)",
    ):
        agent.reset(make_track("tumftm:Monza", vehicle_class="fullsize"), "car_0", 0)


# ---------------------------------------------------------------------- the cloned start
def test_bc_alone_is_resolved_per_class_and_recorded_at_full_size():
    orca, full = SelfPlayConfig(), SelfPlayConfig(vehicle_class="fullsize")
    assert (orca.bc_alone, full.bc_alone) == (0.0, 0.5)
    assert "bc_alone" not in orca.to_dict()  # an ORCA run's config as it always was
    assert full.to_dict()["bc_alone"] == 0.5 and SelfPlayConfig.from_dict(full.to_dict()) == full
    assert SelfPlayConfig(bc_alone=0.25).to_dict()["bc_alone"] == 0.25
    assert SelfPlayConfig(vehicle_class="fullsize", bc_alone=0.0).to_dict()["bc_alone"] == 0.0
    for bad in (-0.1, 1.5, "half", True):
        with pytest.raises(ValueError, match=f"bc_alone must be in \\[0, 1\\], got {bad!r}"):
            SelfPlayConfig(bc_alone=bad)


def test_alone_races_show_the_policy_the_solo_phantoms():
    cfg = SelfPlayConfig(vehicle_class="fullsize", n_envs=4, n_cars=3)
    assert alone_envs(cfg) == 2 and alone_envs(SelfPlayConfig(n_envs=4)) == 0
    track = make_track("tumftm:Monza", vehicle_class="fullsize")
    env = racing_env.RacingParallelEnv(track=track, n_cars=1, max_cycles=5)
    obs, _ = env.reset(seed=0)
    view = _alone_view(3, 10, track.length)(obs["car_0"][None])[0]
    np.testing.assert_array_equal(view, adapt_observation(obs["car_0"], 3, 10, track.length))
    assert view[6] == view[12] == np.float32(-0.5 * track.length)


@pytest.mark.slow
def test_fullsize_behaviour_cloned_start_drives_alone(tmp_path):
    """The behaviour-cloned start of a full-size run (the pipeline's, default settings) alone
    on Monza from the solo evaluation's starts for 50 s: at least 80% of the raceline expert's
    distance with under 5% of steps off track; the phantoms of a race alone lie inside the
    observation statistics it was fitted with (not at VecNormalize's clip)."""
    cfg = SelfPlayConfig(vehicle_class="fullsize", mpc_reference=False)
    state = SelfPlayState.new(cfg)

    class Bar:
        def write(self, text):
            pass

    path = tmp_path / _behaviour_cloned_init(cfg, tmp_path, state, Bar())
    bc = state.evals[-1]
    expert = evaluate_solo(RacelineFollower(grip=0.85), cfg)
    assert expert["distance_m"] > 1500.0
    assert bc["distance_m"] >= 0.8 * expert["distance_m"], (bc, expert)
    assert bc["off_track_frac"] < 0.05
    agent = PPOAgent(checkpoint=path)
    env = racing_env.RacingParallelEnv(track=cfg.track, n_cars=1, vehicle_class="fullsize")
    obs, _ = env.reset(seed=0)
    agent.reset(env.track, "car_0", 0)
    z = agent.normalize(adapt_observation(obs["car_0"], 3, 10, env.track.length))
    assert np.all(np.abs(z[[6, 12]]) < 5.0)


def test_orca_behaviour_cloning_is_as_before():
    """The ORCA class clones with no race alone: the same data and fit as before
    ``bc_alone`` existed (figures of that code on this tiny run)."""
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from experiments.learning.config import RACELINE_GRIP
    from experiments.learning.imitation import behaviour_cloning
    from experiments.learning.selfplay import _Idle, _new_model

    cfg = SelfPlayConfig(n_cars=2, n_envs=2, max_cycles=40, n_steps=64, batch_size=64)
    cfg = replace(cfg, bc_steps=96, bc_rounds=2, bc_epochs=2)
    rc = race_config(cfg)
    env = HeadToHeadVecEnv(2, n_cars=2, track=cfg.track, config=rc, opponents=[_Idle()])
    venv = VecNormalize(VecMonitor(env), gamma=cfg.gamma)
    model = _new_model(cfg, venv, cfg.seed)
    fit = behaviour_cloning(model, cfg, cfg.seed, rc, RACELINE_GRIP)
    assert fit["mse"] == pytest.approx(0.4678463041782379, rel=1e-6)
    assert venv.obs_rms.mean[0] == pytest.approx(3.9897859774063917, rel=1e-6)


def test_the_shipped_ppo_is_the_tracks_class_policy():
    """``ppo`` without a checkpoint races the shipped policy of the track's class: the ORCA
    car's on a 1:43 track, the full-size one on a full-size circuit (each with its card)."""
    from agents import make_agent_spec
    from agents.ppo_agent import CLASS_CHECKPOINTS, default_checkpoint
    from racing_env import make_track

    for cls, name in CLASS_CHECKPOINTS.items():
        assert default_checkpoint(cls).is_file()
        assert default_checkpoint(cls).with_suffix(".md").is_file(), name
    orca, full = make_agent_spec("ppo"), make_agent_spec("ppo")
    orca.reset(make_track("default"), "car_0", 0)
    full.reset(make_track("tumftm:Monza", vehicle_class="fullsize"), "car_0", 0)
    assert orca.vehicle_class == "orca" and orca.checkpoint == default_checkpoint("orca")
    assert full.vehicle_class == "fullsize" and full.checkpoint == default_checkpoint("fullsize")
    named = make_agent_spec(f"ppo:checkpoint={default_checkpoint('orca')}")
    with pytest.raises(ValueError, match="trained for the 'orca' vehicle class"):
        named.reset(make_track("tumftm:Monza", vehicle_class="fullsize"), "car_0", 0)
