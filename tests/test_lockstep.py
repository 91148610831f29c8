"""Races in lockstep (:mod:`experiments.infra.lockstep`): a race run in a batch is bit for bit
the race run alone in its own env, whatever the batch size and its place in it."""

import numpy as np
import pytest

pytest.importorskip("daqp")

from agents import make_agent_spec  # noqa: E402
from experiments.infra.lockstep import (  # noqa: E402
    LockstepRace,
    live_slots,
    race_setup,
    run_lockstep,
)
from racing_env import RacingParallelEnv  # noqa: E402

ORCA = {"n_cars": 3, "max_cycles": 30}
ORCA_SPECS = ["mpc:zeta=0.9", "mpc:zeta=1.0,s1=0.1", "raceline"]
ORCA_ORDERS = [[0, 1, 2], [2, 0, 1], [1, 2, 0], [0, 2, 1], [2, 1, 0]]
FULLSIZE = {"n_cars": 2, "max_cycles": 100, "vehicle_class": "fullsize", "track": "tumftm:Monza"}
FULLSIZE_SPECS = ["raceline", "mpc:zeta=1.0"]
FULLSIZE_ORDERS = [[0, 1], [1, 0], [0, 1], [1, 0], [1, 0]]
SEEDS = [11, 12, 13, 14, 15]


def race_alone(env_kwargs, specs, seed, order):
    """The per-race path: one RacingParallelEnv stepped with a dict of actions per period, as
    ``simulate_race`` and ``run_race`` run it. Returns states, rewards and every step's drag
    factors (T, N)."""
    env = RacingParallelEnv(**env_kwargs)
    agents = [make_agent_spec(s) for s in specs]
    obs, _ = env.reset(seed=seed, options={"order": order})
    for k, agent in enumerate(agents):
        agent.reset(env.track, f"car_{k}", seed + k)
    states, rewards, drag = [env.core.state[0].copy()], [], []
    while env.agents:
        actions = {a: agents[i].act(obs[a]) for i, a in enumerate(env.possible_agents)}
        obs, rew, _, _, infos = env.step(actions)
        rewards.append([rew[a] for a in env.possible_agents])
        drag.append([infos[a]["drag_factor"] for a in env.possible_agents])
        states.append(env.core.state[0].copy())
    return np.array(states), np.array(rewards), np.array(drag)


def lockstep_races(env_kwargs, specs, seeds, orders, make=make_agent_spec):
    track, config = race_setup(**env_kwargs)
    races = []
    for seed, order in zip(seeds, orders):
        agents = [make(s) for s in specs]
        for k, agent in enumerate(agents):
            agent.reset(track, f"car_{k}", seed + k)
        races.append(LockstepRace(agents, track, config, seed, order))
    return races


@pytest.mark.parametrize(
    "env_kwargs, specs, orders",
    [(ORCA, ORCA_SPECS, ORCA_ORDERS), (FULLSIZE, FULLSIZE_SPECS, FULLSIZE_ORDERS)],
    ids=["orca", "fullsize"],
)
def test_a_race_in_a_batch_is_bit_for_bit_the_race_alone(env_kwargs, specs, orders):
    alone = [race_alone(env_kwargs, specs, s, o) for s, o in zip(SEEDS, orders)]
    if env_kwargs is FULLSIZE:  # the wake is on and acts in these races
        assert min(d.min() for _, _, d in alone) < 1.0
    # batches of 1, 2 (race 3 first: the place in the batch does not matter) and 5
    for picks in ([0], [3, 0], [0, 1, 2, 3, 4]):
        results = run_lockstep(
            lockstep_races(env_kwargs, specs, [SEEDS[k] for k in picks], [orders[k] for k in picks])
        )
        for k, res in zip(picks, results):
            states, rewards, _ = alone[k]
            assert np.array_equal(res.states, states), (picks, k)
            assert np.array_equal(res.rewards, rewards), (picks, k)
            assert res.start_order.tolist() == orders[k]


@pytest.mark.slow
def test_a_batch_on_the_multithreaded_kernel_is_bit_for_bit_too():
    from racing_env.core import PARALLEL_MIN_RACES

    env_kwargs, specs = {"n_cars": 3, "max_cycles": 60}, ["raceline"] * 3
    seeds = list(range(PARALLEL_MIN_RACES))
    orders = [ORCA_ORDERS[k % 5] for k in seeds]
    results = run_lockstep(lockstep_races(env_kwargs, specs, seeds, orders))
    for k, res in enumerate(results):
        states, rewards, _ = race_alone(env_kwargs, specs, seeds[k], orders[k])
        assert np.array_equal(res.states, states) and np.array_equal(res.rewards, rewards)


def test_races_that_end_at_laps_stop_while_the_others_go_on():
    env_kwargs = {"n_cars": 2, "max_cycles": 400, "laps": 1}
    specs, orders, seeds = ["raceline", "raceline:grip=0.8"], [[0, 1], [1, 0], [0, 1]], [1, 2, 3]
    results = run_lockstep(lockstep_races(env_kwargs, specs, seeds, orders))
    assert all(r.terminated for r in results)
    assert len({r.steps for r in results}) > 1  # the races end at different steps
    for res, seed, order in zip(results, seeds, orders):
        states, rewards, _ = race_alone(env_kwargs, specs, seed, order)
        assert np.array_equal(res.states, states) and np.array_equal(res.rewards, rewards)
        assert max(len(t) for t in res.lap_times) == 1


class Straight:
    """A batched agent (one instance in several slots): half throttle, steering to the centre."""

    def __init__(self):
        self.batch_calls = []

    def reset(self, track, agent_id="car_0", seed=None):
        pass

    def act(self, observation):
        return np.array([0.5, -0.1 * observation[1]])

    def act_batch(self, observations):
        self.batch_calls.append(len(observations))
        return np.stack([self.act(o) for o in observations])


class Grouped:
    """Agents of one kind decided as a group (``act_group``), each with its own gain."""

    group_calls: list = []

    def __init__(self, gain):
        self.gain = gain

    def reset(self, track, agent_id="car_0", seed=None):
        pass

    def act(self, observation):
        return np.array([0.4, -self.gain * observation[1]])

    @classmethod
    def act_group(cls, agents, observations):
        cls.group_calls.append(len(agents))
        return np.stack([a.act(o) for a, o in zip(agents, observations)])


def test_batched_agents_decide_once_per_period_and_mixed_races_work():
    env_kwargs = {"n_cars": 3, "max_cycles": 12}
    shared = Straight()
    track, config = race_setup(**env_kwargs)
    races = []
    for k, seed in enumerate((5, 6, 7)):
        other = make_agent_spec("raceline")
        other.reset(track, "car_2", seed)
        races.append(
            LockstepRace([shared, Grouped(0.1 * k), other], track, config, seed, [0, 1, 2])
        )
    Grouped.group_calls.clear()
    batched = run_lockstep(races)
    # car_0 and car_1 of the three races, each kind in one call per period
    assert shared.batch_calls == [3] * 12 and Grouped.group_calls == [3] * 12
    for race in races:
        race.agents[2].reset(track, "car_2", race.seed)
    per_car = run_lockstep(races, batch_decisions=False)
    assert shared.batch_calls == [3] * 12 and Grouped.group_calls == [3] * 12
    for a, b in zip(batched, per_car):
        assert np.array_equal(a.states, b.states) and np.array_equal(a.rewards, b.rewards)
    assert live_slots(np.array([True, False, True]), 2).tolist() == [[0, 0], [0, 1], [2, 0], [2, 1]]


def test_a_batch_of_mixed_configs_or_tracks_is_refused_naming_the_difference():
    races = lockstep_races({"n_cars": 2, "max_cycles": 5}, ["raceline"] * 2, [1], [[0, 1]])
    other = lockstep_races({"n_cars": 2, "max_cycles": 6}, ["raceline"] * 2, [2], [[0, 1]])
    with pytest.raises(ValueError, match=r"race 1's config differs .* max_cycles=6"):
        run_lockstep(races + other)
    oval = lockstep_races(
        {"n_cars": 2, "max_cycles": 5, "track": "oval"}, ["raceline"] * 2, [2], [[0, 1]]
    )
    with pytest.raises(ValueError, match="race 1 is on track 'oval'"):
        run_lockstep(races + oval)
    with pytest.raises(ValueError, match="race 0 has 1 agents for 2 cars"):
        run_lockstep([LockstepRace(races[0].agents[:1], races[0].track, races[0].config, 1)])


@pytest.mark.parametrize("extra", [{}, {"space": "extended", "start": "close", "pace": "overtake"}])
def test_a_collection_shard_in_lockstep_is_the_shard_raced_one_by_one(tmp_path, extra):
    from experiments.potential.collect import (
        CollectConfig,
        simulate_race,
        simulate_shard,
        write_shard,
    )

    config = CollectConfig(races=3, n_cars=3, steps=15, seed=3, races_per_shard=3, **extra)
    one_by_one = [simulate_race(config, i) for i in config.shard_races(0)]
    write_shard({k: np.stack([r[k] for r in one_by_one]) for k in one_by_one[0]}, 0, tmp_path / "a")
    write_shard(simulate_shard(config, 0), 0, tmp_path / "b")
    with np.load(tmp_path / "a/shard_00000.npz") as a, np.load(tmp_path / "b/shard_00000.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            assert a[key].dtype == b[key].dtype and np.array_equal(a[key], b[key]), key
