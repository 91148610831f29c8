"""Learning the alpha-potential (paper section 3): value network, potential network, validation.

``alpha-racer train --data data/races --out models/alpha`` runs three resumable stages on a
collection written by ``alpha-racer collect``:

1. **Value** ``V(f_i(x), theta)``: one network shared by every car, on the ego-centric features
   of :func:`agents.features.value_features` (so ``V_i(x, theta) = V(f_i(x, theta))``). Targets
   are gamma-discounted returns of the per-step rewards. A race ends after T steps while the
   discounted sum does not, so the return from step t is the observed part plus
   ``gamma^(T - t) V(x_T)`` from the current network (recomputed every epoch), the standard
   correction for time-limit truncation.
2. **Potential** ``Phi(x, theta)`` on unilateral deviations: at states x of the training races,
   a joint theta (the race's own, or uniform) and a deviation theta'_i of one car i (uniform);
   the target is ``V_i(x, theta') - V_i(x, theta)`` and Phi is fitted so that
   ``Phi(x, theta') - Phi(x, theta)`` matches it. Objectives: ``mse``; the paper's min-max
   (semi-infinite program ``min alpha s.t. |dPhi - dV_i| <= alpha``) as ``smoothmax``
   (``tau log mean exp(|gap| / tau)``) or ``tail`` (mean of the largest ``tail_fraction`` of
   the batch's gaps). The min-max objectives start from an MSE warm-up.
3. **Validation** on held-out races (never seen by either network): the approximation gap
   ``|dPhi - dV_i|`` relative to the range of V over the held-out states, its median, 95th
   percentile and maximum (the empirical alpha), against a constant potential (``dPhi = 0``);
   and against simulated values: paired rollouts from held-out states that differ only in
   car i's theta (``rollout_pairs`` of them).

The collection's policy space (``alpha-racer collect --space``: the paper's five parameters or
the extended space's six) is read from its manifest and checked against its thetas' last
dimension; features, deviations and the model's theta box are that space's, and the model
records it (``space``). Continuing a run in the same ``--out`` on races of another space is
refused, naming both.

The collection's vehicle class and wake (``alpha-racer collect --vehicle-class fullsize``) are
read from its manifest too: the track is built at the class's scale, the paired rollouts race
its cars with its wake, deviations are drawn in the box the collection drew its thetas from
(:func:`experiments.potential.collect.collection_space`: zeta up to 1.0 at full size) and the
model records the class and wake (``vehicle_class``, ``wake``, left out for the paper's 1:43
class without a wake), so that :class:`agents.alpha_agent.AlphaAgent` races it only on tracks
of its class.

Each stage checkpoints (``value_ckpt.pt``, ``potential_ckpt.pt``, every epoch / ``save_every``
steps); a killed run resumes from its last checkpoint. The output ``model.npz``
(:class:`agents.potential.PotentialModel`) carries the config, the feature version, the data
it came from and the metrics; ``metrics.json`` and ``model_card.md`` sit beside it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from agents.features import (
    FEATURE_VERSION,
    potential_dim,
    potential_features,
    theta_space,
    value_dim,
    value_features,
)
from agents.potential import PotentialModel
from experiments.evaluation.bench_config import PAPER_WORLD
from experiments.potential import nets, validation
from experiments.potential.card_lines import (
    added_options_text,
    pace_text,
    theta_box_lines,
    track_steps_text,
)
from experiments.potential.nets import TrainConfig

# ---------------------------------------------------------------------------- data


# ---------------------------------------------------------------------------- training
def train(
    data_dir,
    out_dir,
    config: TrainConfig | None = None,
    progress_bar: bool = True,
    log=print,
    command: str | None = None,
    space: str | None = None,
) -> dict:
    """Run (or resume) the three stages; returns the metrics dict (also in ``metrics.json``).
    The policy space is the collection's; ``space``, when given, must be it (``ValueError``
    naming both otherwise)."""
    from racing_env.extras import require

    torch = require("torch", "training the value and alpha-potential networks (alpha-racer train)")
    from experiments.potential.collect import (
        ZETA_CEILING,
        collection_class,
        collection_space,
        is_paper_world,
        load_races,
    )
    from racing_env.tracks import make_track

    cfg = config or TrainConfig()
    family = _is_family(data_dir)  # many tracks and field sizes: the general model
    if family:
        from experiments.potential.train_general import GENERAL_HEAD as head
        from experiments.potential.train_general import train_general
    else:
        head = {"feature_version": FEATURE_VERSION}
    run = nets.TrainingRun.open(
        data_dir, out_dir, cfg, space, head, torch, progress_bar, log, command
    )
    if family:
        return train_general(run)
    data = load_races(data_dir)
    world = collection_class(data["config"])  # (vehicle_class, wake)
    track = make_track(data["config"]["track"], vehicle_class=world[0])
    states, thetas, rewards = data["states"], data["thetas"], data["rewards"]
    R, T, N = rewards.shape
    train_idx, val_idx = run.split(R, thetas.shape[-1])
    log(
        f"data: {R} races x {T} steps x {N} cars from {data_dir} "
        f"({len(train_idx)} training, {len(val_idx)} held out)"
        + (
            ""
            if run.space.name == "paper"
            else f", policy space {run.space.name!r} {run.space.names}"
        )
    )

    # the box the collection drew from (its class's zeta ceiling): the deviations' box
    box = collection_space(run.space.name, world[0])
    value, potential = run.fit(
        _value_data(states, thetas, rewards, train_idx, val_idx, track, cfg),
        _Deviations(states, thetas, train_idx, track, cfg.own_theta_fraction, box),
    )
    meta = {"feature_version": FEATURE_VERSION, "n_cars": N, "track": data["config"]["track"]}
    if not is_paper_world(data["config"]):
        meta.update(vehicle_class=world[0], wake=world[1])
    if ZETA_CEILING.get(world[0]) is not None:
        meta["zeta_ceiling"] = ZETA_CEILING[world[0]]
    return run.finish(
        value,
        potential,
        meta,
        {"dir": str(data_dir), "races": R, "steps": T, "collect": data["config"]},
        lambda model: validate_gaps(model, states, thetas, val_idx, track, cfg, box),
        lambda model, vr: validate_rollouts(
            model, vr, states, thetas, val_idx, track, cfg, progress_bar, box, world
        ),
        model_card_text,
    )


def _is_family(data_dir) -> bool:
    """Whether ``data_dir`` holds a family collection (many tracks / field sizes)."""
    path = Path(data_dir) / "manifest.json"
    if not path.exists():
        raise ValueError(
            f"{data_dir}: no manifest.json; expected a folder written by `alpha-racer collect`"
        )
    return json.loads(path.read_text()).get("kind") == "family"


def _features_in_chunks(states, thetas, r, t, c, track, chunk=200_000):
    out = np.empty((len(r), value_dim(states.shape[2], theta_space(thetas))), dtype=np.float32)
    for lo in range(0, len(r), chunk):
        sl = slice(lo, lo + chunk)
        out[sl] = value_features(states[r[sl], t[sl]], thetas[r[sl]], track, c[sl])
    return out


def _value_data(states, thetas, rewards, train_idx, val_idx, track, cfg) -> nets.ValueData:
    """One track, one field size: every ``value_stride``-th step of the training races (every
    5th at least of the held-out ones), every car."""
    R, T, N = rewards.shape
    P, tail = nets.discounted_partial_returns(rewards, cfg.gamma)
    tr = nets.value_samples(states, thetas, train_idx, cfg.value_stride, T, N)
    va = nets.value_samples(states, thetas, val_idx, max(cfg.value_stride, 5), T, N)
    X_tr = _features_in_chunks(states, thetas, *tr, track)
    X_va = _features_in_chunks(states, thetas, *va, track)
    # features of every race's final state, for the truncation bootstrap
    rr, cc = np.meshgrid(np.arange(R), np.arange(N), indexing="ij")
    X_end = value_features(states[rr.ravel(), T], thetas[rr.ravel()], track, cc.ravel()).astype(
        np.float32
    )
    parts = lambda smp: (P[smp[0], smp[1], smp[2]], tail[smp[1]], smp[0] * N + smp[2])
    return nets.ValueData(X_tr, X_va, X_end, *parts(tr), *parts(va))


def sample_deviations(
    states, thetas, races, n: int, rng, own_theta_fraction: float = 0.5, box=None
):
    """``n`` unilateral deviations at states of ``races``: (x (n, N, 6), theta (n, N, dim),
    theta' (n, N, dim), car i (n,)); theta' differs from theta only in car i's row (uniform in
    ``box``, a :class:`~agents.theta.PolicySpace`: by default the box of the thetas' policy
    space, read from their last dimension ``dim``; a collection's
    :func:`~experiments.potential.collect.collection_space` for one with a zeta ceiling)."""
    R, T1, N, _ = states.shape
    sp = theta_space(thetas) if box is None else box
    r = rng.choice(races, n)
    t = rng.integers(0, T1 - 1, n)
    x = states[r, t].astype(np.float64)
    th = rng.uniform(sp.low, sp.high, (n, N, sp.dim))
    own = rng.random(n) < own_theta_fraction
    th[own] = thetas[r[own]]
    i = rng.integers(0, N, n)
    th2 = th.copy()
    th2[np.arange(n), i] = rng.uniform(sp.low, sp.high, (n, sp.dim))
    return x, th, th2, i


class _Deviations:
    """Unilateral deviations at the training states of one track and one field size, and
    their features (the potential stage's data; :mod:`experiments.potential.train_general` has the one
    for a family of tracks and field sizes). ``draw(n, rng)`` returns a batch;
    ``value_features(batch, k)`` and ``potential_features(batch, k)`` give its features
    (float64) under theta (k = 1) or the deviation theta' (k = 2)."""

    general = False

    def __init__(self, states, thetas, races, track, own_theta_fraction, box=None):
        self.states, self.thetas, self.races, self.track = states, thetas, races, track
        self.own, self.box = own_theta_fraction, box
        self.potential_dim = potential_dim(states.shape[2], theta_space(thetas))

    def draw(self, n, rng):
        return sample_deviations(self.states, self.thetas, self.races, n, rng, self.own, self.box)

    def value_features(self, batch, k):
        x, th1, th2, i = batch
        return value_features(x, (th1, th2)[k - 1], self.track, i)

    def potential_features(self, batch, k):
        x, th1, th2, i = batch
        return potential_features(x, (th1, th2)[k - 1], self.track)


# ---------------------------------------------------------------------------- validation
def approximation_gaps(model: PotentialModel, x, th1, th2, i, track):
    """(dPhi, dV) of deviations (arrays (n,))."""
    dv = model.value(x, th2, track, i) - model.value(x, th1, track, i)
    dphi = model.potential(x, th2, track) - model.potential(x, th1, track)
    return dphi, dv


def relative_gaps(model: PotentialModel, x, th1, th2, i, track, vr: float):
    """``(|dPhi - dV| / vr, |dV| / vr, dPhi, dV)`` of deviations, arrays (n,): the gap of the
    learned potential and of a constant one (dPhi = 0), relative to the value range ``vr``."""
    dphi, dv = approximation_gaps(model, x, th1, th2, i, track)
    return np.abs(dphi - dv) / vr, np.abs(dv) / vr, dphi, dv


def value_range(
    model: PotentialModel, states, thetas, races, track, rng, n=20000, box=None
) -> float:
    """Range (max - min) of V_i over held-out states, cars and thetas uniform in ``box`` (the
    paper's normalisation of the approximation gap; ``box`` as for :func:`sample_deviations`)."""
    x, th, _, i = sample_deviations(states, thetas, races, n, rng, box=box)
    v = model.value(x, th, track, i)
    return float(v.max() - v.min())


def validate_gaps(model, states, thetas, val_idx, track, cfg, box=None) -> dict:
    rng = np.random.default_rng(cfg.seed + 2)
    vr = value_range(model, states, thetas, val_idx, track, rng, box=box)
    x, th1, th2, i = sample_deviations(
        states, thetas, val_idx, cfg.val_pairs, rng, cfg.own_theta_fraction, box
    )
    _, _, dphi, dv = relative_gaps(model, x, th1, th2, i, track, vr)
    return {
        "value_range": vr,
        "val_pairs": int(cfg.val_pairs),
        **validation.gap_statistics(dphi, dv, vr),
    }


def validate_rollouts(
    model, vr, states, thetas, val_idx, track, cfg, progress_bar, box=None, world=PAPER_WORLD
) -> dict:
    """Paired rollouts from held-out states: dG_i (simulated, bootstrapped by V after
    ``rollout_steps``) against dPhi and dV, relative to the value range ``vr``; deviations in
    ``box`` (as for :func:`sample_deviations`), races of ``world`` (the collection's vehicle
    class and wake, :func:`~experiments.potential.collect.collection_class`)."""
    rng = np.random.default_rng(cfg.seed + 3)
    n = cfg.rollout_pairs
    x, th1, th2, i = sample_deviations(
        states, thetas, val_idx, n, rng, own_theta_fraction=1.0, box=box
    )
    jobs = [
        (model.meta["track"], x[k], th, int(i[k]), cfg.rollout_steps, cfg.gamma, *world)
        for k in range(n)
        for th in (th1[k], th2[k])
    ]
    res = validation.paired_rollouts(jobs, cfg.threads, progress_bar)
    G = np.array([r[0] for r in res]).reshape(n, 2)
    x_end = np.array([r[1] for r in res]).reshape(n, 2, *x.shape[1:])
    boot = cfg.gamma**cfg.rollout_steps
    v_end = np.stack([model.value(x_end[:, k], (th1, th2)[k], track, i) for k in range(2)], axis=1)
    dG = (G[:, 1] + boot * v_end[:, 1]) - (G[:, 0] + boot * v_end[:, 0])
    dphi, dv = approximation_gaps(model, x, th1, th2, i, track)
    return validation.rollout_statistics(dphi, dv, dG, vr, cfg.rollout_steps)


def model_card_text(meta: dict) -> str:
    """A short Markdown model card from a model's metadata."""
    m, c, d = meta["metrics"], meta["config"], meta["data"]
    col = d.get("collect", {})
    return "\n".join(
        [
            f"# alpha-potential model (feature version {meta['feature_version']})",
            "",
            f"* **Data:** {d['races']} races x {d['steps']} steps x {meta['n_cars']} cars on "
            f"`{meta['track']}` (`alpha-racer collect --races {col.get('races', d['races'])} "
            f"--seed {col.get('seed', 0)}{added_options_text(col)}{track_steps_text(col)}"
            + "`; every car an MPC with theta uniform in its bounds"
            + pace_text(col)
            + "); "
            + f"{100 * c['val_fraction']:.0f}% of the races held out.",
            *theta_box_lines(meta),
            f"* **Discount:** gamma = {meta['gamma']}.",
            f"* **Networks:** value {list(c['value_hidden'])} ({c['value_epochs']} epochs), potential "
            f"{list(c['potential_hidden'])} ({c['potential_steps']} steps of {c['potential_batch']} "
            f"deviations, objective `{c['objective']}`), SiLU.",
            f"* **Command:** `{meta.get('command', '')}`",
            f"* **Training time:** {m['train_seconds'] / 60:.1f} min on this 2-core machine "
            f"({m['total_seconds'] / 60:.1f} min with validation)."
            + (f" {meta['note']}" if meta.get("note") else ""),
            "",
            "## Held-out validation",
            "",
            f"* Value network R^2 on held-out discounted returns: {m['value_val_r2']:.3f}.",
            f"* Approximation gap |dPhi - dV_i| / range(V) over {m['val_pairs']} held-out unilateral "
            f"deviations: median {100 * m['gap_rel_median']:.2f}%, 95th percentile "
            f"{100 * m['gap_rel_p95']:.2f}%, max {100 * m['gap_rel_max']:.1f}%; "
            f"{100 * m['gap_rel_within_10pct']:.1f}% within 10%; alpha = {m['alpha']:.4f} "
            f"(range of V {m['value_range']:.3f} m).",
            f"* A constant potential (dPhi = 0) would have median {100 * m['const_rel_median']:.2f}% "
            f"and 95th percentile {100 * m['const_rel_p95']:.2f}%.",
            *(
                [
                    f"* Paired rollouts ({m['rollout_pairs']} held-out states, {m['rollout_steps']} steps "
                    f"then V): |dPhi - dG_sim| / range median {100 * m['rollout_phi_rel_median']:.2f}%, "
                    f"95th percentile {100 * m['rollout_phi_rel_p95']:.2f}%; |dV - dG_sim| median "
                    f"{100 * m['rollout_value_rel_median']:.2f}%; constant {100 * m['rollout_const_rel_median']:.2f}%."
                ]
                if "rollout_pairs" in m
                else []
            ),
            "",
        ]
    )
