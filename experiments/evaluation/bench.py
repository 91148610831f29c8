"""Head-to-head benchmark (the paper's Table 1): ``alpha-racer bench``.

The paper's protocol: three cars, the ego against two opponents of one kind, ``races`` races
(99) of ``steps`` control periods (500 x 0.1 s = 50 s). Race k puts the ego in start region
R1, R2, R3 for k = 0, 1, 2 (mod 3), so 99 races give 33 per region; of the two other regions
opponent O1 always takes the front one, O2 the back one. Cars: car_0 ego, car_1 O1, car_2 O2.
A race is won by the largest total progress along the track (unwrapped s).

Scaled to N cars (``--cars N``, 2..8): N start regions R1..RN, race k puts the ego in
R(k mod N + 1) (so ``races`` must be a multiple of N: every region equally often), and the
opponents O1..O(N-1) take the other regions front to back. N = 3 is the paper's protocol,
race for race (same seeds, same start orders, same outputs).

Output directory:

* ``manifest.json``: schema version and the :class:`BenchConfig`; a directory of another
  config is refused.
* ``races.jsonl``: one JSON line per finished race (written by the driver as the race
  arrives, flushed and fsynced; a killed run resumes with the missing races, and a torn last
  line is dropped).
* ``states/race_00000.npz``: every car's Frenet state per step (float32, (T + 1, 3, 6)),
  for animations of the benchmark's own races.
* ``summary.json`` and ``summary.md``: :func:`summarise`.

Every record carries the race's strategy metrics (:mod:`experiments.evaluation.metrics`: passes per car,
passes through contact, whether the winner came from behind, time within 1 m behind),
computed from the stored float32 states; a folder written before they existed gets them
recomputed from its ``states/`` when summarised.

``ego_regions`` (``alpha-racer strategy``) fixes the ego's start region per race instead of
the rotation: race k puts the ego in ``ego_regions[k mod len]``.

``alpha-racer bench --paper-table`` runs the paper's five cases (:data:`PAPER_CASES`) with one
pool over all their races and writes ``paper_table.md`` beside the paper's numbers.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from experiments.evaluation import metrics as race_metrics
from experiments.infra.artifacts import (
    ResumableRun,
    append_jsonl,
    env_version,
    read_jsonl,
    run_missing,
    write_json,
    write_npz,
    write_text,
)
from experiments.infra.parallel import Pool

SCHEMA_VERSION = 1
ROLES = ("ego", "O1", "O2")
REGIONS = ("R1", "R2", "R3")


def roles(n_cars: int = 3) -> tuple[str, ...]:
    """Names of the cars of an N-car benchmark: ``ego``, ``O1`` .. ``O(N-1)``."""
    return ("ego",) + tuple(f"O{k}" for k in range(1, n_cars))


def regions(n_cars: int = 3) -> tuple[str, ...]:
    """Start regions ``R1`` (front-most) .. ``RN``."""
    return tuple(f"R{k}" for k in range(1, n_cars + 1))


@dataclass(frozen=True)
class PaperCase:
    opponents: str
    title: str
    paper_wins: tuple[int, int, int]  # the paper's Table 1: ego, O1, O2 wins of 99


#: The paper's Table 1, ego = ``alpha`` (gamma 0.99, 4000 races) in every case.
PAPER_CASES = {
    "I": PaperCase(
        "alpha:model=gamma0.98", "Opponents with low gamma (alpha, gamma 0.98)", (61, 28, 10)
    ),
    "II": PaperCase(
        "alpha:model=gamma0.995", "Opponents with high gamma (alpha, gamma 0.995)", (52, 40, 7)
    ),
    "III": PaperCase(
        "alpha:model=races400", "Opponents trained with less data (alpha, 400 races)", (76, 16, 7)
    ),
    "IV": PaperCase("ibr", "Opponents using IBR (6 rounds, 2 s horizon)", (73, 22, 4)),
    "V": PaperCase("ppo", "Opponents trained by self-play RL (PPO)", (91, 7, 1)),
}


def paper_cases(space: str = "paper") -> dict[str, PaperCase]:
    """The paper's five cases in policy space ``space``: :data:`PAPER_CASES` in the paper's
    space; in another, the learned opponents of cases I-III are that space's variants of the
    same kind (``alpha:model=gamma0.98`` becomes ``alpha:space=extended,model=
    extended_gamma0.98``: same discount or data, trained on the space's races), while IBR
    and PPO stay as they are."""
    from agents.reference import policy_space

    space = policy_space(space).name  # names the choices if unknown
    if space == "paper":
        return dict(PAPER_CASES)
    prefix = "alpha:model="
    out = {}
    for name, case in PAPER_CASES.items():
        if case.opponents.startswith(prefix):
            model = case.opponents[len(prefix) :]
            case = PaperCase(
                f"alpha:space={space},model={space}_{model}",
                case.title.replace("(alpha,", f"(alpha, {space} space,"),
                case.paper_wins,
            )
        out[name] = case
    return out


@dataclass(frozen=True)
class BenchConfig:
    """One head-to-head benchmark: ``ego`` (an agent spec) against ``n_cars - 1``
    ``opponents`` (one agent spec, used for O1, O2, ...) in ``races`` races of ``steps`` steps
    on ``track``. Race k's start positions and the agents' seeds come from ``(seed, k)``.
    With N != 3 cars, ``races`` must be a multiple of N (the ego starts from every region
    equally often); the paper's 3-car benchmark takes any count, as it always has.
    ``ego_regions`` (region names, e.g. ``("R2", "R3")``) replaces the ego's rotation through
    every region by a cycle through these (any race count; :meth:`order`)."""

    ego: str = "alpha"
    opponents: str = "mpc"
    races: int = 99
    steps: int = 500
    track: str = "default"
    seed: int = 0
    n_cars: int = 3
    ego_regions: tuple[str, ...] | None = None

    def __post_init__(self):
        for name in ("races", "steps"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"BenchConfig.{name} must be a positive integer, got {v!r}")
        if isinstance(self.n_cars, bool) or not (
            isinstance(self.n_cars, int) and 2 <= self.n_cars <= 8
        ):
            raise ValueError(f"BenchConfig.n_cars must be an integer in 2..8, got {self.n_cars!r}")
        if self.ego_regions is not None:
            object.__setattr__(self, "ego_regions", tuple(self.ego_regions))
            bad = [r for r in self.ego_regions if r not in self.regions]
            if not self.ego_regions or bad:
                raise ValueError(
                    f"BenchConfig.ego_regions must be a non-empty sequence of "
                    f"start regions of {', '.join(self.regions)}, got "
                    f"{list(self.ego_regions)}"
                )
        elif self.n_cars != 3 and self.races % self.n_cars:
            raise ValueError(
                f"BenchConfig.races must be a multiple of n_cars = {self.n_cars} "
                f"(every start region equally often), got {self.races}"
            )
        check_spec_fields(self, ("ego", "opponents"))

    @property
    def agents(self) -> list[str]:
        return [self.ego] + [self.opponents] * (self.n_cars - 1)

    @property
    def roles(self) -> tuple[str, ...]:
        return roles(self.n_cars)

    @property
    def regions(self) -> tuple[str, ...]:
        return regions(self.n_cars)

    def to_dict(self) -> dict:
        """The config as stored in manifests and summaries; the 3-car default of ``n_cars``
        is left out, so the paper's benchmarks keep the manifests they always had."""
        d = asdict(self)
        if d["n_cars"] == 3:
            del d["n_cars"]
        if d["ego_regions"] is None:
            del d["ego_regions"]
        else:
            d["ego_regions"] = list(d["ego_regions"])
        return d

    def race_seed(self, k: int) -> int:
        return int(np.random.SeedSequence([self.seed, k]).generate_state(1)[0])

    @staticmethod
    def start_order(k: int, n_cars: int = 3) -> list[int]:
        """Start regions (0 = R1) of ego, O1, O2, ... in race k: the ego cycles R1 .. RN and
        the opponents take the other regions front to back (O1 the front-most)."""
        ego = k % n_cars
        return [ego] + [r for r in range(n_cars) if r != ego]

    def order(self, k: int) -> list[int]:
        """Start regions (0 = R1) of ego, O1, O2, ... in race k of this benchmark:
        :meth:`start_order`, or with ``ego_regions`` the ego in ``ego_regions[k mod len]``
        and the opponents in the other regions front to back."""
        if self.ego_regions is None:
            return self.start_order(k, self.n_cars)
        ego = self.regions.index(self.ego_regions[k % len(self.ego_regions)])
        return [ego] + [r for r in range(self.n_cars) if r != ego]


def check_spec_fields(config: object, names: Sequence[str]) -> None:
    """Raise a ValueError naming the first field of ``config`` among ``names`` that is not
    an agent spec string (a non-empty ``str``)."""
    for name in names:
        if not isinstance(getattr(config, name), str) or not getattr(config, name):
            raise ValueError(
                f"{type(config).__name__}.{name} must be an agent spec string, "
                f"got {getattr(config, name)!r}"
            )


def check_agent_specs(specs, tracks=()) -> None:
    """Build each agent spec once, so a typo fails before any race starts; an agent with a
    ``check_track(track)`` method (``mpc:theta=best``: the track's entry in the best-theta
    table) checks each of ``tracks`` too."""
    from agents import make_agent_spec

    for spec in dict.fromkeys(specs):
        agent = make_agent_spec(spec)
        check = getattr(agent, "check_track", None)
        for track in dict.fromkeys(tracks) if check is not None else ():
            try:
                check(track)
            except ValueError as exc:
                raise ValueError(f"agent {spec!r}: {exc}") from None


def bench_race(config: BenchConfig, k: int) -> dict:
    """Race k of the benchmark (pure: no file access); returns its record and states."""
    from experiments.evaluation.race import run_race

    warnings.simplefilter("ignore")
    t0 = time.perf_counter()
    seed, order = config.race_seed(k), config.order(k)
    result, _ = run_race(
        config.agents,
        track=config.track,
        seed=seed,
        max_cycles=config.steps,
        start="regions",
        order=order,
        progress_bar=False,
    )
    if not np.isfinite(result.states).all():
        raise FloatingPointError(f"benchmark race {k} produced non-finite states")
    p = result.progress
    winner = int(np.argmax(p))
    states = result.states.astype(np.float32)
    reg = config.regions
    record = {
        "race": k,
        "seed": seed,
        "ego_region": reg[order[0]],
        "start_regions": [reg[r] for r in order],
        "agents": config.agents,
        "winner": config.roles[winner],
        "progress_m": [round(float(v), 4) for v in p],
        "margin_m": round(float(p[0] - max(p[1:])), 4),
        "ranks": [int(r) for r in np.argsort(np.argsort(-p, kind="stable"), kind="stable") + 1],
        "contacts": result.contacts.tolist(),
        "off_tracks": result.off_tracks.tolist(),
        "decision_ms": [round(float(v), 4) for v in result.decision_ms],
        "fallbacks": [int(st.get("fallbacks", 0)) for st in result.agent_stats],
        # from the states as stored, so a summary recomputing them finds the same numbers
        **race_metrics.record_metrics(states, result.dt, result.contact_dn),
        "seconds": round(time.perf_counter() - t0, 3),
    }
    return {"record": record, "states": states}


# ---------------------------------------------------------------------------- storage
class BenchRun(ResumableRun):
    """The output directory of one benchmark (see the module docstring)."""

    what = "a benchmark"
    records_name = "races.jsonl"

    def __init__(self, out_dir, config: BenchConfig):
        super().__init__(out_dir, config)
        (self.out / "states").mkdir(exist_ok=True)
        self.claim(
            {"schema_version": SCHEMA_VERSION, "config": config.to_dict(), "env": env_version()},
            config.agents,
            [config.track],
        )

    @classmethod
    def open(cls, out_dir) -> BenchRun:
        """The benchmark stored in ``out_dir``, to read (its races and states): the config
        comes from its manifest and nothing is written, where constructing a run claims the
        folder and records this commit's provenance in it."""
        out = Path(out_dir)
        config = BenchConfig(**json.loads((out / cls.manifest_name).read_text())["config"])
        run = cls.__new__(cls)
        ResumableRun.__init__(run, out, config)
        return run

    def tasks(self) -> list[int]:
        return list(range(self.config.races))

    def record_key(self, record: dict) -> int:
        return record["race"]

    def check_record(self, record: dict) -> bool:
        return self._states_path(record["race"]).exists()

    def add(self, result: dict) -> None:
        """Store one race: states first, then its JSON line (a line means a complete race)."""
        rec = result["record"]
        write_npz(self._states_path(rec["race"]), compressed=True, states=result["states"])
        super().add(rec)

    def _states_path(self, k: int) -> Path:
        return self.out / "states" / f"race_{k:05d}.npz"

    def states(self, k: int) -> np.ndarray:
        with np.load(self._states_path(k)) as z:
            return z["states"]

    def records_with_metrics(self) -> dict[int, dict]:
        """:meth:`records`, each with its strategy metrics: those of a record written before
        they existed are computed from its stored states (with the default race config's
        ``dt`` and contact box, the only ones a benchmark races with)."""
        out = self.records()
        for k, rec in out.items():
            if any(key not in rec for key in race_metrics.RECORD_KEYS):
                out[k] = {**rec, **race_metrics.record_metrics(self.states(k), *_race_dt_dn())}
        return out

    def write_summary(self) -> dict:
        summary = summarise(list(self.records_with_metrics().values()), self.config)
        write_json(self.out / "summary.json", summary)
        write_text(self.out / "summary.md", summary_markdown(summary))
        return summary


# ---------------------------------------------------------------------------- statistics
def wilson_interval(wins: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval (95% by default) of a binomial proportion ``wins / n``."""
    if n <= 0:
        raise ValueError(f"wilson_interval needs n >= 1 trials, got {n}")
    if not 0 <= wins <= n:
        raise ValueError(f"wins must be in [0, n={n}], got {wins}")
    p = wins / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    lo = 0.0 if wins == 0 else max(0.0, min(p, centre - half))  # exact ends (no 1 - 1e-16)
    hi = 1.0 if wins == n else min(1.0, max(p, centre + half))
    return float(lo), float(hi)


def win_share(wins: int, races: int) -> dict:
    """``{"wins", "races", "fraction", "ci95"}``: a win count with its Wilson 95% interval."""
    lo, hi = wilson_interval(wins, races)
    return {"wins": int(wins), "races": int(races), "fraction": wins / races, "ci95": [lo, hi]}


def _race_dt_dn() -> tuple[float, float]:
    """(dt [s], contact_dn [m]) of the default race config."""
    from racing_env.config import RaceConfig

    c = RaceConfig()
    return c.dt, c.rules.contact_dn


def _wins(records, role) -> dict:
    return win_share(sum(r["winner"] == role for r in records), len(records))


def summarise(records: list[dict], config: BenchConfig) -> dict:
    """Win counts per car and per ego start region (Wilson 95% intervals), progress margins
    (ego minus the best opponent, m), contacts, off-track steps, decision times and fallbacks
    per car (means per race)."""
    if not records:
        raise ValueError("no finished races to summarise")
    records = sorted(records, key=lambda r: r["race"])
    n = len(records)
    arr = lambda key: np.array([r[key] for r in records], dtype=float)  # (n, N)
    margin = arr("margin_m")
    names = config.roles
    out = {
        "config": config.to_dict(),
        "races": n,
        "complete": n == config.races,
        "wins": {role: _wins(records, role) for role in names},
        "by_region": {},
    }
    for reg in config.regions:
        sub = [r for r in records if r["ego_region"] == reg]
        if sub:
            out["by_region"][reg] = {role: _wins(sub, role) for role in names}
            out["by_region"][reg]["margin_m_mean"] = float(np.mean([r["margin_m"] for r in sub]))
    out["margin_m"] = {
        "mean": float(margin.mean()),
        "median": float(np.median(margin)),
        "std": float(margin.std()),
    }
    for key in ("progress_m", "contacts", "off_tracks", "decision_ms", "fallbacks"):
        a = arr(key)
        out[key] = dict(zip(names, map(float, a.mean(axis=0))))
    out["decision_ms_max_race_mean"] = dict(zip(names, map(float, arr("decision_ms").max(axis=0))))
    out["race_seconds_total"] = float(sum(r["seconds"] for r in records))
    out["strategy"] = strategy_summary(records, names, config.regions)
    return out


def strategy_summary(records: list[dict], names, region_names) -> dict:
    """The strategy metrics of benchmark ``records`` (:mod:`experiments.evaluation.metrics`), per car
    (``names``: ego, O1, ...): ``passes``, ``passes_contact`` and ``fell_back`` (totals
    and means per race), ``wins_from_behind`` (count), ``behind_1m_s`` (mean seconds per race);
    ``wins_by_start_region`` (races won by the car that started in each region, R2.. being
    wins from behind); and per ego start region (``by_region``) the ego's and opponents'
    passes and wins from behind. Over the records that carry the metrics; ``races`` counts
    them and ``missing`` the others (recorded before the metrics existed, without states):
    with none, every figure is ``None``, never a zero."""
    have = [r for r in records if all(k in r for k in race_metrics.RECORD_KEYS)]
    out = {
        "definition": race_metrics.definition(*_race_dt_dn()),
        "races": len(have),
        "missing": len(records) - len(have),
    }
    keys = (
        "passes",
        "passes_per_race",
        "passes_contact",
        "passes_contact_per_race",
        "fell_back",
        "wins_from_behind",
        "behind_1m_s",
        "wins_by_start_region",
        "by_region",
    )
    if not have:
        return {**out, **dict.fromkeys(keys)}
    n = len(have)
    names = list(names)

    def per_car(key, sub):
        return np.array([r[key] for r in sub], dtype=float).sum(axis=0)

    def wfb(sub):
        return {
            role: int(sum(r["won_from_behind"] and r["winner"] == role for r in sub))
            for role in names
        }

    for key in ("passes", "passes_contact", "fell_back"):
        tot = per_car(key, have)
        out[key] = dict(zip(names, map(int, tot)))
        if key != "fell_back":
            out[key + "_per_race"] = dict(zip(names, map(float, tot / n)))
    out["wins_from_behind"] = wfb(have)
    out["behind_1m_s"] = dict(zip(names, map(float, per_car("behind_1m_s", have) / n)))
    out["wins_by_start_region"] = {
        reg: int(sum(r["start_regions"][names.index(r["winner"])] == reg for r in have))
        for reg in region_names
    }
    out["by_region"] = {}
    for reg in region_names:
        sub = [r for r in have if r["ego_region"] == reg]
        if sub:
            out["by_region"][reg] = {
                "races": len(sub),
                "passes": dict(zip(names, map(int, per_car("passes", sub)))),
                "wins_from_behind": wfb(sub),
            }
    return out


def _pct(w: dict) -> str:
    return f"{w['wins']}/{w['races']} ({100 * w['ci95'][0]:.0f}-{100 * w['ci95'][1]:.0f}%)"


def summary_markdown(s: dict) -> str:
    c = s["config"]
    N = c.get("n_cars", 3)
    names = roles(N)
    many = "two" if N == 3 else str(N - 1)
    lines = [
        f"# Benchmark: `{c['ego']}` vs {many} `{c['opponents']}`",
        "",
        f"{s['races']} of {c['races']} races, {c['steps']} steps each on `{c['track']}`, "
        f"seed {c['seed']}. Wins with Wilson 95% intervals.",
        "",
        "| | " + " | ".join(names) + " |",
        "|---" * (N + 1) + "|",
        "| wins (all) | " + " | ".join(_pct(s["wins"][r]) for r in names) + " |",
    ]
    for reg, w in s["by_region"].items():
        lines.append(f"| wins, ego from {reg} | " + " | ".join(_pct(w[r]) for r in names) + " |")
    for key, label, fmt in (
        ("progress_m", "progress per race [m]", "{:.2f}"),
        ("contacts", "contact steps per race", "{:.2f}"),
        ("off_tracks", "off-track steps per race", "{:.2f}"),
        ("fallbacks", "fallbacks per race", "{:.2f}"),
        ("decision_ms", "mean decision time [ms]", "{:.2f}"),
    ):
        lines.append(f"| {label} | " + " | ".join(fmt.format(s[key][r]) for r in names) + " |")
    lines += strategy_rows(s.get("strategy"), names)
    m = s["margin_m"]
    lines += [
        "",
        f"Ego margin over the best opponent: mean {m['mean']:.2f} m, median "
        f"{m['median']:.2f} m, std {m['std']:.2f} m.",
    ]
    lines += strategy_note(s.get("strategy"), s["races"])
    return "\n".join(lines) + "\n"


def strategy_rows(st: dict | None, names) -> list[str]:
    """Rows of the summary table for :func:`strategy_summary` (``-`` where missing)."""
    have = st is not None and st.get("passes") is not None
    rows = []
    for key, label, fmt in (
        ("passes_per_race", "passes per race (held 1 s, clear sideways)", "{:.2f}"),
        ("passes_contact_per_race", "passes through contact per race", "{:.2f}"),
        ("wins_from_behind", "wins from behind", "{}"),
        ("behind_1m_s", "time within 1 m behind [s per race]", "{:.1f}"),
    ):
        cells = [fmt.format(st[key][r]) if have else "-" for r in names]
        rows.append(f"| {label} | " + " | ".join(cells) + " |")
    return rows


def strategy_note(st: dict | None, races: int) -> list[str]:
    """A line saying over which races the strategy metrics were taken, or that they are
    missing (old records without states)."""
    if st is None or not st.get("races"):
        return [
            "",
            f"Strategy metrics missing for all {races} races (recorded before they "
            f"existed, and no stored states to compute them from).",
        ]
    lines = [
        "",
        "Wins by the winner's start region: "
        + ", ".join(f"{reg} {w}" for reg, w in st["wins_by_start_region"].items())
        + " (from R2 and behind: wins from behind).",
    ]
    if st["missing"]:
        lines.append(
            f"Strategy metrics over {st['races']} of {races} races; "
            f"{st['missing']} lack them (recorded before they existed, no states)."
        )
    return lines


# ---------------------------------------------------------------------------- drivers
def _run_many(runs: dict, pool: Pool) -> None:
    """Run the missing races of every :class:`BenchRun` in ``runs`` (name -> run) in one pool."""
    run_missing(
        runs,
        bench_race,
        lambda run, k: (run.config, k),
        pool,
        desc="bench",
        unit="race",
        postfix=lambda key, result: f"{key[0]}:{result['record']['winner']}",
    )


def bench(config: BenchConfig, out_dir, pool: Pool = Pool()) -> dict:
    """Run (or resume) one benchmark into ``out_dir`` on ``pool``; returns its summary."""
    check_agent_specs(config.agents, [config.track])
    run = BenchRun(out_dir, config)
    _run_many({"bench": run}, pool)
    return run.write_summary()


def paper_table(
    out_dir,
    ego: str = "alpha",
    races: int = 99,
    steps: int = 500,
    track: str = "default",
    seed: int = 0,
    cases=None,
    pool: Pool = Pool(),
    space: str = "paper",
) -> dict:
    """The paper's five cases (or ``cases``, names of :data:`PAPER_CASES`) with the
    opponents of policy space ``space`` (:func:`paper_cases`) in ``out_dir/case_<name>``, all
    races in one pool; writes ``out_dir/paper_table.md`` and ``paper_table.json`` and returns
    the latter's content."""
    from agents.reference import policy_space

    space = policy_space(space).name  # the name, as paper_table.json records it
    table_cases = paper_cases(space)
    cases = list(table_cases) if cases is None else list(cases)
    unknown = [c for c in cases if c not in table_cases]
    if unknown:
        raise ValueError(f"unknown paper cases {unknown}; choose from {list(table_cases)}")
    out = Path(out_dir)
    configs = {
        c: BenchConfig(
            ego=ego,
            opponents=table_cases[c].opponents,
            races=races,
            steps=steps,
            track=track,
            seed=seed,
        )
        for c in cases
    }
    check_agent_specs([ego] + [cfg.opponents for cfg in configs.values()], [track])
    runs = {c: BenchRun(out / f"case_{c}", cfg) for c, cfg in configs.items()}
    todo = sum(len(run.missing()) for run in runs.values())
    t0 = time.perf_counter()
    _run_many(runs, pool)
    wall = time.perf_counter() - t0
    history = out / "runs.jsonl"
    if todo:  # every invocation that raced: the table's total wall time
        append_jsonl(
            history,
            {
                "cases": cases,
                "races_simulated": todo,
                "wall_seconds": wall,
                "workers": pool.workers,
                "backend": pool.backend,
                "finished": time.strftime("%Y-%m-%dT%H:%M:%S"),
            },
        )
    past = read_jsonl(history)
    table = {
        "ego": ego,
        "space": space,
        "races": races,
        "steps": steps,
        "track": track,
        "seed": seed,
        "workers": pool.workers,
        "backend": pool.backend,
        "wall_seconds_this_run": wall,
        "runs": past,
        "cases": {
            c: {
                "opponents": table_cases[c].opponents,
                "title": table_cases[c].title,
                "paper_wins": list(table_cases[c].paper_wins),
                "summary": runs[c].write_summary(),
            }
            for c in cases
        },
    }
    write_json(out / "paper_table.json", table)
    write_text(out / "paper_table.md", paper_table_markdown(table))
    return table


def paper_table_markdown(table: dict) -> str:
    lines = [
        "# Head-to-head benchmark: the paper's Table 1",
        "",
        f"Ego `{table['ego']}` against two opponents of one kind; {table['races']} races per "
        f"case of {table['steps']} steps ({table['steps'] / 10:.0f} s), the ego starting "
        f"from R1, R2, R3 in turn (race k from R(k mod 3 + 1)), O1 always ahead of O2; "
        f"won by the largest "
        f"total progress. Wins with Wilson 95% intervals; `paper` is the paper's Table 1.",
        "",
        "| case | opponents | ego wins | O1 wins | O2 wins | paper (ego/O1/O2) "
        "| ego wins from R1 / R2 / R3 | ego margin m | contacts ego/opp | off-track ego/opp "
        "| ms/decision ego/opp |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c, case in table["cases"].items():
        s = case["summary"]
        w = s["wins"]
        reg = " / ".join(
            str(s["by_region"][r]["ego"]["wins"]) if r in s["by_region"] else "-" for r in REGIONS
        )
        opp = lambda key: 0.5 * (s[key]["O1"] + s[key]["O2"])  # noqa: B023
        lines.append(
            f"| {c} | `{case['opponents']}` | {_pct(w['ego'])} | {w['O1']['wins']} | "
            f"{w['O2']['wins']} | {'/'.join(map(str, case['paper_wins']))} | {reg} | "
            f"{s['margin_m']['mean']:+.2f} | {s['contacts']['ego']:.1f}/{opp('contacts'):.1f} | "
            f"{s['off_tracks']['ego']:.1f}/{opp('off_tracks'):.1f} | "
            f"{s['decision_ms']['ego']:.1f}/{opp('decision_ms'):.1f} |"
        )
        if not s["complete"]:
            lines[-1] += f" (partial: {s['races']} of {s['config']['races']} races)"
    runs = table.get("runs", [])
    total = sum(r["wall_seconds"] for r in runs)
    simulated = sum(r["races_simulated"] for r in runs)
    race_cpu = sum(c["summary"]["race_seconds_total"] for c in table["cases"].values())
    lines += [
        "",
        f"Wall time: {total / 60:.1f} min for the {simulated} races simulated over "
        f"{len(runs)} invocation(s) (`runs.jsonl`); the races themselves took "
        f"{race_cpu / 60:.1f} worker-minutes.",
    ]
    return "\n".join(lines) + "\n"


def comparison_markdown(tables: dict, note: str = "") -> str:
    """One table over paper tables run on the same races with different egos (``tables``:
    label -> ``paper_table.json`` content, the first label's cases in order): per case, each
    ego's wins, its wins by start region R1/R2/R3 and its mean margin over the best opponent
    [m]. ``note`` (a sentence) follows the description."""
    labels = list(tables)
    if not labels:
        raise ValueError("no paper tables to compare")
    first = tables[labels[0]]
    lines = [
        "# The same races with other egos: what maximising the potential adds",
        "",
        f"Every ego races the same {first['races']} races per case ({first['steps']} "
        f"steps, seed {first['seed']}, same start orders and opponents): "
        + ", ".join(f"{label} = `{t['ego']}`" for label, t in tables.items())
        + ". Wins of the races, then by the ego's start region R1 / R2 / R3 (R1 the "
        "front); margin: ego minus the best opponent, mean over the races [m]."
        + (f" {note}" if note else ""),
        "",
        "| case | opponents | "
        + " | ".join(f"{label} wins (R1/R2/R3)" for label in labels)
        + " | margin m ("
        + " / ".join(labels)
        + ") |",
        "|---|---|" + "---|" * (len(labels) + 1),
    ]
    for c, case in first["cases"].items():
        cells, margins = [], []
        for label in labels:
            s = tables[label]["cases"].get(c, {}).get("summary")
            if s is None:
                cells.append("-")
                margins.append("-")
                continue
            reg = "/".join(
                str(s["by_region"][r]["ego"]["wins"]) if r in s["by_region"] else "-"
                for r in REGIONS
            )
            cells.append(f"{s['wins']['ego']['wins']}/{s['races']} ({reg})")
            margins.append(f"{s['margin_m']['mean']:+.2f}")
        lines.append(
            f"| {c} | `{case['opponents']}` | " + " | ".join(cells) + f" | {' / '.join(margins)} |"
        )
    return "\n".join(lines) + "\n"
