"""Self-play's progress: a typed state with a JSON round trip, reading old state files."""

import json

import pytest

from experiments.learning.config import SelfPlayConfig, SelfPlayState


def test_a_state_survives_a_json_round_trip(tmp_path):
    cfg = SelfPlayConfig(n_cars=3)
    state = SelfPlayState.new(cfg)
    assert state.cars == [None] * 3 and state.trained_turns == [0] * 3
    state.turn, state.turn_steps, state.total_steps = 4, 128, 4 * 2048 + 128
    state.current = "checkpoints/partial/turn_004_car_1_000000128.zip"
    state.cars[0] = "checkpoints/turn_003_car_0.zip"
    state.trained_turns[0] = 2
    state.train_seconds, state.train_cpu_seconds, state.bc_cpu_seconds = 12.5, 11.25, 3.5
    state.evals.append({"phase": "ppo", "turn": 3, "car": 0, "distance_m": 41.5})
    state.train_curve.append({"turn": 3, "car": 0, "total_steps": 2048, "ep_rew_mean": 0.25})
    state.mpc_reference = {"distance_m": 50.0, "off_track_frac": 0.0}
    state.bc_init = "checkpoints/bc_init.zip"
    state.save(tmp_path / "state.json")
    back = SelfPlayState.load(tmp_path / "state.json", cfg)
    assert back == state
    assert json.loads((tmp_path / "state.json").read_text()) == state.to_dict()


def test_a_missing_file_is_a_new_run(tmp_path):
    cfg = SelfPlayConfig(n_cars=2)
    assert SelfPlayState.load(tmp_path / "state.json", cfg) == SelfPlayState.new(cfg)


def test_an_old_state_file_without_the_cpu_times_still_reads(tmp_path):
    # written before train_cpu_seconds and bc_cpu_seconds were recorded
    old = {
        "turn": 2,
        "turn_steps": 0,
        "current": None,
        "total_steps": 4096,
        "train_seconds": 30.0,
        "cars": ["a.zip", "b.zip", None],
        "trained_turns": [1, 1, 0],
        "evals": [],
        "train_curve": [],
        "mpc_reference": None,
        "bc_init": None,
        "done": False,
    }
    (tmp_path / "state.json").write_text(json.dumps(old))
    state = SelfPlayState.load(tmp_path / "state.json", SelfPlayConfig(n_cars=3))
    assert state.turn == 2 and state.total_steps == 4096 and state.cars[1] == "b.zip"
    assert state.train_cpu_seconds == 0.0 and state.bc_cpu_seconds is None


def test_unknown_fields_and_a_wrong_number_of_cars_are_refused():
    cfg = SelfPlayConfig(n_cars=3)
    with pytest.raises(ValueError, match="unknown self-play state fields.*'turns'"):
        SelfPlayState.from_dict({"turns": 1}, cfg)
    with pytest.raises(ValueError, match="2 cars.*n_cars=3"):
        SelfPlayState.from_dict({"cars": [None, None], "trained_turns": [0, 0]}, cfg)
    with pytest.raises(ValueError, match="JSON object"):
        SelfPlayState.from_dict([1, 2], cfg)
