"""Learning the track-general alpha-potential on a family collection (many tracks, 2..8 cars).

``alpha-racer train --data data/family --out data/model_general`` on a folder written by
``alpha-racer collect --tracks ... --cars ...`` runs the three stages of
:mod:`experiments.potential.train` (value network, potential network, validation; the same loops,
objectives and checkpoints) on the ``general`` features (:mod:`agents.general_features`):

1. **Value**: targets are every race's gamma-discounted returns, as for one track (each race
   bootstraps with V at its own final state); features are computed with each race's own
   track and field size, padded to N_MAX slots.
2. **Potential**: unilateral deviations at training states; each deviation changes the theta
   of one car of that race's own field (car i uniform in 0..N-1), the other cars' thetas are
   the race's own or uniform, as for one track.
3. **Validation** on held-out races (whole races, split as for one track): the approximation
   gap relative to the range of V, overall and per field size (``by_cars``), and paired
   rollouts on each race's own track.

The thetas are those of the collection's policy space (read from its manifest and checked
against the thetas as in :mod:`experiments.potential.train`; family collections race the paper's), and
the model records it.

Torch is seeded with the config's seed, so the same data and config give the same model.
The model's metadata records the feature set (``general``), the tracks, the field sizes and
the collection it came from.
"""

from __future__ import annotations

import numpy as np

from agents import general_features as gf
from agents.features import theta_space
from agents.general_features import TrackSet
from agents.potential import PotentialModel
from experiments.potential import nets, validation
from experiments.potential.card_lines import added_options_text, theta_box_lines
from experiments.potential.family import RaceGroup, load_family


class FamilyData:
    """The races of a family collection, numbered 0..R-1 in the order of
    :func:`experiments.potential.family.load_family`'s groups, stored by field size N (one bucket per N:
    ``states`` (R_N, T + 1, N, 6), ``thetas`` (R_N, N, dim), ``rewards`` (R_N, T, N),
    ``track_id`` (R_N,) into :attr:`tracks`, ``race`` (R_N,) the global numbers); ``space``
    the thetas' policy space (one for every group)."""

    def __init__(self, groups: list[RaceGroup]):
        if not groups:
            raise ValueError("a family collection needs at least one group of races")
        steps = {g.rewards.shape[1] for g in groups}
        if len(steps) != 1:
            raise ValueError(f"races of different lengths {sorted(steps)} in one collection")
        self.T = steps.pop()
        dims = {g.thetas.shape[-1] for g in groups}
        if len(dims) != 1:
            raise ValueError(f"thetas of {sorted(dims)} parameters in one collection")
        self.space = theta_space(groups[0].thetas)
        specs = list(dict.fromkeys(g.track for g in groups))
        self.tracks = TrackSet(specs)
        index = {spec: k for k, spec in enumerate(specs)}
        counts = [len(g.states) for g in groups]
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        self.n_races = int(sum(counts))
        self.race_n = np.empty(self.n_races, dtype=np.int64)
        self.race_local = np.empty(self.n_races, dtype=np.int64)
        self.buckets: dict[int, dict] = {}
        for n in sorted({g.n_cars for g in groups}):
            members = [(k, g) for k, g in enumerate(groups) if g.n_cars == n]
            race = np.concatenate([start[k] + np.arange(len(g.states)) for k, g in members])
            self.race_n[race] = n
            self.race_local[race] = np.arange(len(race))
            self.buckets[n] = {
                "states": np.concatenate([g.states for _, g in members]),
                "thetas": np.concatenate([g.thetas for _, g in members]),
                "rewards": np.concatenate([g.rewards for _, g in members]),
                "track_id": np.concatenate(
                    [np.full(len(g.states), index[g.track]) for _, g in members]
                ),
                "race": race,
            }

    @property
    def cars(self) -> list[int]:
        return sorted(self.buckets)

    def track_spec(self, race: int) -> str:
        """The spec of race ``race``'s track (``tumftm:Spa``, not its name ``Spa``)."""
        b = self.buckets[int(self.race_n[race])]
        return self.tracks.specs[int(b["track_id"][self.race_local[race]])]


class FamilyDeviations:
    """Unilateral deviations at states of ``races`` (global numbers) of a :class:`FamilyData`:
    the family counterpart of :class:`experiments.potential.train._Deviations` (same interface).

    A batch holds per sample the race ``r``, the step ``t``, theta and theta' (n, N_MAX, dim)
    (rows beyond the race's field unused) and the deviating car ``i`` (in 0..N_r - 1)."""

    general = True

    def __init__(self, data: FamilyData, races, own_theta_fraction: float):
        self.data, self.races, self.own = data, np.asarray(races), own_theta_fraction
        if not len(self.races):
            raise ValueError("no races to draw deviations from")
        self.space = data.space
        self.dims = gf.dims(data.space)
        self.potential_dim = self.dims["potential"]

    def draw(self, n: int, rng) -> dict:
        d = self.data
        r = rng.choice(self.races, n)
        t = rng.integers(0, d.T, n)
        cars = d.race_n[r]
        sp = self.space
        th = rng.uniform(sp.low, sp.high, (n, gf.N_MAX, sp.dim))
        own = rng.random(n) < self.own
        for N in np.unique(cars[own]):
            idx = np.flatnonzero(own & (cars == N))
            th[idx, :N] = d.buckets[N]["thetas"][d.race_local[r[idx]]]
        i = rng.integers(0, cars)
        th2 = th.copy()
        th2[np.arange(n), i] = rng.uniform(sp.low, sp.high, (n, sp.dim))
        return {"r": r, "t": t, "cars": cars, "theta": (th, th2), "i": i}

    def _per_field(self, batch, dim, fn) -> np.ndarray:
        """``fn(x (m, N, 6), rows, N, track ids (m,))`` for each field size of the batch,
        assembled in batch order: (n, dim)."""
        d = self.data
        out = np.empty((len(batch["r"]), dim))
        for N in np.unique(batch["cars"]):
            rows = np.flatnonzero(batch["cars"] == N)
            b = d.buckets[N]
            loc = d.race_local[batch["r"][rows]]
            x = b["states"][loc, batch["t"][rows]].astype(np.float64)
            out[rows] = fn(x, rows, N, b["track_id"][loc])
        return out

    def states(self, batch) -> list[np.ndarray]:
        """Each sample's joint state (N_r, 6) as float64."""
        d = self.data
        return [
            d.buckets[int(N)]["states"][d.race_local[r], t].astype(np.float64)
            for r, t, N in zip(batch["r"], batch["t"], batch["cars"])
        ]

    def value_features(self, batch, k) -> np.ndarray:
        th = batch["theta"][k - 1]
        return self._per_field(
            batch,
            self.dims["value"],
            lambda x, rows, N, ids: gf.value_features(
                x, th[rows, :N], self.data.tracks, batch["i"][rows], track_id=ids
            ),
        )

    def potential_features(self, batch, k) -> np.ndarray:
        th = batch["theta"][k - 1]
        return self._per_field(
            batch,
            self.potential_dim,
            lambda x, rows, N, ids: gf.potential_features(
                x, th[rows, :N], self.data.tracks, track_id=ids
            ),
        )


def _value_data(data: FamilyData, train_idx, val_idx, cfg, chunk: int = 100_000) -> nets.ValueData:
    """The value dataset over every field size: features with each race's own track and N,
    targets' parts from each race's own rewards."""
    train_set, val_set = set(train_idx.tolist()), set(val_idx.tolist())
    parts = {"tr": [], "va": []}
    ends, offset = [], 0
    for N in data.cars:
        b = data.buckets[N]
        R = len(b["race"])
        P, tail = nets.discounted_partial_returns(b["rewards"], cfg.gamma)
        for key, chosen, stride in (
            ("tr", train_set, cfg.value_stride),
            ("va", val_set, max(cfg.value_stride, 5)),
        ):
            local = np.array([k for k, g in enumerate(b["race"]) if g in chosen], dtype=np.int64)
            r, t, c = nets.value_samples(None, None, local, stride, data.T, N)
            X = np.empty((len(r), gf.value_dim(space=data.space)), dtype=np.float32)
            for lo in range(0, len(r), chunk):
                sl = slice(lo, lo + chunk)
                X[sl] = gf.value_features(
                    b["states"][r[sl], t[sl]],
                    b["thetas"][r[sl]],
                    data.tracks,
                    c[sl],
                    track_id=b["track_id"][r[sl]],
                )
            parts[key].append((X, P[r, t, c], tail[t], offset + r * N + c))
        rr, cc = np.meshgrid(np.arange(R), np.arange(N), indexing="ij")
        rr, cc = rr.ravel(), cc.ravel()
        ends.append(
            gf.value_features(
                b["states"][rr, data.T],
                b["thetas"][rr],
                data.tracks,
                cc,
                track_id=b["track_id"][rr],
            ).astype(np.float32)
        )
        offset += R * N
    cat = lambda key, j: np.concatenate([p[j] for p in parts[key]])
    return nets.ValueData(
        cat("tr", 0),
        cat("va", 0),
        np.concatenate(ends),
        cat("tr", 1),
        cat("tr", 2),
        cat("tr", 3),
        cat("va", 1),
        cat("va", 2),
        cat("va", 3),
        general=True,
    )


# ---------------------------------------------------------------------------- validation
def family_gaps(
    model: PotentialModel,
    data: FamilyData,
    races,
    pairs: int,
    seed: int,
    own_theta_fraction: float = 0.5,
    value_range: float | None = None,
) -> dict:
    """Approximation gaps of ``pairs`` unilateral deviations at states of ``races``:
    :func:`experiments.potential.validation.gap_statistics` relative to ``value_range`` (default: the range
    of V over 20000 states of these races with uniform thetas, as for one track), overall and
    per field size (``by_cars``: pairs, median, p95, max and the constant potential's median
    and p95). Also ``value_range_measured``, the range of V over these races."""
    rng = np.random.default_rng(seed)
    dev = FamilyDeviations(data, races, 0.5)
    b = dev.draw(20000, rng)
    v = model.value_net(dev.value_features(b, 1))
    measured = float(v.max() - v.min())
    vr = measured if value_range is None else float(value_range)
    dev.own = own_theta_fraction
    b = dev.draw(pairs, rng)
    dv = model.value_net(dev.value_features(b, 2)) - model.value_net(dev.value_features(b, 1))
    dphi = model.potential_net(dev.potential_features(b, 2)) - model.potential_net(
        dev.potential_features(b, 1)
    )
    if not (np.isfinite(dv).all() and np.isfinite(dphi).all()):
        raise FloatingPointError("non-finite value or potential differences")
    out = {
        "value_range": vr,
        "value_range_measured": measured,
        "val_pairs": int(pairs),
        **validation.gap_statistics(dphi, dv, vr),
        "by_cars": {},
    }
    for N in np.unique(b["cars"]):
        m = b["cars"] == N
        s = validation.gap_statistics(dphi[m], dv[m], vr)
        out["by_cars"][str(int(N))] = {
            "pairs": int(m.sum()),
            **{
                k: s[k]
                for k in (
                    "gap_rel_median",
                    "gap_rel_p95",
                    "gap_rel_max",
                    "const_rel_median",
                    "const_rel_p95",
                )
            },
        }
    return out


def family_rollouts(model, vr, data: FamilyData, val_idx, cfg, progress_bar) -> dict:
    """Paired rollouts from held-out states on each race's own track (as
    :func:`experiments.potential.train.validate_rollouts` for one track)."""
    rng = np.random.default_rng(cfg.seed + 3)
    n = cfg.rollout_pairs
    dev = FamilyDeviations(data, val_idx, own_theta_fraction=1.0)
    b = dev.draw(n, rng)
    xs = dev.states(b)
    specs = [data.track_spec(int(r)) for r in b["r"]]
    thetas = [(b["theta"][0][k, : len(x)], b["theta"][1][k, : len(x)]) for k, x in enumerate(xs)]
    jobs = [
        (specs[k], xs[k], th, int(b["i"][k]), cfg.rollout_steps, cfg.gamma)
        for k in range(n)
        for th in thetas[k]
    ]
    res = validation.paired_rollouts(jobs, cfg.threads, progress_bar)
    boot = cfg.gamma**cfg.rollout_steps
    dG, dphi, dv = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        x, i, tr = xs[k][None], np.array([b["i"][k]]), specs[k]
        th1, th2 = (th[None] for th in thetas[k])
        g = [
            res[2 * k + j][0] + boot * float(model.value(res[2 * k + j][1][None], th, tr, i)[0])
            for j, th in enumerate((th1, th2))
        ]
        dG[k] = g[1] - g[0]
        dv[k] = float(model.value(x, th2, tr, i)[0] - model.value(x, th1, tr, i)[0])
        dphi[k] = float(model.potential(x, th2, tr)[0] - model.potential(x, th1, tr)[0])
    return validation.rollout_statistics(dphi, dv, dG, vr, cfg.rollout_steps)


# ---------------------------------------------------------------------------- training
GENERAL_HEAD = {"feature_set": "general", "feature_version": gf.FEATURE_VERSION}
"""What ties a training run to the general features (its ``train_config.json``'s head)."""


def train_general(run: nets.TrainingRun) -> dict:
    """Run (or resume) the three stages of the training ``run`` (opened by
    :func:`experiments.potential.train.train` with :data:`GENERAL_HEAD`) on its family collection;
    returns the metrics (also in ``metrics.json``); writes ``model.npz`` and ``model_card.md``
    beside them."""
    cfg, data_dir = run.cfg, run.data_dir
    groups, _ = load_family(data_dir)
    data = FamilyData(groups)
    train_idx, val_idx = run.split(data.n_races, data.space.dim)
    run.log(
        f"data: {data.n_races} races x {data.T} steps on {len(data.tracks)} tracks with "
        f"{', '.join(map(str, data.cars))} cars from {data_dir} ({len(train_idx)} training, "
        f"{len(val_idx)} held out)"
    )
    value, potential = run.fit(
        _value_data(data, train_idx, val_idx, cfg),
        FamilyDeviations(data, train_idx, cfg.own_theta_fraction),
    )
    metrics = run.finish(
        value,
        potential,
        {
            "feature_set": "general",
            "feature_version": gf.FEATURE_VERSION,
            "n_max": gf.N_MAX,
            "n_cars_range": [min(data.cars), max(data.cars)],
            "n_cars_trained": data.cars,
            "tracks": data.tracks.specs,
            "track_specs": run.manifest["config"]["tracks"],
        },
        {
            "dir": str(data_dir),
            "races": data.n_races,
            "steps": data.T,
            "collect": run.manifest["config"],
        },
        lambda model: family_gaps(
            model, data, val_idx, cfg.val_pairs, cfg.seed + 2, cfg.own_theta_fraction
        ),
        lambda model, vr: family_rollouts(model, vr, data, val_idx, cfg, run.progress_bar),
        general_model_card_text,
    )
    for N, s in metrics["by_cars"].items():
        run.log(
            f"  {N} cars: gap median {100 * s['gap_rel_median']:.2f}%, 95th pct "
            f"{100 * s['gap_rel_p95']:.2f}% (constant potential {100 * s['const_rel_median']:.2f}%, "
            f"{100 * s['const_rel_p95']:.2f}%)"
        )
    return metrics


def general_model_card_text(meta: dict) -> str:
    """A short Markdown model card of a general model from its metadata."""
    m, c, d = meta["metrics"], meta["config"], meta["data"]
    col = d["collect"]
    lo, hi = meta["n_cars_range"]
    rows = [
        f"| {N} | {s['pairs']} | {100 * s['gap_rel_median']:.2f}% | "
        f"{100 * s['gap_rel_p95']:.2f}% | {100 * s['const_rel_median']:.2f}% | "
        f"{100 * s['const_rel_p95']:.2f}% |"
        for N, s in m["by_cars"].items()
    ]
    return "\n".join(
        [
            f"# General alpha-potential model (general features, version {meta['feature_version']})",
            "",
            f"* **Data:** {d['races']} races x {d['steps']} steps on {len(meta['tracks'])} tracks "
            f"({' '.join(meta['track_specs'])}) with {lo}..{hi} cars (`alpha-racer collect --races "
            f"{col['races']} --tracks {' '.join(col['tracks'])} --cars "
            f"{','.join(map(str, col['cars']))} --seed {col['seed']}{added_options_text(col)}`); "
            f"{100 * c['val_fraction']:.0f}% of the races held out.",
            *theta_box_lines(meta),
            f"* **Features:** cars sorted by progress and padded to {meta['n_max']} slots with a "
            f"presence flag; curvature preview and half widths at each car (`agents/general_features.py`).",
            f"* **Discount:** gamma = {meta['gamma']}.",
            f"* **Networks:** value {list(c['value_hidden'])} ({c['value_epochs']} epochs), potential "
            f"{list(c['potential_hidden'])} ({c['potential_steps']} steps of {c['potential_batch']} "
            f"deviations, objective `{c['objective']}`), SiLU.",
            f"* **Command:** `{meta.get('command', '')}`",
            f"* **Training time:** {m['train_seconds'] / 60:.1f} min ({m['total_seconds'] / 60:.1f} "
            f"min with validation).",
            "",
            "## Held-out validation (races of the training tracks held out)",
            "",
            f"* Value network R^2 on held-out discounted returns: {m['value_val_r2']:.3f}.",
            f"* Approximation gap |dPhi - dV_i| / range(V) over {m['val_pairs']} deviations: median "
            f"{100 * m['gap_rel_median']:.2f}%, 95th percentile {100 * m['gap_rel_p95']:.2f}% "
            f"(constant potential {100 * m['const_rel_median']:.2f}%, "
            f"{100 * m['const_rel_p95']:.2f}%); range of V {m['value_range']:.3f} m.",
            "",
            "| cars | deviations | gap median | gap p95 | constant median | constant p95 |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
            "Held-out tracks: `alpha-racer general-report` (never used in training).",
            "",
        ]
    )
