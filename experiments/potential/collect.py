"""Race data for the alpha-potential (paper section 4): races of MPC cars with random theta.

``alpha-racer collect --races 4000 --out data/races`` simulates races of ``n_cars`` MPC agents,
each with theta drawn uniformly within the documented bounds, from the paper's start regions
in a random order with small random offsets, and stores per step the joint state, every car's
theta and the per-car rewards (rewards, not returns, so any discount can be used later).

Storage: shards of ``races_per_shard`` races, ``shard_00000.npz`` ..., each written atomically
(temporary file, then rename), plus ``manifest.json`` (schema version, config). A killed run
resumes where it stopped: finished shards are kept and skipped, so no finished race is lost
or recomputed. Race ``i`` draws everything from ``SeedSequence(seed).spawn`` child ``i``, so the
same seed gives the same data whatever the worker count or backend. A worker races a shard's
races in one lockstep batch (:mod:`experiments.infra.lockstep`), each bit for bit the race run
alone (:func:`simulate_race`).

Shard arrays (R races, T steps, N cars): ``states`` (R, T + 1, N, 6) float32 joint Frenet
states (unwrapped s); ``thetas`` (R, N, dim) float32 (dim 5 in the paper's policy space, 6 in
the extended one, ``CollectConfig.space``); ``rewards`` (R, T, N) float32;
``race_index`` (R,) int64; ``start_order`` (R, N) int64 (start region of each car);
``fallbacks`` (R, N) int32 (MPC fallbacks, to spot bad races).
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.infra.artifacts import claim, manifest_config, provenance, write_npz
from experiments.infra.checks import check_counts
from experiments.infra.parallel import Pool, run_tasks_with_progress

SCHEMA_VERSION = 1
#: Start-region geometry of a collection's races (``StartConfig`` region_length, region_gap
#: [m]): the paper's, or close together so that the cars interact from the first corner.
START_REGIONS = {"paper": (0.4, 0.6), "close": (0.2, 0.1)}
#: How a race's paces are drawn: ``"box"``, every car's zeta over the whole box (the paper);
#: ``"close"``, one zeta for the race drawn over the box and every car's within
#: ``PACE_SPREAD`` of it (clipped to the box), so that the field stays together while the
#: collection still spans the box's paces; ``"spread"``, the same with every car's zeta within
#: ``PACE_SPREADS["spread"]``, so that cars a few percent faster start among slower ones and
#: passes happen (at ``"close"`` cars of nearly equal pace rarely get past one another);
#: ``"overtake"``, the paces of ``"spread"`` dealt slowest to R1 and fastest to the last region,
#: so that every faster car starts behind every slower one and must pass to gain.
PACES = ("box", "close", "spread", "overtake")
PACE_SPREAD = 0.03  # half-width of a "close" race's zeta spread (absolute, zeta units)
PACE_SPREADS = {"close": PACE_SPREAD, "spread": 0.08, "overtake": 0.08}
#: Config fields added after collections were first made, with their paper defaults: a manifest
#: records them only when they differ (:func:`experiments.infra.artifacts.manifest_config`).
ADDED_FIELDS = {"space": "paper", "start": "paper", "pace": "box"}


class ShardedRaces:
    """Races ``0..races-1`` cut into shards of ``races_per_shard`` (the last may be short)."""

    races: int
    races_per_shard: int

    @property
    def n_shards(self) -> int:
        return -(-self.races // self.races_per_shard)

    def shard_races(self, shard: int) -> range:
        lo = shard * self.races_per_shard
        return range(lo, min(lo + self.races_per_shard, self.races))


@dataclass(frozen=True)
class CollectConfig(ShardedRaces):
    """What to simulate. Defaults: the paper's races (3 cars, 500 steps of 0.1 s)."""

    races: int = 4000
    n_cars: int = 3
    steps: int = 500
    track: str = "default"
    seed: int = 0
    races_per_shard: int = 25
    start_jitter: float = 0.8  # lateral jitter of the start positions (fraction of the room)
    space: str = "paper"  # policy space the thetas are drawn from (agents.reference)
    start: str = "paper"  # start regions: "paper" (0.4 m long, 0.6 m apart) or
    # "close" (0.2 m long, 0.1 m apart: pass and block at once)
    pace: str = "box"  # the cars' zeta: "box" (each over the box), or as PACES says

    def __post_init__(self):
        from agents.reference import policy_space

        policy_space(self.space)  # names the choices if unknown
        if self.start not in START_REGIONS:
            raise ValueError(
                f"CollectConfig.start must be one of {sorted(START_REGIONS)}, got {self.start!r}"
            )
        if self.pace not in PACES:
            raise ValueError(f"CollectConfig.pace must be one of {list(PACES)}, got {self.pace!r}")
        check_counts(self, ("races", "n_cars", "steps", "races_per_shard"))
        if not 2 <= self.n_cars <= 8:
            raise ValueError(f"CollectConfig.n_cars must be in 2..8, got {self.n_cars}")


def _mpc_agents(
    track, thetas, rng=None, agent_ids=None, space: str = "paper", first: int = 0
) -> list:
    """This process's MPC agents ``first ..`` of policy space ``space`` set to ``thetas``
    (N, dim) and reset on ``track``."""
    from agents.reference import Theta

    agents = _agents(first + len(thetas), space)[first:]
    for k, (agent, theta) in enumerate(zip(agents, thetas)):
        agent.theta = Theta.from_array(theta)
        agent.reset(
            track,
            agent_ids[k] if agent_ids else f"car_{k}",
            None if rng is None else int(rng.integers(2**31)),
        )
    return agents


def _env_kwargs(config: CollectConfig) -> dict:
    """The ``RacingParallelEnv`` keywords of a race of the config."""
    from racing_env import StartConfig

    length, gap = START_REGIONS[config.start]
    start = StartConfig(
        mode="regions", lateral_jitter=config.start_jitter, region_length=length, region_gap=gap
    )
    return {
        "track": config.track,
        "n_cars": config.n_cars,
        "max_cycles": config.steps,
        "start": start,
    }


def _race_draws(config: CollectConfig, race_index: int) -> tuple:
    """``(rng, order, seed, thetas)`` of race ``race_index``: its generator (the agents' seeds
    are drawn next), start order (N,), start seed and thetas (N, dim), from its own seed."""
    from agents.reference import policy_space

    rng = np.random.default_rng(
        np.random.SeedSequence(config.seed).spawn(race_index + 1)[race_index]
    )
    order = rng.permutation(config.n_cars)
    seed = int(rng.integers(2**31))
    space = policy_space(config.space)  # the paper's draws are Theta.sample's, bit for bit
    thetas = np.array([space.sample(rng) for _ in range(config.n_cars)])
    if config.pace in PACE_SPREADS:
        thetas = close_paces(thetas, space, rng, PACE_SPREADS[config.pace])
    if config.pace == "overtake":  # car i starts in region order[i]: R1 gets the slowest
        thetas = thetas[np.argsort(thetas[:, space.names.index("zeta")], kind="stable")][order]
    return rng, order, seed, thetas


def simulate_race(config: CollectConfig, race_index: int) -> dict:
    """Simulate race ``race_index`` of the config alone, in its own env (the per-race path);
    everything random comes from its own seed."""
    from racing_env import RacingParallelEnv

    env = RacingParallelEnv(**_env_kwargs(config))
    rng, order, seed, thetas = _race_draws(config, race_index)
    obs, _ = env.reset(seed=seed, options={"order": order.tolist()})
    agents = _mpc_agents(env.track, thetas, rng, env.possible_agents, config.space)
    fallbacks0 = [a.stats["fallbacks"] for a in agents]
    states = np.empty((config.steps + 1, config.n_cars, 6), dtype=np.float32)
    rewards = np.zeros((config.steps, config.n_cars), dtype=np.float32)
    states[0] = env.core.state[0]
    t = 0
    while env.agents:
        actions = {a: agents[i].act(obs[a]) for i, a in enumerate(env.possible_agents)}
        obs, rew, _, _, _ = env.step(actions)
        rewards[t] = [rew[a] for a in env.possible_agents]
        t += 1
        states[t] = env.core.state[0]
    fallbacks = [a.stats["fallbacks"] - f0 for a, f0 in zip(agents, fallbacks0)]
    return _race_record(config, race_index, states, rewards, thetas, order, fallbacks)


def simulate_races(config: CollectConfig, indices) -> list[dict]:
    """Races ``indices`` of the config in one lockstep batch
    (:func:`experiments.infra.lockstep.run_lockstep`), each bit for bit :func:`simulate_race`'s."""
    from experiments.infra.lockstep import LockstepRace, race_setup, run_lockstep

    track, race_config = race_setup(**_env_kwargs(config))
    races, draws = [], []
    for k, i in enumerate(indices):
        rng, order, seed, thetas = _race_draws(config, i)
        agents = _mpc_agents(track, thetas, rng, None, config.space, first=k * config.n_cars)
        races.append(LockstepRace(agents, track, race_config, seed, order.tolist()))
        draws.append((i, order, thetas))
    return [
        _race_record(config, i, r.states, r.rewards, thetas, order, r.fallbacks)
        for r, (i, order, thetas) in zip(run_lockstep(races), draws)
    ]


def _race_record(config, race_index, states, rewards, thetas, order, fallbacks) -> dict:
    """A race's arrays as a shard stores them (float32 states, rewards and thetas)."""
    states, rewards = np.asarray(states, np.float32), np.asarray(rewards, np.float32)
    if not (np.isfinite(states).all() and np.isfinite(rewards).all()):
        raise FloatingPointError(f"race {race_index} produced non-finite data")
    return {
        "states": states,
        "thetas": thetas.astype(np.float32),
        "rewards": rewards,
        "race_index": race_index,
        "start_order": order,
        "fallbacks": np.asarray(fallbacks, dtype=np.int32),
    }


def close_paces(
    thetas: np.ndarray, space, rng: np.random.Generator, spread: float = PACE_SPREAD
) -> np.ndarray:
    """``thetas`` (N, dim) with every car's zeta replaced by one drawn within ``spread``
    (zeta units) of a zeta for the race, itself drawn uniformly over ``space``'s zeta bounds,
    clipped to them (a copy)."""
    z = space.names.index("zeta")
    lo, hi = space.low[z], space.high[z]
    centre = rng.uniform(lo, hi)
    out = thetas.copy()
    out[:, z] = np.clip(centre + rng.uniform(-spread, spread, len(out)), lo, hi)
    return out


def rollout_from_state(track, state, thetas, steps: int):
    """Race MPC cars with ``thetas`` (N, 5) from the joint state ``state`` (N, 6) (s unwrapped)
    for ``steps`` steps; returns (states (steps + 1, N, 6), rewards (steps, N)).

    The MPCs start cold (no warm start), as after a reset. Used for the simulated values of
    paired rollouts (deviations of one car's theta from the same state).
    """
    from racing_env import BatchedRaces
    from racing_env.config import RaceConfig
    from racing_env.tracks import make_track

    state = np.asarray(state, dtype=float)
    N = state.shape[0]
    core = BatchedRaces(make_track(track), RaceConfig(n_cars=N, max_cycles=steps), n_races=1)
    core.reset(seed=0)
    core.state[0] = state
    core.start[0] = state
    core.s_line[0] = state[:, 0].max()
    thetas = np.asarray(thetas, dtype=float)
    from agents.theta import space_of

    agents = _mpc_agents(core.track, thetas, space=space_of(thetas[0]).name)
    obs = core.observe()[0]
    states = np.empty((steps + 1, N, 6))
    rewards = np.empty((steps, N))
    states[0] = state
    for t in range(steps):
        actions = np.stack([agents[k].act(obs[k]) for k in range(N)])[None]
        obs, rew, _, _ = core.step(actions)
        obs = obs[0]
        rewards[t] = rew[0]
        states[t + 1] = core.state[0]
    return states, rewards


_AGENTS: dict = {}


def _agents(n: int, space: str = "paper") -> list:
    """MPC agents of policy space ``space`` reused across races in this process (building one
    compiles and loads code)."""
    from agents.mpc_agent import MPCAgent

    pool = _AGENTS.setdefault(space, [])
    while len(pool) < n:
        pool.append(MPCAgent(space=space))
    return pool[:n]


def simulate_shard(config: CollectConfig, shard: int) -> dict:
    """The task function of every backend: simulate one shard's races, return its arrays.

    Pure (no file access), so a remote worker without the driver's disk can run it; the
    driver writes the result with :func:`write_shard`.
    """
    warnings.simplefilter("ignore")
    races = simulate_races(config, config.shard_races(shard))  # one lockstep batch
    return {k: np.stack([r[k] for r in races]) for k in races[0]}


def shard_path(out_dir, shard: int) -> Path:
    """The file of shard ``shard`` in the collection folder ``out_dir`` (both kinds')."""
    return Path(out_dir) / f"shard_{shard:05d}.npz"


def write_shard(arrays: dict, shard: int, out_dir) -> str:
    """Write a shard atomically (temporary file, then rename); returns its path."""
    return str(write_npz(shard_path(out_dir, shard), schema_version=SCHEMA_VERSION, **arrays))


def shard_is_complete(path: Path, config: CollectConfig, shard: int) -> bool:
    try:
        with np.load(path) as z:
            return int(z["schema_version"]) == SCHEMA_VERSION and z["race_index"].tolist() == list(
                config.shard_races(shard)
            )
    except Exception:  # truncated, corrupt or foreign file: redo it
        return False


def collect(config: CollectConfig, out_dir, pool: Pool = Pool()) -> dict:
    """Simulate every missing shard on ``pool``; returns a summary.

    Local processes and Ray tasks alike run :func:`simulate_shard` and this process writes
    the shards, so the data are identical. Resumable: complete shards are skipped.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    claim(
        out / "manifest.json",
        {"schema_version": SCHEMA_VERSION, "config": manifest_config(config, ADDED_FIELDS)},
        "race data",
        provenance=provenance(),
    )
    return simulate_missing_shards(
        config,
        out,
        simulate_shard,
        shard_is_complete,
        lambda k, arrays: write_shard(arrays, k, out),
        "collect",
        pool,
    )


def simulate_missing_shards(
    config: ShardedRaces,
    out: Path,
    simulate,
    is_complete,
    write,
    desc: str,
    pool: Pool,
) -> dict:
    """Simulate every shard ``k`` of ``config`` whose file in ``out`` is not complete
    (``is_complete(path, config, k)``) as ``simulate(config, k)`` on the pool, and
    ``write(k, arrays)`` each as it arrives, behind a progress bar ``desc`` over all races;
    returns the summary (races, simulated, resumed, seconds, races_per_s, out) of both kinds
    of collection."""
    todo = [k for k in range(config.n_shards) if not is_complete(shard_path(out, k), config, k)]
    done_races = config.races - sum(len(config.shard_races(k)) for k in todo)
    t0 = time.perf_counter()
    run_tasks_with_progress(
        simulate,
        [(k, (config, k)) for k in todo],
        write,
        pool,
        total=config.races,
        done=done_races,
        desc=desc,
        unit="race",
        count=lambda k: len(config.shard_races(k)),
    )
    seconds = time.perf_counter() - t0
    new = config.races - done_races
    return {
        "races": config.races,
        "simulated": new,
        "resumed": done_races,
        "seconds": seconds,
        "races_per_s": new / seconds if seconds > 0 else float("nan"),
        "out": str(out),
    }


def load_races(out_dir) -> dict:
    """All shards of a collection concatenated in race order (checks the schema)."""
    out = Path(out_dir)
    meta = json.loads((out / "manifest.json").read_text())
    if meta["schema_version"] != SCHEMA_VERSION:
        raise ValueError(
            f"{out}: schema {meta['schema_version']}, this code reads {SCHEMA_VERSION}"
        )
    parts = []
    for path in sorted(out.glob("shard_*.npz")):
        with np.load(path) as z:
            parts.append({k: z[k] for k in z.files if k != "schema_version"})
    if not parts:
        raise ValueError(f"{out}: no shards")
    data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    data["config"] = meta["config"]
    return data
