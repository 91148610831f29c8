"""The look-ahead agent (issue 48): its world is the race as its observation holds it, and from
the exact state its rollouts are the oracle's, bit for bit; alone,
its look-ahead picks the faster of its candidates and gains by it over the base raced fixed;
its models of the others drive the theta it assumes; its choices cost what it reports; bad
settings are named."""

import numpy as np
import pytest

import agents.lookahead
from agents import make_agent_spec
from agents.best_theta import best_theta
from agents.lookahead import LookaheadAgent, world_state
from experiments.evaluation.oracle import _rollout
from experiments.evaluation.race import run_race, start_race
from racing_env import RacingParallelEnv

SLOW = "q=20,zeta=0.8,s1=0.1,s2=4,s3=1"


def test_its_world_is_the_race_its_observation_holds():
    env = RacingParallelEnv(track="default", n_cars=3, max_cycles=40)
    agents = [make_agent_spec("raceline") for _ in range(3)]
    obs = start_race(env, agents, seed=3, order=[2, 0, 1])
    for _ in range(25):
        obs = env.step({a: ag.act(obs[a]) for ag, a in zip(agents, env.possible_agents)})[0]
    state = env.core.state[0]
    for car, aid in enumerate(env.possible_agents):
        seen = world_state(obs[aid], env.config.n_preview, car)
        shift = state[car, 0] - seen[car, 0]  # its own s is on its lap: a whole number of laps
        length = env.track.length
        assert (shift + 0.5 * length) % length - 0.5 * length == pytest.approx(0.0, abs=1e-3)
        seen[:, 0] += shift
        assert np.allclose(seen, state, atol=1e-3, rtol=1e-5)  # float32 observations
    with pytest.raises(ValueError, match="car must be an index of the 3 cars observed, got 3"):
        world_state(obs["car_0"], env.config.n_preview, 3)


def test_from_the_exact_state_its_rollouts_are_the_oracle_s(monkeypatch):
    """With the other car's own spec as its model and the exact state in place of the
    observation's float32 one, each candidate scores what the room's oracle scores."""
    race = dict(seed=5, order=[1, 0])
    env = RacingParallelEnv(track="default", n_cars=2, max_cycles=60)
    agent = make_agent_spec(f"lookahead:{SLOW},moves=3,horizon=1,every=20")
    obs = start_race(env, [agent, make_agent_spec(f"mpc:{SLOW}")], **race)
    exact = env.core.state[0].copy()
    monkeypatch.setattr(agents.lookahead, "world_state", lambda *_: exact.copy())
    scores: list[float] = []
    rollout = LookaheadAgent._rollout
    monkeypatch.setattr(
        LookaheadAgent, "_rollout", lambda self, *a: scores.append(rollout(self, *a)) or scores[-1]
    )
    agent.act(obs["car_0"])
    env2 = RacingParallelEnv(track="default", n_cars=2, max_cycles=60)
    copies = [make_agent_spec(f"mpc:{SLOW}") for _ in range(2)]
    obs2 = start_race(env2, copies, **race)
    assert scores == [_rollout(env2, copies, obs2, theta, 10) for theta in agent.thetas]
    assert len(set(scores)) > 1  # the candidates differ


def test_alone_it_picks_the_faster_candidate_and_gains_by_it():
    spec = f"lookahead:{SLOW},moves=3,horizon=1,every=20"
    ahead, _ = run_race([spec], seed=5, max_cycles=80, progress_bar=False)
    fixed, _ = run_race([f"mpc:{SLOW}"], seed=5, max_cycles=80, progress_bar=False)
    agent = make_agent_spec(spec)
    agent.reset("default", "car_0", 0)
    assert [t.zeta for t in agent.thetas] == [0.8, 0.8, 0.8, 0.95]  # base, s1=0, q=500, zeta
    assert ahead.progress[0] > fixed.progress[0] + 0.5


def test_its_models_of_the_others_drive_what_it_assumes():
    env = RacingParallelEnv(track="default", n_cars=2, max_cycles=12)
    for model in ("self", "best"):
        agent = make_agent_spec(f"lookahead:{SLOW},moves=1,horizon=0.5,every=5,model={model}")
        other = make_agent_spec("raceline")
        obs = start_race(env, [agent, other], seed=1, order=[1, 0])
        while env.agents:
            obs = env.step({"car_0": agent.act(obs["car_0"]), "car_1": other.act(obs["car_1"])})[0]
        (model_car,) = agent._others
        expected = agent.thetas[0] if model == "self" else best_theta(env.track)
        assert model_car.theta == expected
        assert model_car.stats["solves"] == 12  # warm: it acted at every period of the race
        st = agent.stats
        assert sum(st["candidate_share"]) == pytest.approx(1.0)
        assert st["choice_ms_median"] > 0 and st["solves"] == 12


def test_a_zeta_ceiling_leaves_out_the_move_it_makes_the_base():
    agent = LookaheadAgent(q=20, zeta=1.0, moves=3, zeta_max=0.88)
    agent.reset("default", "car_0", 0)
    assert len(agent.thetas) == 3  # zeta=0.95 drives 0.88, as the base does


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"moves": 9}, "moves must be an integer in 0..8, got 9"),
        ({"horizon": 0}, r"horizon must be a time in \(0, 60\] s, got 0"),
        ({"every": 0}, "every must be a positive number of periods, got 0"),
        ({"model": "ibr"}, r"model must be one of \('self', 'best'\), got 'ibr'"),
        ({"wake": -1.0}, "wake must be a non-negative strength, got -1.0"),
        ({"zeta": 2.0}, r"zeta = 2.0 is outside its bounds \[0.8, 1.05\]"),
    ],
)
def test_bad_settings_are_named(kw, match):
    with pytest.raises(ValueError, match=match):
        LookaheadAgent(**kw)
