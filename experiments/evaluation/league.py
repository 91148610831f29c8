"""Round-robin league of any set of agents, rated with openskill: ``alpha-racer league``.

**Schedule** (:func:`schedule`, deterministic from the config). A *group* is a set of
``cars`` distinct agents that race each other. With ``C(k, cars)`` (k agents) at most
``max_groups``, the groups are every ``cars``-subset of the agents, the same in every round.
Otherwise each round draws its own balanced sample (:func:`balanced_groups`): whole blocks of
a random cyclic arrangement of the agents cut into windows of ``cars``, so every agent is in
the same number of groups (pairs meet about equally often, not exactly). Every group races on
every track ``cars`` times, the start regions rotated: in rotation r car j (the group's j-th
agent) starts from region ``(j + r) mod cars`` (0 = R1, the front one), so each agent starts
from each region once per group, track and round. Races are numbered round by round, the
races of a round in a seeded random order (the online rating weighs races unequally, so no
agent, region or track may come systematically first); race k's start positions and agents'
seeds come from ``(seed, k)``. The schedule repeats ``rounds`` times with new seeds.

**Result and rating.** A race is decided by total progress (unwrapped s), as in
``alpha-racer bench``: rank 1 is the most progress, exact ties go to the lower car index.
The finishing orders are rated with openskill's Plackett-Luce model (:func:`rate`), every
agent a team of one, the races replayed in schedule order, so the ratings depend neither on
the worker count nor on the order in which races finished. The model's dynamics ``tau`` is 0:
the agents do not learn between races, so their skill is a constant to estimate, not a drift
to follow. The leaderboard is sorted by the conservative ordinal ``mu - 3 sigma``.

Output directory:

* ``manifest.json``: schema version and the :class:`LeagueConfig`; a directory of another
  config is refused.
* ``races.jsonl``: one JSON line per finished race (written by the driver as the race
  arrives, flushed and fsynced; a killed run resumes with the missing races, and a torn last
  line is dropped).
* ``leaderboard.json``, ``leaderboard.md``: :func:`leaderboard` (ratings, wins with Wilson
  95% intervals, mean finish, progress, off-track steps, decision time, the strategy metrics
  of :mod:`experiments.evaluation.metrics` (passes, passes through contact, wins from behind, time
  within 1 m behind); the pairwise matrix). A league stores no states: records written
  before the strategy metrics existed lack them, and the leaderboard says so.
* ``ratings.png`` (:func:`plot_ratings`) and ``pairwise.png`` (:func:`plot_pairwise`).
"""

from __future__ import annotations

import itertools
import json
import math
import time
import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from experiments.evaluation import metrics as race_metrics
from experiments.evaluation.bench_config import check_agent_specs
from experiments.evaluation.bench_summary import wilson_interval
from experiments.infra.artifacts import (
    ResumableRun,
    as_stored,
    check_track_specs,
    env_version,
    write_json,
    write_text,
)
from experiments.infra.parallel import Pool

SCHEMA_VERSION = 1
#: openskill Plackett-Luce parameters: the package's defaults (mu 25, sigma 25/3, beta 25/6)
#: with no dynamics (tau 0; see the module docstring).
RATING_MODEL = {
    "model": "PlackettLuce",
    "mu": 25.0,
    "sigma": 25.0 / 3.0,
    "beta": 25.0 / 6.0,
    "tau": 0.0,
}
ORDINAL_Z = 3.0
"""The leaderboard's ordinal is ``mu - ORDINAL_Z * sigma``."""
TIMING_KEYS = ("decision_ms", "seconds")
"""Record fields that are wall-clock measurements (they differ between identical reruns)."""


@dataclass(frozen=True)
class LeagueConfig:
    """One league: ``agents`` (distinct agent specs, each one player of the rating) race in
    groups of ``cars`` on each of ``tracks`` for ``steps`` control periods of 0.1 s; the
    schedule (module docstring) repeats ``rounds`` times. ``max_groups`` caps the groups per
    round (above it the groups are a balanced sample); ``seed`` fixes the sample, the start
    positions and the agents' seeds."""

    agents: tuple[str, ...]
    tracks: tuple[str, ...] = ("default",)
    cars: int = 3
    rounds: int = 1
    steps: int = 500
    seed: int = 0
    max_groups: int = 60

    def __post_init__(self):
        from racing_env.config import MAX_CARS

        object.__setattr__(self, "agents", tuple(self.agents))
        object.__setattr__(self, "tracks", tuple(self.tracks))
        for name in ("rounds", "steps", "max_groups"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"LeagueConfig.{name} must be a positive integer, got {v!r}")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise ValueError(f"LeagueConfig.seed must be a non-negative integer, got {self.seed!r}")
        if not (isinstance(self.cars, int) and 2 <= self.cars <= MAX_CARS):
            raise ValueError(
                f"cars per race must be an integer in 2..{MAX_CARS}, got {self.cars!r}"
            )
        if not all(isinstance(a, str) and a for a in self.agents):
            raise ValueError(f"agents must be agent spec strings, got {list(self.agents)}")
        twice = sorted({a for a in self.agents if self.agents.count(a) > 1})
        if twice:
            raise ValueError(
                f"agent specs must be distinct (each is one player of the rating); "
                f"given more than once: {', '.join(twice)}"
            )
        if len(self.agents) < self.cars:
            raise ValueError(
                f"{self.cars} cars per race need at least {self.cars} agent specs, "
                f"got {len(self.agents)}: {', '.join(self.agents) or 'none'}"
            )
        check_track_specs(self.tracks)

    def race_seed(self, k: int) -> int:
        """Seed of race k: its start positions and (through ``run_race``) its agents."""
        return int(np.random.SeedSequence([self.seed, k]).generate_state(1)[0])


@dataclass(frozen=True)
class ScheduledRace:
    """Race ``index`` of a league: ``agents`` (specs, car order), each car's start region
    ``order[i]`` (0 = R1), on ``track``, in ``round`` and start ``rotation``, with ``seed``."""

    index: int
    round: int
    rotation: int
    track: str
    agents: tuple[str, ...]
    order: tuple[int, ...]
    seed: int


# ---------------------------------------------------------------------------- schedule
def balanced_groups(
    n_agents: int, cars: int, max_groups: int, rng: np.random.Generator
) -> list[tuple[int, ...]]:
    """Groups of ``cars`` distinct agent indices (sorted tuples) in which every agent of
    ``range(n_agents)`` appears equally often.

    One block: a random permutation of the agents repeated ``L = cars / gcd(n_agents, cars)``
    times and cut into ``lcm(n_agents, cars) / cars`` consecutive windows of ``cars``; each
    agent is in ``L`` windows, and a window of ``cars <= n_agents`` consecutive places of a
    cyclic permutation never repeats an agent. As many blocks (each of a fresh permutation)
    as fit in ``max_groups``, at least one.
    """
    if not 1 <= cars <= n_agents:
        raise ValueError(f"groups of {cars} need 1 <= cars <= agents ({n_agents})")
    block = math.lcm(n_agents, cars) // cars
    groups = []
    for _ in range(max(1, max_groups // block)):
        ring = np.tile(rng.permutation(n_agents), cars // math.gcd(n_agents, cars))
        groups += [tuple(sorted(int(a) for a in w)) for w in ring.reshape(block, cars)]
    return groups


def round_groups(config: LeagueConfig, rnd: int) -> list[tuple[int, ...]]:
    """The groups (sorted tuples of indices into ``config.agents``) of round ``rnd``: every
    subset when there are at most ``max_groups``, else :func:`balanced_groups` drawn from
    ``(seed, rnd)``."""
    k, n = len(config.agents), config.cars
    if math.comb(k, n) <= config.max_groups:
        return list(itertools.combinations(range(k), n))
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, rnd, 1]))
    return balanced_groups(k, n, config.max_groups, rng)


def schedule(config: LeagueConfig, stages=None) -> list[ScheduledRace]:
    """Every race of the league, in schedule order (the module docstring); pure.

    ``stages``: the numbers of agents the league had as agents joined it (``[3, 4]``: three
    agents raced first, the fourth joined later; default one stage of all agents). The races
    of the first stage are those of a league of its agents alone, unchanged by later joins;
    each later stage adds only the groups that hold at least one of its new agents (every
    such group while there are at most ``max_groups``, else a sample of ``max_groups`` drawn
    from the seed), with the same rounds, rotations and tracks, numbered on from the races
    before them."""
    stages = [len(config.agents)] if stages is None else list(stages)
    if (
        stages[-1] != len(config.agents)
        or any(b <= a for a, b in zip(stages, stages[1:]))
        or stages[0] < config.cars
    ):
        raise ValueError(
            f"league stages must grow from at least {config.cars} to "
            f"{len(config.agents)} agents, got {stages}"
        )
    races = []
    n = config.cars
    first = replace(config, agents=config.agents[: stages[0]])
    for rnd in range(config.rounds):
        _add_round(races, config, rnd, round_groups(first, rnd), (config.seed, rnd, 2))
    for before, now in zip(stages, stages[1:]):
        for rnd in range(config.rounds):
            groups = [g for g in itertools.combinations(range(now), n) if g[-1] >= before]
            if len(groups) > config.max_groups:
                rng = np.random.default_rng(np.random.SeedSequence([config.seed, rnd, 3, before]))
                groups = [
                    groups[i]
                    for i in sorted(rng.choice(len(groups), config.max_groups, replace=False))
                ]
            _add_round(races, config, rnd, groups, (config.seed, rnd, 2, before))
    return races


def _add_round(races: list, config: LeagueConfig, rnd: int, groups, shuffle_key) -> None:
    """Append round ``rnd`` of ``groups`` (every rotation on every track, shuffled by
    ``shuffle_key``) to ``races``, numbered on."""
    n = config.cars
    slots = [(rot, track, g) for rot in range(n) for track in config.tracks for g in groups]
    shuffle = np.random.default_rng(np.random.SeedSequence(list(shuffle_key)))
    for i in shuffle.permutation(len(slots)):
        rot, track, g = slots[i]
        k = len(races)
        races.append(
            ScheduledRace(
                index=k,
                round=rnd,
                rotation=rot,
                track=track,
                agents=tuple(config.agents[a] for a in g),
                order=tuple((j + rot) % n for j in range(n)),
                seed=config.race_seed(k),
            )
        )


# ---------------------------------------------------------------------------- one race
def _import_once(imports) -> None:
    """Import those of the user's agent modules (names, or ``.py`` paths) that this process
    has not imported: a forked worker has them from the driver, a spawned or Ray one not."""
    import sys

    todo = [m for m in imports if (Path(m).stem if m.endswith(".py") else m) not in sys.modules]
    if todo:
        from agents import import_agent_modules

        import_agent_modules(todo)


def finish_ranks(progress) -> list[int]:
    """Finishing positions (1 = winner) by total progress [m], exact ties to the lower car
    index (the winner rule of ``alpha-racer bench``)."""
    p = np.asarray(progress, dtype=float)
    return [int(r) + 1 for r in np.argsort(np.argsort(-p, kind="stable"), kind="stable")]


def league_race(race: ScheduledRace, steps: int, imports=()) -> dict:
    """Run one scheduled race (pure: no file access) and return its record."""
    from experiments.evaluation.race import run_race

    warnings.simplefilter("ignore")
    _import_once(imports)
    t0 = time.perf_counter()
    try:
        result, _ = run_race(
            list(race.agents),
            track=race.track,
            seed=race.seed,
            max_cycles=steps,
            start="regions",
            order=list(race.order),
            progress_bar=False,
        )
    except Exception as exc:  # name the race: the traceback of a worker does not
        raise RuntimeError(
            f"league race {race.index} ({', '.join(race.agents)} on "
            f"{race.track!r}, seed {race.seed}) failed: "
            f"{type(exc).__name__}: {exc}"
        ) from exc
    if not np.isfinite(result.states).all():
        raise FloatingPointError(
            f"league race {race.index} ({', '.join(race.agents)} on "
            f"{race.track!r}) produced non-finite states"
        )
    ranks = finish_ranks(result.progress)
    return {
        "race": race.index,
        "round": race.round,
        "rotation": race.rotation,
        "track": race.track,
        "seed": race.seed,
        "agents": list(race.agents),
        "start_regions": [f"R{r + 1}" for r in race.order],
        "ranks": ranks,
        "winner": race.agents[ranks.index(1)],
        "progress_m": [round(float(v), 4) for v in result.progress],
        "contacts": result.contacts.tolist(),
        "off_tracks": result.off_tracks.tolist(),
        "decision_ms": [round(float(v), 4) for v in result.decision_ms],
        "fallbacks": [int(st.get("fallbacks", 0)) for st in result.agent_stats],
        **race_metrics.record_metrics(result.states, result.dt, result.contact_dn),
        "seconds": round(time.perf_counter() - t0, 3),
    }


# ---------------------------------------------------------------------------- rating
def rate(records: list[dict], agents) -> dict[str, tuple[float, float]]:
    """``{agent: (mu, sigma)}`` after replaying ``records`` in race-index order through
    openskill's Plackett-Luce model (:data:`RATING_MODEL`), each car a team of one ranked by
    its record's ``ranks``. Agents without races keep the prior."""
    from openskill.models import PlackettLuce

    p = RATING_MODEL
    model = PlackettLuce(mu=p["mu"], sigma=p["sigma"], beta=p["beta"], tau=p["tau"])
    ratings = {a: model.rating(name=a) for a in agents}
    for rec in sorted(records, key=lambda r: r["race"]):
        unknown = [a for a in rec["agents"] if a not in ratings]
        if unknown:
            raise ValueError(
                f"race {rec['race']} has agents {unknown} outside the league {list(ratings)}"
            )
        new = model.rate([[ratings[a]] for a in rec["agents"]], ranks=list(rec["ranks"]))
        for a, (r,) in zip(rec["agents"], new):
            ratings[a] = r
    return {a: (float(r.mu), float(r.sigma)) for a, r in ratings.items()}


def pairwise(records: list[dict], agents) -> dict:
    """For every ordered pair (a, b) of distinct agents: ``races[a][b]``, the races with both,
    and ``ahead[a][b]``, the share of them in which a finished ahead of b (``None`` if they
    never met)."""
    agents = list(agents)
    met = {a: {b: 0 for b in agents if b != a} for a in agents}
    won = {a: {b: 0 for b in agents if b != a} for a in agents}
    for rec in records:
        for (a, ra), (b, rb) in itertools.permutations(zip(rec["agents"], rec["ranks"]), 2):
            met[a][b] += 1
            won[a][b] += ra < rb
    share = {a: {b: (won[a][b] / met[a][b] if met[a][b] else None) for b in met[a]} for a in agents}
    return {"races": met, "ahead": share}


def leaderboard(records: list[dict], config: LeagueConfig) -> dict:
    """The league's standings: per agent (sorted by ordinal ``mu - 3 sigma``, best first)
    rank, mu, sigma, ordinal, races, wins, win rate with its Wilson 95% interval, mean
    finishing position, mean progress [m], mean off-track steps per race and decision time
    per act() [ms] (the median over races of a race's mean); the strategy metrics over the
    races that carry them (``strategy_races`` of them): ``passes`` and ``passes_contact``
    (totals and ``*_per_race``), ``wins_from_behind`` (count) and ``behind_1m_s`` (mean
    seconds per race), ``None`` when none of the agent's races carries them; plus
    :func:`pairwise`."""
    if not records:
        raise ValueError("no finished races to rank")
    records = sorted({r["race"]: r for r in records}.values(), key=lambda r: r["race"])
    ratings = rate(records, config.agents)
    rows = []
    for a in config.agents:
        cars = [(r, r["agents"].index(a)) for r in records if a in r["agents"]]
        mu, sigma = ratings[a]
        row = {
            "agent": a,
            "mu": mu,
            "sigma": sigma,
            "ordinal": mu - ORDINAL_Z * sigma,
            "races": len(cars),
        }
        if cars:
            wins = sum(r["ranks"][i] == 1 for r, i in cars)
            lo, hi = wilson_interval(wins, len(cars))
            mean = lambda key: float(np.mean([r[key][i] for r, i in cars]))  # noqa: B023
            row.update(
                {
                    "wins": int(wins),
                    "win_rate": wins / len(cars),
                    "win_ci95": [lo, hi],
                    "mean_finish": mean("ranks"),
                    "progress_m": mean("progress_m"),
                    "off_tracks": mean("off_tracks"),
                    # the median: a worker's first race carries the JIT and solver builds
                    "decision_ms": float(np.median([r["decision_ms"][i] for r, i in cars])),
                }
            )
        row.update(_strategy_row(cars))
        rows.append(row)
    rows.sort(key=lambda r: (-r["ordinal"], r["agent"]))
    for i, row in enumerate(rows, 1):
        row["rank"] = i
    expected = len(schedule(config))
    return {
        "config": asdict(config),
        "rating_model": dict(RATING_MODEL),
        "ordinal_z": ORDINAL_Z,
        "races": len(records),
        "races_scheduled": expected,
        "complete": len(records) == expected,
        "standings": rows,
        "pairwise": pairwise(records, [r["agent"] for r in rows]),
    }


def _strategy_row(cars) -> dict:
    """An agent's strategy metrics over its races ``cars`` ((record, car index) pairs) that
    carry them; ``None`` figures when none does (no silent zeros)."""
    have = [(r, i) for r, i in cars if all(k in r for k in race_metrics.RECORD_KEYS)]
    row = {"strategy_races": len(have)}
    if not have:
        return {
            **row,
            **dict.fromkeys(
                (
                    "passes",
                    "passes_per_race",
                    "passes_contact",
                    "passes_contact_per_race",
                    "wins_from_behind",
                    "behind_1m_s",
                )
            ),
        }
    for key in ("passes", "passes_contact"):
        tot = int(sum(r[key][i] for r, i in have))
        row[key], row[key + "_per_race"] = tot, tot / len(have)
    row["wins_from_behind"] = int(sum(r["won_from_behind"] and r["ranks"][i] == 1 for r, i in have))
    row["behind_1m_s"] = float(np.mean([r["behind_1m_s"][i] for r, i in have]))
    return row


def _f(v, fmt: str) -> str:
    return "-" if v is None else fmt.format(v)


def leaderboard_markdown(board: dict) -> str:
    c = board["config"]
    n = c["cars"]
    lines = [
        "# League",
        "",
        f"{len(c['agents'])} agents, {n} cars per race from the start regions R1-R{n} "
        f"(rotated so each agent starts from each region equally often), "
        f"{c['steps']} steps ({c['steps'] / 10:g} s) per race on "
        f"{', '.join('`' + t + '`' for t in c['tracks'])}; {c['rounds']} round(s), "
        f"seed {c['seed']}. {board['races']} of {board['races_scheduled']} races"
        + ("" if board["complete"] else " (partial)")
        + ".",
        "",
        f"Rating: openskill Plackett-Luce (mu0 {board['rating_model']['mu']:g}, sigma0 "
        f"{board['rating_model']['sigma']:.3g}, beta {board['rating_model']['beta']:.3g}, "
        f"tau {board['rating_model']['tau']:g}) over the finishing orders by total "
        f"progress, replayed in schedule order; ranked by the ordinal mu - "
        f"{board['ordinal_z']:g} sigma. Wins with Wilson 95% intervals (chance: 1/{n}).",
        "",
        "| rank | agent | ordinal | mu | sigma | races | wins | win rate | mean finish "
        "| progress m | off-track steps | ms/decision (median) | passes/race "
        "| via contact/race | wins from behind | <= 1 m behind s/race |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in board["standings"]:
        if not r["races"]:
            lines.append(
                f"| {r['rank']} | `{r['agent']}` | {r['ordinal']:.2f} | {r['mu']:.2f} "
                f"| {r['sigma']:.2f} | 0 | - | - | - | - | - | - | - | - | - | - |"
            )
            continue
        lo, hi = r["win_ci95"]
        lines.append(
            f"| {r['rank']} | `{r['agent']}` | {r['ordinal']:.2f} | {r['mu']:.2f} "
            f"| {r['sigma']:.2f} | {r['races']} | {r['wins']} "
            f"| {100 * r['win_rate']:.0f}% ({100 * lo:.0f}-{100 * hi:.0f}%) "
            f"| {r['mean_finish']:.2f} | {r['progress_m']:.2f} | {r['off_tracks']:.1f} "
            f"| {r['decision_ms']:.2f} | {_f(r.get('passes_per_race'), '{:.2f}')} "
            f"| {_f(r.get('passes_contact_per_race'), '{:.2f}')} "
            f"| {_f(r.get('wins_from_behind'), '{}')} "
            f"| {_f(r.get('behind_1m_s'), '{:.1f}')} |"
        )
    partial = [
        r for r in board["standings"] if r["races"] and r.get("strategy_races", 0) < r["races"]
    ]
    if partial:
        lines += [
            "",
            "Strategy metrics (passes held 1 s and clear sideways; wins from behind; "
            "time within 1 m behind) missing for some races, recorded before they "
            "existed (a league stores no states to recompute them): "
            + ", ".join(
                f"`{r['agent']}` over {r.get('strategy_races', 0)} of {r['races']} races"
                for r in partial
            )
            + ".",
        ]
    pw = board["pairwise"]
    names = [r["agent"] for r in board["standings"]]
    lines += [
        "",
        "## Pairwise",
        "",
        "Row a, column b: the share of the races with both in which a finished ahead of "
        "b (races together in brackets).",
        "",
        "| a \\ b | " + " | ".join(f"`{b}`" for b in names) + " |",
        "|---|" + "---|" * len(names),
    ]
    for a in names:
        cells = [
            "" if a == b else f"{_f(pw['ahead'][a][b], '{:.2f}')} ({pw['races'][a][b]})"
            for b in names
        ]
        lines.append(f"| `{a}` | " + " | ".join(cells) + " |")
    lines += ["", "![ratings](ratings.png)", "", "![pairwise](pairwise.png)"]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------- figures
def _figure(size):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)  # the Agg canvas directly: the global backend is left alone
    return fig


def plot_ratings(board: dict, path, dpi: int = 120) -> Path:
    """PNG of every agent's mu with a +-2 sigma bar and its ordinal (mu - 3 sigma), in
    leaderboard order (best at the top)."""
    rows = board["standings"]
    y = np.arange(len(rows))[::-1]
    mu = np.array([r["mu"] for r in rows])
    sigma = np.array([r["sigma"] for r in rows])
    fig = _figure((7, 1.2 + 0.45 * len(rows)))
    ax = fig.subplots()
    ax.errorbar(mu, y, xerr=2 * sigma, fmt="o", capsize=4, label="mu +- 2 sigma")
    ax.plot(
        mu - board["ordinal_z"] * sigma,
        y,
        "x",
        color="0.4",
        label=f"ordinal mu - {board['ordinal_z']:g} sigma",
    )
    ax.set_yticks(y, [r["agent"] for r in rows])
    ax.set_xlabel("openskill Plackett-Luce rating")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower right", fontsize="small")
    ax.set_title(f"League ratings, {board['races']} races")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return Path(path)


def plot_pairwise(board: dict, path, dpi: int = 120) -> Path:
    """PNG of the pairwise matrix: row a, column b, the share of their common races in which
    a finished ahead of b (blank where they never met), in leaderboard order."""
    names = [r["agent"] for r in board["standings"]]
    ahead = board["pairwise"]["ahead"]
    m = np.array(
        [[np.nan if a == b or ahead[a][b] is None else ahead[a][b] for b in names] for a in names]
    )
    k = len(names)
    fig = _figure((2.5 + 0.8 * k, 2 + 0.7 * k))
    ax = fig.subplots()
    mesh = ax.imshow(np.ma.masked_invalid(m), cmap="RdBu", vmin=0.0, vmax=1.0)
    for i in range(k):
        for j in range(k):
            if np.isfinite(m[i, j]):
                ax.text(
                    j,
                    i,
                    f"{m[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize="small",
                    color="white" if abs(m[i, j] - 0.5) > 0.3 else "black",
                )
    ax.set_xticks(range(k), names, rotation=45, ha="right")
    ax.set_yticks(range(k), names)
    ax.set_xlabel("b")
    ax.set_ylabel("a")
    fig.colorbar(mesh, ax=ax, label="share of races a ahead of b")
    ax.set_title("Pairwise finishing order")
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    return Path(path)


# ---------------------------------------------------------------------------- storage
class LeagueRun(ResumableRun):
    """The output directory of one league (see the module docstring)."""

    what = "a league"
    records_name = "races.jsonl"

    def __init__(self, out_dir, config: LeagueConfig):
        super().__init__(out_dir, config)
        self.stages, joining = self._stages(self.manifest_path, config)
        self.races = schedule(config, self.stages)
        meta = {"schema_version": SCHEMA_VERSION, "config": asdict(config), "env": env_version()}
        if len(self.stages) > 1:
            meta["stages"] = self.stages
        # agents join: the stored manifest is of the league before them
        stored = None
        if joining:
            stored = {
                k: v
                for k, v in json.loads(self.manifest_path.read_text()).items()
                if k != "provenance"
            }
        self.claim(meta, config.agents, config.tracks, stored=stored)

    @staticmethod
    def _stages(manifest: Path, config: LeagueConfig) -> tuple[list[int], bool]:
        """The league's stages (see :func:`schedule`) and whether agents join now: the stored
        stages, plus one when ``config`` adds agents to the stored league (its agents first,
        in their order, every other setting equal); a league of another configuration is left
        for :func:`claim` to refuse."""
        if not manifest.exists():
            return [len(config.agents)], False
        stored = json.loads(manifest.read_text())
        old = stored.get("config", {})
        stages = list(stored.get("stages") or [len(old.get("agents", []))])
        now = as_stored(asdict(config))
        old_agents, new_agents = old.get("agents", []), now["agents"]
        same_rest = {k: v for k, v in old.items() if k != "agents"} == {
            k: v for k, v in now.items() if k != "agents"
        }
        if (
            same_rest
            and len(new_agents) > len(old_agents)
            and new_agents[: len(old_agents)] == old_agents
        ):
            return stages + [len(new_agents)], True
        return (stages if old_agents == new_agents else [len(config.agents)]), False

    def tasks(self) -> list[ScheduledRace]:
        return self.races

    def task_key(self, task: ScheduledRace) -> int:
        return task.index

    def record_key(self, record: dict) -> int:
        return record["race"]

    def check_record(self, record: dict) -> bool:
        """A record that is not the scheduled race of its index (agents, track, seed) is an
        error: the schedule has changed since it was written."""
        k = record.get("race")
        race = self.races[k] if isinstance(k, int) and 0 <= k < len(self.races) else None
        if race is None or (record["agents"], record["track"], record["seed"]) != (
            list(race.agents),
            race.track,
            race.seed,
        ):
            raise ValueError(
                f"{self.records_path}: race {k} is not the race this league "
                f"schedules there (written by another version?); use "
                f"another --out"
            )
        return True

    def write_outputs(self) -> dict:
        board = leaderboard(list(self.records().values()), self.config)
        write_json(self.out / "leaderboard.json", board)
        write_text(self.out / "leaderboard.md", leaderboard_markdown(board))
        plot_ratings(board, self.out / "ratings.png")
        plot_pairwise(board, self.out / "pairwise.png")
        return board


def check_tracks(tracks, cars: int) -> None:
    """Build each track and its ``cars`` start regions once, so a bad track spec or a track
    too short for the regions fails before any race starts."""
    from racing_env.config import StartConfig, VehicleParams
    from racing_env.core import start_states
    from racing_env.tracks import make_track

    for spec in tracks:
        try:
            start_states(
                make_track(spec),
                cars,
                StartConfig(mode="regions"),
                VehicleParams().width,
                np.random.default_rng(0),
            )
        except (ValueError, FileNotFoundError, KeyError) as exc:
            msg = str(exc)
            raise ValueError(msg if repr(spec) in msg else f"track {spec!r}: {msg}") from None


def check_field(agents, cars: int, track: str) -> None:
    """Let each agent take one decision in a field of ``cars`` cars on ``track`` (the others
    raceline followers), so an agent that cannot race that many cars (an alpha-potential model
    trained for another number) fails before any race of the league starts."""
    from experiments.evaluation.race import run_race

    for spec in agents:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                run_race(
                    [spec] + ["raceline"] * (cars - 1),
                    track=track,
                    max_cycles=1,
                    start="regions",
                    order=list(range(cars)),
                    progress_bar=False,
                )
        except Exception as exc:
            exc = getattr(exc, "agent_error", exc)  # this message names the agent already
            raise ValueError(
                f"agent {spec!r} cannot race in a field of {cars} cars on "
                f"{track!r}: {type(exc).__name__}: {exc}"
            ) from None


def league(
    config: LeagueConfig,
    out_dir,
    pool: Pool = Pool(),
    imports=(),
) -> dict:
    """Run (or resume) the league ``config`` into ``out_dir``; returns its leaderboard with
    ``new_races``, the number of races run by this call. ``imports`` (module names or ``.py``
    paths, as ``--import``) are imported in every worker before its first race."""
    imports = tuple(str(Path(m).resolve()) if m.endswith(".py") else m for m in imports)
    _import_once(imports)
    check_agent_specs(config.agents, config.tracks)
    check_tracks(config.tracks, config.cars)
    check_field(config.agents, config.cars, config.tracks[0])
    run = LeagueRun(out_dir, config)
    new = run.run_missing(
        league_race,
        lambda race: (race, config.steps, imports),
        pool,
        desc="league",
        unit="race",
        postfix=lambda k, rec: f"{k}:{rec['winner']}",
    )
    board = run.write_outputs()
    board["new_races"] = new
    return board
