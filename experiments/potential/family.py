"""Race data over a family of tracks and field sizes, for the track-general alpha-potential.

``alpha-racer collect --tracks default oval random:0-299 tumftm:Monza --cars 2-6 --races 6000``
simulates the races of :mod:`experiments.potential.collect` (MPC cars with theta uniform in its bounds,
from the start regions in a random order) on many tracks and with 2..8 cars, in the paper's
policy space or the extended one, with the paper's or close starts and paces (``space``,
``start``, ``pace`` as in :class:`experiments.potential.collect.CollectConfig`). Every shard is
homogeneous: one track and one number of cars N, assigned by :meth:`FamilyConfig.assignment`
from the seed and the shard index alone, and recorded in the shard (``track``, ``n_cars``)
and in ``manifest.json`` (one entry per shard). Tracks and field sizes are dealt out in cycles
of a seeded permutation each, so every track gets its share of the shards (within one) and so
does every field size. Race ``i`` draws its thetas and starts from the same
``SeedSequence(seed)`` child ``i`` as a single-track collection, so the same seed gives the same
data for any worker count and backend; a killed run resumes with the missing shards.

Track specs: anything :func:`racing_env.tracks.make_track` takes (``default``, ``oval``,
``random:SEED``, ``tumftm:NAME``, a ``.csv`` path), plus ``random:A-B`` for the procedural
seeds A..B (inclusive). Field sizes: ``2-6`` (a range), ``2,3,5`` (a list) or one number.

Shard arrays (R races, T steps, N cars of the shard): those of :mod:`experiments.potential.collect`
plus ``track`` (a string) and ``n_cars``; the schema is :data:`SCHEMA_VERSION` (2). A
single-track collection (schema 1) loads here too, as a family of one track and one N.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from experiments.infra.artifacts import claim, manifest_config, write_npz
from experiments.infra.checks import check_counts
from experiments.infra.parallel import Pool
from experiments.potential.collect import (
    ADDED_FIELDS,
    CollectConfig,
    ShardedRaces,
    shard_path,
    simulate_missing_shards,
    simulate_race,
)
from experiments.potential.collect import SCHEMA_VERSION as SINGLE_SCHEMA_VERSION

SCHEMA_VERSION = 2
MIN_CARS, MAX_CARS = 2, 8


def expand_tracks(specs) -> list[str]:
    """Track specs with ``random:A-B`` expanded to ``random:A`` .. ``random:B``; a repeated
    track or a bad range is a ValueError naming it. The tracks themselves are not built
    (see :func:`check_tracks`)."""
    if isinstance(specs, str):
        specs = [specs]
    out: list[str] = []
    for spec in specs:
        if not isinstance(spec, str) or not spec:
            raise ValueError(f"a track spec must be a non-empty string, got {spec!r}")
        if spec.startswith("random:") and "-" in spec[len("random:") :]:
            lo, _, hi = spec[len("random:") :].partition("-")
            if not (lo.isdigit() and hi.isdigit()) or int(lo) > int(hi):
                raise ValueError(
                    f"track range {spec!r}: expected random:A-B with integer seeds "
                    f"0 <= A <= B, e.g. random:0-299"
                )
            out += [f"random:{k}" for k in range(int(lo), int(hi) + 1)]
        else:
            out.append(spec)
    seen = set()
    for name in out:
        if name in seen:
            raise ValueError(f"track {name!r} is listed twice in {list(specs)}; list each once")
        seen.add(name)
    return out


def check_tracks(names) -> None:
    """Build every track once, so an unknown or broken track spec fails before any race:
    a ValueError naming the spec and what is expected."""
    from racing_env.tracks import make_track

    for name in names:
        try:
            make_track(name)
        except ValueError as exc:
            raise ValueError(
                f"track spec {name!r}: {exc} (or random:A-B for the seeds A..B)"
            ) from None


def parse_cars(text) -> tuple[int, ...]:
    """Field sizes from ``"2-6"``, ``"2,3,5"``, ``"3"`` or a sequence of integers; each must be
    in 2..8 (a ValueError names the value and the range)."""
    if isinstance(text, (int, np.integer)) and not isinstance(text, bool):
        cars = [int(text)]
    elif isinstance(text, str):
        parts = [p.strip() for p in text.split(",") if p.strip()]
        cars = []
        try:
            for p in parts:
                lo, dash, hi = p.partition("-")
                cars += list(range(int(lo), int(hi) + 1)) if dash else [int(p)]
        except ValueError:
            raise ValueError(
                f"cars {text!r}: expected a number, a range A-B or a list A,B,C of "
                f"field sizes in {MIN_CARS}..{MAX_CARS}"
            ) from None
        if parts and not cars:
            raise ValueError(f"cars {text!r}: the range is empty (A must not exceed B)")
    else:
        cars = []
        for c in text:
            if isinstance(c, bool) or not isinstance(c, (int, np.integer)):
                raise ValueError(f"cars must be integers in {MIN_CARS}..{MAX_CARS}, got {c!r}")
            cars.append(int(c))
    if not cars:
        raise ValueError(f"cars {text!r}: no field size given")
    bad = [c for c in cars if not MIN_CARS <= c <= MAX_CARS]
    if bad:
        raise ValueError(
            f"cars {text!r}: every field size must be in {MIN_CARS}..{MAX_CARS}, "
            f"got {', '.join(map(str, bad))}"
        )
    if len(set(cars)) != len(cars):
        raise ValueError(f"cars {text!r}: a field size is listed twice")
    return tuple(sorted(cars))


@dataclass(frozen=True)
class FamilyConfig(ShardedRaces):
    """A collection over ``tracks`` (specs, ``random:A-B`` ranges allowed) and field sizes
    ``cars``: ``races`` races of ``steps`` steps, ``races_per_shard`` per shard."""

    races: int = 6000
    tracks: tuple = ("default", "oval", "random:0-299")
    cars: tuple = (2, 3, 4, 5, 6)
    steps: int = 500
    seed: int = 0
    races_per_shard: int = 4
    start_jitter: float = 0.8
    space: str = "paper"  # as CollectConfig: the policy space, start regions and paces
    start: str = "paper"
    pace: str = "box"

    def __post_init__(self):
        # the single-track config checks space, start and pace (naming the choices)
        CollectConfig(space=self.space, start=self.start, pace=self.pace)
        check_counts(self, ("races", "steps", "races_per_shard"))
        object.__setattr__(self, "tracks", tuple(self.tracks))
        object.__setattr__(self, "cars", parse_cars(self.cars))
        expand_tracks(self.tracks)  # syntax and repeats

    @property
    def track_list(self) -> list[str]:
        """Every track of the family, ranges expanded, in the given order."""
        return expand_tracks(self.tracks)

    def assignment(self, shard: int, _tracks: list | None = None) -> tuple[str, int]:
        """(track, N) of shard ``shard``: tracks are dealt in cycles of ``len(tracks)`` shards,
        each cycle a permutation drawn from ``(seed, cycle, 0)``; field sizes likewise from
        ``(seed, cycle, 1)``. Depends on the seed, the lists and the index alone."""
        tracks = self.track_list if _tracks is None else _tracks
        c, k = divmod(shard, len(tracks))
        track = tracks[np.random.default_rng([self.seed, c, 0]).permutation(len(tracks))[k]]
        c, k = divmod(shard, len(self.cars))
        n = self.cars[np.random.default_rng([self.seed, c, 1]).permutation(len(self.cars))[k]]
        return track, int(n)

    def assignments(self) -> list[tuple[str, int]]:
        tracks = self.track_list
        return [self.assignment(k, tracks) for k in range(self.n_shards)]

    def race_config(self, shard: int) -> CollectConfig:
        """The single-track config that simulates this shard's races (same seed, so race i
        draws what race i of any collection with this seed draws)."""
        track, n = self.assignment(shard)
        return CollectConfig(
            races=self.races,
            n_cars=n,
            steps=self.steps,
            track=track,
            seed=self.seed,
            races_per_shard=self.races_per_shard,
            start_jitter=self.start_jitter,
            space=self.space,
            start=self.start,
            pace=self.pace,
        )

    def manifest(self) -> dict:
        shards = [
            {
                "shard": k,
                "track": t,
                "n_cars": n,
                "races": [self.shard_races(k).start, self.shard_races(k).stop],
            }
            for k, (t, n) in enumerate(self.assignments())
        ]
        return {
            "schema_version": SCHEMA_VERSION,
            "kind": "family",
            "config": json.loads(json.dumps(manifest_config(self, ADDED_FIELDS))),
            "shards": shards,
        }


def simulate_family_shard(config: FamilyConfig, shard: int) -> dict:
    """The task of every backend: one shard's races on its track with its N (pure)."""
    warnings.simplefilter("ignore")
    cfg = config.race_config(shard)
    races = [simulate_race(cfg, i) for i in config.shard_races(shard)]
    arrays = {k: np.stack([r[k] for r in races]) for k in races[0]}
    arrays["track"] = np.array(cfg.track)
    arrays["n_cars"] = np.array(cfg.n_cars, dtype=np.int64)
    return arrays


def shard_is_complete(path: Path, config: FamilyConfig, shard: int) -> bool:
    track, n = config.assignment(shard)
    try:
        with np.load(path) as z:
            return (
                int(z["schema_version"]) == SCHEMA_VERSION
                and str(z["track"]) == track
                and int(z["n_cars"]) == n
                and z["race_index"].tolist() == list(config.shard_races(shard))
            )
    except Exception:  # truncated, corrupt or foreign file: redo it
        return False


def collect_family(config: FamilyConfig, out_dir, pool: Pool = Pool()) -> dict:
    """Simulate every missing shard of the family on ``pool``; returns a summary (as
    :func:`experiments.potential.collect.collect`). Every track is built first, so a bad spec fails
    before any race."""
    check_tracks(config.track_list)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    claim(out / "manifest.json", config.manifest(), "race data")
    return simulate_missing_shards(
        config,
        out,
        simulate_family_shard,
        shard_is_complete,
        lambda k, arrays: write_npz(shard_path(out, k), schema_version=SCHEMA_VERSION, **arrays),
        "collect family",
        pool,
    )


@dataclass
class RaceGroup:
    """The races of one track and one field size N: ``states`` (R, T + 1, N, 6), ``thetas``
    (R, N, 5), ``rewards`` (R, T, N), ``race_index`` (R,) (the collection's race numbers)."""

    track: str
    n_cars: int
    states: np.ndarray
    thetas: np.ndarray
    rewards: np.ndarray
    race_index: np.ndarray


def load_family(out_dir) -> tuple[list[RaceGroup], dict]:
    """``(groups, manifest)``: the races of a collection grouped by (track, N), groups in order
    of first appearance, races in collection order within a group. Reads a family collection
    (schema 2; every shard of its manifest must be there, with the track and N listed for
    it) or a single-track one (schema 1, one group)."""
    out = Path(out_dir)
    path = out / "manifest.json"
    if not path.exists():
        raise ValueError(f"{out}: no manifest.json (not a folder written by alpha-racer collect)")
    meta = json.loads(path.read_text())
    version = meta.get("schema_version")
    if version not in (SINGLE_SCHEMA_VERSION, SCHEMA_VERSION):
        raise ValueError(
            f"{out}: race data of schema {version}, this code reads "
            f"{SINGLE_SCHEMA_VERSION} (one track) and {SCHEMA_VERSION} (a family)"
        )
    if version == SINGLE_SCHEMA_VERSION:
        from experiments.potential.collect import load_races

        d = load_races(out)
        c = d["config"]
        return [
            RaceGroup(
                c["track"],
                int(c["n_cars"]),
                d["states"],
                d["thetas"],
                d["rewards"],
                d["race_index"],
            )
        ], meta
    missing = [e["shard"] for e in meta["shards"] if not shard_path(out, e["shard"]).exists()]
    if missing:
        raise ValueError(
            f"{out}: {len(missing)} of {len(meta['shards'])} shards missing (first: "
            f"{missing[0]}); run the same alpha-racer collect command to finish it"
        )
    parts: dict[tuple[str, int], list[dict]] = {}
    for entry in meta["shards"]:
        p = shard_path(out, entry["shard"])
        with np.load(p) as z:
            if int(z["schema_version"]) != SCHEMA_VERSION:
                raise ValueError(
                    f"{p}: schema {int(z['schema_version'])}, expected {SCHEMA_VERSION}"
                )
            key = (str(z["track"]), int(z["n_cars"]))
            if key != (entry["track"], entry["n_cars"]):
                raise ValueError(
                    f"{p} holds {key[1]} cars on {key[0]!r}, the manifest lists "
                    f"{entry['n_cars']} on {entry['track']!r}"
                )
            parts.setdefault(key, []).append(
                {k: z[k] for k in ("states", "thetas", "rewards", "race_index")}
            )
    if not parts:
        raise ValueError(f"{out}: no shards")
    groups = [
        RaceGroup(
            t,
            n,
            *(
                np.concatenate([p[k] for p in ps])
                for k in ("states", "thetas", "rewards", "race_index")
            ),
        )
        for (t, n), ps in parts.items()
    ]
    return groups, meta
