"""The best fixed theta of the full-size class: the control rule races its map and playoff in
the class's world, and its winner is installed beside the paper's entries (keyed by track
and class) where ``mpc:theta=best`` finds it on the full-size circuit, not the 1:43 one."""

import json

import pytest

pytest.importorskip("daqp")

from agents import best_theta, make_agent_spec  # noqa: E402
from agents.best_theta import TABLE_ENV_VAR  # noqa: E402
from experiments.evaluation import control as ct  # noqa: E402
from experiments.evaluation import control_rule as ct_rule  # noqa: E402
from experiments.infra.artifacts import claim_best_thetas  # noqa: E402
from racing_env.tracks import make_track  # noqa: E402

THETA = {"q": 20.0, "zeta": 0.97, "s1": 0.1, "s2": 4.0, "s3": 1.0}
TRACK = "tumftm:Monza"  # shipped with the package: no database needed


@pytest.fixture
def table(tmp_path, monkeypatch):
    path = tmp_path / "table.json"
    monkeypatch.setenv(TABLE_ENV_VAR, str(path))
    return path


def test_the_config_races_in_the_class_s_world_and_records_it():
    cfg = ct.ControlConfig(vehicle_class="fullsize")
    assert cfg.wake == 1.0  # the class's
    m, p = cfg.map_config(TRACK), cfg.playoff_config(TRACK, list(THETA.values()))
    assert (m.vehicle_class, m.wake) == (p.vehicle_class, p.wake) == ("fullsize", 1.0)
    stored = ct.stored_config(cfg)
    assert stored["vehicle_class"] == "fullsize" and stored["wake"] == 1.0
    assert "vehicle_class" not in ct.stored_config(ct.ControlConfig())  # paper folders resume
    assert ct.default_out("paper", "fullsize") == "results/control_fullsize"
    assert ct.default_out("extended", "fullsize") == "results/control_extended_fullsize"
    with pytest.raises(ValueError, match="vehicle_class must be one of orca, fullsize"):
        ct.ControlConfig(vehicle_class="kart")


def test_a_fullsize_winner_is_found_on_the_fullsize_circuit_only(table, tmp_path):
    full = make_track(TRACK, vehicle_class="fullsize")
    sel = {
        "track": TRACK,
        "name": full.name,
        "fingerprint": full.fingerprint(),
        "env": best_theta.env_name(),
        "package_version": "test",
        "rule": ct_rule.RULE,
        "config": ct.stored_config(ct.ControlConfig(vehicle_class="fullsize")),
        "candidates": [{}],
        "winner": {"theta": THETA, "index": 1, "wins": 2, "races": 3, "margin_m_mean": 4.0},
    }
    path = tmp_path / "selection.json"
    path.write_text(json.dumps(sel))
    entry = ct.install(path)
    assert entry["vehicle_class"] == "fullsize"
    assert list(json.loads(table.read_text())["tracks"]) == [f"{TRACK} (fullsize)"]
    assert best_theta.lookup(full)["theta"] == THETA
    agent = make_agent_spec("mpc:theta=best")
    agent.reset(full)
    assert agent.theta.as_array().tolist() == list(THETA.values())
    with pytest.raises(ValueError) as err:  # the 1:43 circuit has no entry
        best_theta.lookup(TRACK)
    assert f"run `alpha-racer control --tracks {TRACK}`" in str(err.value)
    orca = make_agent_spec("mpc:theta=best")
    with pytest.raises(ValueError, match="no best fixed theta"):
        orca.check_track(make_track(TRACK))
    # a run of the class ties its folder to the full-size entry (a bench, a strategy suite)
    claimed = claim_best_thetas(tmp_path / "run", [TRACK], vehicle_class="fullsize")
    assert claimed["paper"][TRACK]["theta"] == THETA
    with pytest.raises(ValueError, match="no best fixed theta"):
        claim_best_thetas(tmp_path / "orca_run", [TRACK])


def test_the_defend_ceiling_is_the_class_s():
    from experiments.evaluation.strategy import ZETA_MAX, StrategyConfig

    assert StrategyConfig().zeta_max == ZETA_MAX == 0.94
    assert StrategyConfig(vehicle_class="fullsize").zeta_max == 0.88
    assert StrategyConfig(vehicle_class="fullsize", zeta_max=0.9).zeta_max == 0.9
    assert StrategyConfig().to_dict()["zeta_max"] == 0.94  # stored suites resume
