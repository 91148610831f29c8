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

Vehicle class (``CollectConfig.vehicle_class``, ``wake``): the paper's races are of the 1:43
``"orca"`` class without a wake; ``"fullsize"`` races full-size single-seaters on a track built
at full scale (``tumftm:Monza``, ``random:SEED``; the built-in ``default`` and ``oval`` are 1:43
tracks), with the class's rules and its wake (strength 1 unless ``wake`` says otherwise), from
the start regions of :data:`START_REGIONS` scaled to the car's length
(:func:`racing_env.scaling.scaled_configs`), and with every car's zeta drawn below the
class's ceiling (:data:`ZETA_CEILING`). A shard of another world than the paper's also holds
``vehicle_class`` and ``wake``, so that a folder is never resumed in another class or wake
(the manifest refuses it too); the paper's shards are as they always were.
"""

from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from experiments.evaluation.bench_config import PAPER_WORLD
from experiments.infra.artifacts import claim, manifest_config, provenance, write_npz
from experiments.infra.checks import check_counts
from experiments.infra.parallel import Pool, run_tasks_with_progress

if TYPE_CHECKING:
    from agents.theta import PolicySpace

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
ADDED_FIELDS = {
    "space": "paper",
    "start": "paper",
    "pace": "box",
    "vehicle_class": "orca",
    "wake": 0.0,
}
#: The ceiling of a collection's zeta draws per vehicle class (None: the box's own top, 1.05).
#: The full-size MPC leaves the track above zeta 1.0 (measured on a lap alone: 14 off-track
#: steps at 1.05, 5 at 1.02, none at 1.0), so a full-size collection draws every
#: car's zeta in [box low, 1.0] (:func:`collection_space`); the theta box itself, and the
#: features' scaling by it, stay the same in every class.
ZETA_CEILING: dict[str, float | None] = {"orca": None, "fullsize": 1.0}


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
    vehicle_class: str = "orca"  # "orca" (the paper's 1:43 cars) or "fullsize"
    wake: float | None = None  # the wake's strength; None: the class's (0 orca, 1 fullsize),
    # stored resolved

    def __post_init__(self):
        from agents.reference import policy_space
        from experiments.evaluation.bench_config import check_class_wake

        policy_space(self.space)  # names the choices if unknown
        try:
            check_class_wake(self)  # resolves wake (None: the class's)
        except ValueError as exc:
            raise ValueError(f"CollectConfig.{exc}") from None
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


def collection_class(config: dict) -> tuple[str, float]:
    """``(vehicle_class, wake)`` of a collection from its stored config (a manifest's
    ``config``): the paper's world (``PAPER_WORLD``) when it records neither."""
    cls, wake = PAPER_WORLD
    return str(config.get("vehicle_class", cls)), float(config.get("wake", wake))


def is_paper_world(config) -> bool:
    """Whether ``config`` (a :class:`CollectConfig` or its stored dict) races the paper's
    world (``PAPER_WORLD``: the 1:43 class without a wake)."""
    return collection_class(config if isinstance(config, dict) else vars(config)) == PAPER_WORLD


def _env_kwargs(config: CollectConfig) -> dict:
    """The ``RacingParallelEnv`` keywords of a race of the config: its track, cars, steps and
    start regions (:data:`START_REGIONS`, metres at 1:43, scaled to the class's car by
    :func:`racing_env.scaling.scaled_configs`: exactly as given for ``"orca"``), and its class
    and wake unless they are the paper's (then the keywords are those of the paper's races)."""
    from racing_env import StartConfig
    from racing_env.scaling import scaled_configs

    length, gap = START_REGIONS[config.start]
    start = StartConfig(
        mode="regions", lateral_jitter=config.start_jitter, region_length=length, region_gap=gap
    )
    kwargs = {
        "track": config.track,
        "n_cars": config.n_cars,
        "max_cycles": config.steps,
        "start": scaled_configs(config.vehicle_class, start=start).start,
    }
    if not is_paper_world(config):
        kwargs.update(vehicle_class=config.vehicle_class, wake=config.wake)
    return kwargs


def collection_space(space: str, vehicle_class: str = "orca") -> PolicySpace:
    """The box a collection of policy space ``space`` and ``vehicle_class`` draws its thetas
    from: the space's box with zeta's top lowered to the class's ceiling
    (:data:`ZETA_CEILING`) where it has one; the space itself (the same object) for the 1:43
    class, so the paper's draws are as they always were, bit for bit."""
    from dataclasses import replace

    from agents.reference import policy_space

    box = policy_space(space)
    ceiling = ZETA_CEILING.get(vehicle_class)
    z = box.names.index("zeta")
    if ceiling is None or ceiling >= box.high[z]:
        return box
    high = box.high.copy()
    high[z] = ceiling
    high.setflags(write=False)
    return replace(box, high=high)


def _race_draws(config: CollectConfig, race_index: int) -> tuple:
    """``(rng, order, seed, thetas)`` of race ``race_index``: its generator (the agents' seeds
    are drawn next), start order (N,), start seed and thetas (N, dim), from its own seed."""
    rng = np.random.default_rng(
        np.random.SeedSequence(config.seed).spawn(race_index + 1)[race_index]
    )
    order = rng.permutation(config.n_cars)
    seed = int(rng.integers(2**31))
    # the paper's draws are Theta.sample's, bit for bit; a class's zeta ceiling lowers the box
    space = collection_space(config.space, config.vehicle_class)
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


def rollout_from_state(
    track, state, thetas, steps: int, vehicle_class: str = "orca", wake: float | None = None
):
    """Race MPC cars with ``thetas`` (N, dim) from the joint state ``state`` (N, 6) (s
    unwrapped) for ``steps`` steps; returns (states (steps + 1, N, 6), rewards (steps, N)).

    The race is of ``vehicle_class`` (the track, a name, built at its scale; its car, rules
    and wake, ``wake`` None being the class's: a collection's :func:`collection_class`). The
    MPCs start cold (no warm start), as after a reset. Used for the simulated values of
    paired rollouts (deviations of one car's theta from the same state).
    """
    from racing_env import BatchedRaces
    from racing_env.class_config import race_config_for
    from racing_env.tracks import make_track

    state = np.asarray(state, dtype=float)
    N = state.shape[0]
    config = race_config_for(vehicle_class, wake=wake).with_(n_cars=N, max_cycles=steps)
    core = BatchedRaces(make_track(track, vehicle_class=vehicle_class), config, n_races=1)
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


#: The keys of a shard that tag its world (absent from the paper's shards).
CLASS_KEYS = ("vehicle_class", "wake")


def class_tag(config: CollectConfig) -> dict:
    """The arrays that tag a shard with the config's class and wake: none for the paper's
    world (its shards are as they always were)."""
    if is_paper_world(config):
        return {}
    return {"vehicle_class": np.array(config.vehicle_class), "wake": np.array(config.wake)}


def shard_class(z) -> tuple[str, float]:
    """``(vehicle_class, wake)`` of an open shard ``z`` (``PAPER_WORLD`` untagged)."""
    if "vehicle_class" not in z.files:
        return PAPER_WORLD
    return str(z["vehicle_class"]), float(z["wake"])


def shard_is_complete(path: Path, config: CollectConfig, shard: int) -> bool:
    """Whether the shard file at ``path`` holds shard ``shard`` of ``config``: its schema, its
    races and its vehicle class and wake (a shard of another class is redone)."""
    try:
        with np.load(path) as z:
            return (
                int(z["schema_version"]) == SCHEMA_VERSION
                and z["race_index"].tolist() == list(config.shard_races(shard))
                and shard_class(z) == (config.vehicle_class, config.wake)
            )
    except Exception:  # truncated, corrupt or foreign file: redo it
        return False


def collect(config: CollectConfig, out_dir, pool: Pool = Pool()) -> dict:
    """Simulate every missing shard on ``pool``; returns a summary.

    Local processes and Ray tasks alike run :func:`simulate_shard` and this process writes
    the shards, so the data are identical. Resumable: complete shards are skipped. The track
    is built at the config's class first, so a track of another class (``default`` for
    ``"fullsize"``) fails before anything is written.
    """
    from racing_env.tracks import make_track

    make_track(config.track, vehicle_class=config.vehicle_class)
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
        lambda k, arrays: write_shard({**arrays, **class_tag(config)}, k, out),
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
    """All shards of a collection concatenated in race order (checks the schema, and every
    shard's vehicle class and wake against the manifest's)."""
    out = Path(out_dir)
    meta = json.loads((out / "manifest.json").read_text())
    if meta["schema_version"] != SCHEMA_VERSION:
        raise ValueError(
            f"{out}: schema {meta['schema_version']}, this code reads {SCHEMA_VERSION}"
        )
    world = collection_class(meta["config"])
    parts = []
    for path in sorted(out.glob("shard_*.npz")):
        with np.load(path) as z:
            if shard_class(z) != world:
                raise ValueError(
                    f"{path}: races of the {shard_class(z)[0]!r} class with wake "
                    f"{shard_class(z)[1]:g}, the manifest says {world[0]!r} with wake {world[1]:g}"
                )
            skip = ("schema_version", *CLASS_KEYS)
            parts.append({k: z[k] for k in z.files if k not in skip})
    if not parts:
        raise ValueError(f"{out}: no shards")
    data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    data["config"] = meta["config"]
    return data
