"""Copies of a race in progress: ``copy.deepcopy`` of the env and of its MPC agents (the
MPC's compiled predictions are shared, not copied) continues the race bit for bit, and a
copy's steps leave the original untouched (what a rollout from the exact joint state needs)."""

import copy

import numpy as np
import pytest

from agents import make_agent_spec
from racing_env import RacingParallelEnv

SPECS = ("mpc", "mpc:space=extended,q=5,zeta=1.0,s1=0.3,s2=0.5,s3=0,b=1", "raceline")


def _race(vehicle_class, track):
    env = RacingParallelEnv(n_cars=3, track=track, vehicle_class=vehicle_class, max_cycles=60)
    obs, _ = env.reset(seed=3)
    agents = [make_agent_spec(spec) for spec in SPECS]
    for k, (a, aid) in enumerate(zip(agents, env.possible_agents)):
        a.reset(env.track, aid, 10 + k)
    return env, agents, obs


def _steps(env, agents, obs, n):
    actions_seen = []
    for _ in range(n):
        acts = {aid: agents[k].act(obs[aid]) for k, aid in enumerate(env.possible_agents)}
        actions_seen.append(np.concatenate(list(acts.values())))
        obs, *_ = env.step(acts)
    return obs, np.array(actions_seen)


@pytest.mark.parametrize(
    ("vehicle_class", "track"), [("orca", "default"), ("fullsize", "tumftm:Monza")]
)
def test_a_copied_race_goes_on_bit_for_bit(vehicle_class, track):
    env, agents, obs = _race(vehicle_class, track)
    _, reference = _steps(env, agents, obs, 25)  # the race, uninterrupted
    env, agents, obs = _race(vehicle_class, track)
    obs, _ = _steps(env, agents, obs, 10)
    env2, agents2, obs2 = copy.deepcopy((env, agents, obs))
    assert agents2[0].mpc._traj is agents[0].mpc._traj  # shared, not copied
    # the copy races on first, then the original: both are the uninterrupted race
    _, from_copy = _steps(env2, agents2, obs2, 15)
    _, from_original = _steps(env, agents, obs, 15)
    assert np.array_equal(from_copy, reference[10:])
    assert np.array_equal(from_original, reference[10:])
    assert np.array_equal(env2.core.state, env.core.state)
