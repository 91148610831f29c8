"""Network training and checkpointing shared by :mod:`experiments.potential.train` (one track, one
field size) and :mod:`experiments.potential.train_general` (a family of tracks and field sizes): the
:class:`TrainConfig`, the discounted-return targets, the value and potential stages (each
checkpointed every epoch / ``save_every`` steps and resumed from its checkpoint), the numpy
model they turn into, the policy space of a collection and of a training run
(:func:`collection_space`, :func:`check_run_space`), and the gap statistics and summary both
report."""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from agents.mlp import MLP
from agents.potential import PotentialModel
from agents.theta import PolicySpace, policy_space
from experiments.infra.artifacts import claim, write_json, write_text
from experiments.infra.checks import check_counts
from experiments.potential.validation import summary_text
from racing_env.files import atomic_path

OBJECTIVES = ("mse", "smoothmax", "tail")


# progress bars redraw twice a second on a terminal, once a minute into a log file
_BAR_INTERVAL = 0.5 if sys.stderr.isatty() else 60.0


@dataclass(frozen=True)
class TrainConfig:
    """Everything that shapes a model. Defaults: the paper's sizes, gamma 0.99."""

    gamma: float = 0.99
    val_fraction: float = 0.1  # share of races held out (whole races)
    seed: int = 0
    # value network
    value_hidden: tuple = (128, 128, 64)
    value_epochs: int = 8
    value_batch: int = 4096
    value_lr: float = 2e-3
    value_stride: int = 2  # use every k-th step of a race (neighbours are near-copies)
    # potential network
    potential_hidden: tuple = (384, 384, 192)
    potential_steps: int = 4000
    potential_batch: int = 1024
    potential_lr: float = 1e-3
    objective: str = "tail"
    tail_fraction: float = 0.2
    smoothmax_tau: float = 0.05  # in units of the normalised gap
    warmup_fraction: float = 0.3  # MSE warm-up share of the steps for min-max objectives
    own_theta_fraction: float = 0.5  # pairs whose base theta is the race's own
    save_every: int = 500
    # validation
    val_pairs: int = 20000
    rollout_pairs: int = 40
    rollout_steps: int = 300
    threads: int = 2

    def __post_init__(self):
        if not 0.0 < self.gamma < 1.0:
            raise ValueError(f"gamma must be in (0, 1), got {self.gamma!r}")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in (0, 1), got {self.val_fraction!r}")
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {OBJECTIVES}, got {self.objective!r}")
        check_counts(
            self,
            (
                "value_epochs",
                "value_batch",
                "value_stride",
                "potential_steps",
                "potential_batch",
                "save_every",
                "val_pairs",
                "rollout_steps",
                "threads",
            ),
        )
        if not (isinstance(self.rollout_pairs, int) and self.rollout_pairs >= 0):
            raise ValueError(
                f"TrainConfig.rollout_pairs must be an integer >= 0, got {self.rollout_pairs!r}"
            )
        if not 0.0 < self.tail_fraction <= 1.0:
            raise ValueError(f"tail_fraction must be in (0, 1], got {self.tail_fraction!r}")
        for name in ("value_hidden", "potential_hidden"):
            h = getattr(self, name)
            if not (len(h) >= 1 and all(isinstance(k, (int, np.integer)) and k >= 1 for k in h)):
                raise ValueError(
                    f"TrainConfig.{name} must be a tuple of positive layer widths, got {h!r}"
                )
            object.__setattr__(self, name, tuple(int(k) for k in h))


def collection_space(
    data_dir, manifest: dict, theta_dim: int | None = None, asked: str | None = None
) -> PolicySpace:
    """The policy space of the collection at ``data_dir``: its manifest's ``space`` (a
    collection made before spaces existed, or a family collection, is the paper's). A
    ``ValueError`` naming both when the thetas' last dimension ``theta_dim`` (given once the
    data are loaded) is not that space's, or when ``asked`` (``alpha-racer train --space``)
    is another space."""
    space = policy_space(manifest.get("config", {}).get("space", "paper"))
    if theta_dim is not None and theta_dim != space.dim:
        raise ValueError(
            f"{data_dir}: the manifest says the {space.name!r} policy space "
            f"({space.dim} parameters), the thetas have {theta_dim}"
        )
    if asked is not None and policy_space(asked).name != space.name:
        raise ValueError(
            f"{data_dir} holds races of the {space.name!r} policy space, "
            f"--space {policy_space(asked).name} was asked for"
        )
    return space


def claim_training_run(
    out: Path, cfg: TrainConfig, data_dir, manifest: dict, space: PolicySpace, head: dict
) -> None:
    """Tie the training run in ``out`` to its settings, both trainings' way: refuse data of
    another policy space than the run started on (:func:`check_run_space`), then claim
    ``train_config.json`` with ``head`` (the feature set's version), the config without
    ``threads`` (how fast, not what: may change on a resume), the collection's ``manifest``
    and the space when it is not the paper's (recorded as collections do)."""
    check_run_space(out, space, data_dir)
    out.mkdir(parents=True, exist_ok=True)
    config = json.loads(json.dumps(asdict(cfg)))
    config.pop("threads")
    meta = {**head, "config": config, "data": manifest}
    if space.name != "paper":
        meta["space"] = space.name
    claim(out / "train_config.json", meta, "a training run (config or data)")


def check_run_space(out: Path, space: PolicySpace, data_dir) -> None:
    """Refuse to continue the training run in ``out`` on data of another policy space than
    it started on (a ``ValueError`` naming both, before anything is loaded)."""
    path = Path(out) / "train_config.json"
    if not path.exists():
        return
    stored = json.loads(path.read_text())
    have = stored.get("space", stored.get("data", {}).get("config", {}).get("space", "paper"))
    if have != space.name:
        raise ValueError(
            f"{out} holds a training run on the {have!r} policy space; the races "
            f"in {data_dir} are of the {space.name!r} space. Use another --out"
        )


def discounted_partial_returns(rewards: np.ndarray, gamma: float):
    """``P[:, t] = sum_{k < T - t} gamma^k r[:, t + k]`` and ``gamma^(T - t)``, for rewards
    (R, T, N): returns (P (R, T, N), tail (T,))."""
    R, T, N = rewards.shape
    P = np.empty((R, T, N), dtype=np.float64)
    acc = np.zeros((R, N))
    for t in range(T - 1, -1, -1):
        acc = rewards[:, t].astype(np.float64) + gamma * acc
        P[:, t] = acc
    return P, gamma ** (T - np.arange(T, dtype=np.float64))


def split_races(n_races: int, val_fraction: float, seed: int):
    """(train, val) race indices: a seeded permutation, whole races on either side."""
    perm = np.random.default_rng(seed).permutation(n_races)
    n_val = max(1, int(round(val_fraction * n_races)))
    if n_val >= n_races:
        raise ValueError(
            f"{n_races} races cannot be split into training and validation "
            f"(val_fraction {val_fraction}); collect more races"
        )
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def torch_mlp(in_dim: int, hidden, torch):
    layers, d = [], in_dim
    for h in hidden:
        layers += [torch.nn.Linear(d, h), torch.nn.SiLU()]
        d = h
    layers.append(torch.nn.Linear(d, 1))
    return torch.nn.Sequential(*layers)


def to_numpy_mlp(net, mean, std, y_scale, y_shift) -> MLP:
    lin = [m for m in net if hasattr(m, "weight")]
    return MLP(
        [(m.weight.detach().numpy().T, m.bias.detach().numpy()) for m in lin],
        mean,
        std,
        y_scale,
        y_shift,
    )


def numpy_model(value, potential, meta: dict) -> PotentialModel:
    """The numpy :class:`PotentialModel` of the trained (normalised) torch networks."""
    return PotentialModel(
        *(
            to_numpy_mlp(n.net, n.mean.numpy(), n.std.numpy(), n.y_scale, n.y_shift)
            for n in (value, potential)
        ),
        meta,
    )


#: the training stages' seconds so far, in the output folder (a resumed run adds its own)
TIMING_FILE = "timing.json"


def save_model(model: PotentialModel, metrics: dict, out: Path, card_text, command: str) -> None:
    """Record ``metrics`` and ``command`` in the model and write ``model.npz``,
    ``metrics.json`` and ``model_card.md`` (``card_text(meta)``) into ``out``."""
    model.meta["metrics"] = metrics
    model.meta["command"] = command
    model.save(out / "model.npz")
    write_json(out / "metrics.json", metrics)
    write_text(out / "model_card.md", card_text(model.meta))


def _resume(ckpt: Path, net, opt, sched, torch) -> dict | None:
    """Load a training checkpoint written by :func:`_save_atomic_torch` into ``net``, ``opt``
    and ``sched``; returns its dict (epoch or step, history), or None when there is none."""
    if not ckpt.exists():
        return None
    st = torch.load(ckpt, weights_only=False)
    net.load_state_dict(st["net"])
    opt.load_state_dict(st["opt"])
    sched.load_state_dict(st["sched"])
    return st


def _save_atomic_torch(obj, path: Path, torch):
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


class Normalised:
    """A torch MLP with fixed input normalisation and output scale (what MLP evaluates)."""

    def __init__(self, net, mean, std, y_scale, y_shift, torch):
        self.net, self.torch = net, torch
        self.mean = torch.as_tensor(mean, dtype=torch.float32)
        self.std = torch.as_tensor(std, dtype=torch.float32)
        self.y_scale, self.y_shift = float(y_scale), float(y_shift)

    def raw(self, x):
        return self.net((x - self.mean) / self.std)[..., 0]

    def __call__(self, x):
        return self.raw(x) * self.y_scale + self.y_shift


def value_samples(states, thetas, races, stride, T, N):
    """(race, t, car) triples of the value dataset: every ``stride``-th step, every car."""
    t = np.arange(0, T, stride)
    r, tt, c = np.meshgrid(races, t, np.arange(N), indexing="ij")
    return r.ravel(), tt.ravel(), c.ravel()


@dataclass
class ValueData:
    """The value network's dataset. ``X_tr`` (n, D), ``X_va`` (m, D) float32 features of
    (race, step, car) samples and ``X_end`` (E, D) those of every race's final state per car;
    the discounted-return target of a sample is ``P + tail * V(X_end[end])`` (the observed
    discounted rewards plus the bootstrap with the current network), with ``P``, ``tail``,
    ``end`` per sample (``*_tr`` and ``*_va``). ``general``: the features are padded (columns
    constant in training keep unit scale, see :func:`input_scale`)."""

    X_tr: np.ndarray
    X_va: np.ndarray
    X_end: np.ndarray
    P_tr: np.ndarray
    tail_tr: np.ndarray
    end_tr: np.ndarray
    P_va: np.ndarray
    tail_va: np.ndarray
    end_va: np.ndarray
    general: bool = False


def input_scale(X: np.ndarray, general: bool = False):
    """``(mean, std)`` (D,) of the input normalisation from training features ``X`` (n, D).
    ``general``: a column that never varies in training (an empty slot of a field size the
    data lack, a presence flag that is always set) keeps unit scale instead of 1e-6, so a
    larger field at racing time gives finite inputs."""
    mean, std = X.mean(axis=0), X.std(axis=0)
    if general:
        std = np.where(std < 1e-3, 1.0, std)
    return mean, std + 1e-6


def train_value(data: ValueData, cfg, out, torch, progress_bar, log):
    rng = np.random.default_rng(cfg.seed)
    X_tr, X_va, X_end = data.X_tr, data.X_va, data.X_end
    mean, std = input_scale(X_tr, data.general)
    y0 = data.P_tr
    y_shift, y_scale = float(y0.mean()), float(y0.std() + 1e-9)
    net = torch_mlp(X_tr.shape[1], cfg.value_hidden, torch)
    model = Normalised(net, mean, std, y_scale, y_shift, torch)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.value_lr)
    steps_per_epoch = -(-len(X_tr) // cfg.value_batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=cfg.value_lr, pct_start=0.1, total_steps=cfg.value_epochs * steps_per_epoch
    )
    ckpt = out / "value_ckpt.pt"
    epoch0, history = 0, []
    st = _resume(ckpt, net, opt, sched, torch)
    if st is not None:
        epoch0, history = st["epoch"], st["history"]
        log(f"value: resuming after epoch {epoch0}")
    Xt, Xv, Xe = (torch.from_numpy(a) for a in (X_tr, X_va, X_end))
    tr = (data.P_tr, data.tail_tr, data.end_tr)
    va = (data.P_va, data.tail_va, data.end_va)

    def targets(parts):
        P, tail, end = parts
        with torch.no_grad():
            v_end = model(Xe).numpy().astype(np.float64)
        return P + tail * v_end[end]

    t0 = time.perf_counter()
    for epoch in range(epoch0, cfg.value_epochs):
        y = torch.from_numpy(((targets(tr) - y_shift) / y_scale).astype(np.float32))
        perm = torch.from_numpy(rng.permutation(len(X_tr)))
        net.train()
        total = 0.0
        bar = tqdm(
            range(steps_per_epoch),
            desc=f"value epoch {epoch + 1}/{cfg.value_epochs}",
            disable=not progress_bar,
            leave=False,
            mininterval=_BAR_INTERVAL,
        )
        for b in bar:
            idx = perm[b * cfg.value_batch : (b + 1) * cfg.value_batch]
            loss = torch.nn.functional.mse_loss(model.raw(Xt[idx]), y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(idx)
        yv = targets(va)
        with torch.no_grad():
            pv = model(Xv).numpy()
        r2 = 1.0 - np.mean((pv - yv) ** 2) / np.var(yv)
        history.append(
            {"epoch": epoch + 1, "train_mse_normalised": total / len(X_tr), "val_r2": float(r2)}
        )
        log(
            f"value epoch {epoch + 1}: train mse {total / len(X_tr):.4f} (normalised), "
            f"held-out R^2 {r2:.4f}"
        )
        _save_atomic_torch(
            {
                "net": net.state_dict(),
                "opt": opt.state_dict(),
                "sched": sched.state_dict(),
                "epoch": epoch + 1,
                "history": history,
            },
            ckpt,
            torch,
        )
    yv = targets(va)
    with torch.no_grad():
        pv = model(Xv).numpy()
    model.metrics = {
        "value_val_r2": float(1.0 - np.mean((pv - yv) ** 2) / np.var(yv)),
        "value_val_rmse": float(np.sqrt(np.mean((pv - yv) ** 2))),
        "value_target_std": float(np.std(yv)),
        "value_history": history,
        "value_seconds_this_run": time.perf_counter() - t0,
    }
    net.eval()
    return model


def train_potential(data, cfg, value, out, torch, progress_bar, log):
    """Fit Phi on deviations drawn from ``data`` (a :class:`_Deviations` or its family
    counterpart) so that dPhi matches dV_i."""
    rng = np.random.default_rng(cfg.seed + 1)
    # input normalisation from a sample of training states with uniform thetas
    F = data.potential_features(data.draw(20000, rng), 1)
    mean, std = input_scale(F, data.general)
    batch = data.draw(20000, rng)
    f32 = lambda a: torch.from_numpy(a.astype(np.float32))
    with torch.no_grad():
        dv = value(f32(data.value_features(batch, 2))) - value(f32(data.value_features(batch, 1)))
    y_scale = float(dv.std() + 1e-9)  # gaps are learned in units of std(dV)
    net = torch_mlp(data.potential_dim, cfg.potential_hidden, torch)
    phi = Normalised(net, mean, std, y_scale, 0.0, torch)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.potential_lr)
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=cfg.potential_lr, pct_start=0.1, total_steps=cfg.potential_steps
    )
    ckpt = out / "potential_ckpt.pt"
    step0, history = 0, []
    st = _resume(ckpt, net, opt, sched, torch)
    if st is not None:
        step0, history = st["step"], st["history"]
        rng = np.random.default_rng([cfg.seed + 1, step0])
        log(f"potential: resuming after step {step0}")
    warm = (
        int(cfg.warmup_fraction * cfg.potential_steps)
        if cfg.objective != "mse"
        else cfg.potential_steps
    )
    t0 = time.perf_counter()
    bar = tqdm(
        range(step0, cfg.potential_steps),
        desc="potential",
        disable=not progress_bar,
        initial=step0,
        total=cfg.potential_steps,
        mininterval=_BAR_INTERVAL,
    )
    window = []
    for step in bar:
        batch = data.draw(cfg.potential_batch, rng)
        fv1, fv2 = (f32(data.value_features(batch, k)) for k in (1, 2))
        fp1, fp2 = (f32(data.potential_features(batch, k)) for k in (1, 2))
        with torch.no_grad():
            dv = (value(fv2) - value(fv1)) / y_scale
        gap = (phi.raw(fp2) - phi.raw(fp1)) - dv
        if step < warm or cfg.objective == "mse":
            loss = (gap**2).mean()
        elif cfg.objective == "tail":
            k = max(1, int(cfg.tail_fraction * len(gap)))
            loss = torch.topk(gap.abs(), k).values.pow(2).mean()
        else:
            tau = cfg.smoothmax_tau
            loss = tau * (torch.logsumexp(gap.abs() / tau, 0) - np.log(len(gap)))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        window.append(float(gap.detach().abs().median()))
        if (step + 1) % 100 == 0:
            bar.set_postfix(median_gap=f"{np.mean(window):.3f}")
            history.append({"step": step + 1, "median_abs_gap_std_units": float(np.mean(window))})
            window = []
        if (step + 1) % cfg.save_every == 0 or step + 1 == cfg.potential_steps:
            _save_atomic_torch(
                {
                    "net": net.state_dict(),
                    "opt": opt.state_dict(),
                    "sched": sched.state_dict(),
                    "step": step + 1,
                    "history": history,
                },
                ckpt,
                torch,
            )
    bar.close()
    net.eval()
    value.metrics["potential_history"] = history
    value.metrics["potential_seconds_this_run"] = time.perf_counter() - t0
    return phi


@dataclass
class TrainingRun:
    """One training run in ``out``, both trainings' way (:meth:`open`, :meth:`fit`,
    :meth:`finish`) on the collection at ``data_dir``: the config, torch, the progress bar and
    log, the collection's ``manifest`` and policy ``space``, the ``command`` the model card
    names, ``t_start`` (the clock after the claim) and ``train_seconds`` (of the two stages,
    once fitted)."""

    data_dir: Path
    cfg: TrainConfig
    out: Path
    torch: object
    progress_bar: bool
    log: object
    manifest: dict
    space: PolicySpace
    command: str
    t_start: float
    train_seconds: float = 0.0
    _fitted_at: float = 0.0  # the clock when fit() ended

    @classmethod
    def open(
        cls,
        data_dir,
        out_dir,
        cfg: TrainConfig,
        space,
        head: dict,
        torch,
        progress_bar,
        log,
        command,
    ) -> TrainingRun:
        """Set torch's threads and seed (the networks' initial weights: same data, same model),
        read the collection's manifest and policy space (``space``, when given, must be it)
        and claim the run in ``out_dir`` with ``head`` (:func:`claim_training_run`)."""
        torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        out = Path(out_dir)
        manifest = json.loads((Path(data_dir) / "manifest.json").read_text())
        sp = collection_space(data_dir, manifest, asked=space)
        claim_training_run(out, cfg, data_dir, manifest, sp, head)
        command = command or f"alpha-racer train --data {data_dir} --out {out_dir}"
        return cls(
            data_dir, cfg, out, torch, progress_bar, log, manifest, sp, command, time.perf_counter()
        )

    def split(self, n_races: int, theta_dim: int):
        """The (train, val) race indices (:func:`split_races`), once the loaded thetas' last
        dimension ``theta_dim`` is checked to be the collection's space's
        (:func:`collection_space`)."""
        collection_space(self.data_dir, self.manifest, theta_dim)
        return split_races(n_races, self.cfg.val_fraction, self.cfg.seed)

    def fit(self, value_data: ValueData, deviations):
        """The value stage on ``value_data``, then the potential stage on ``deviations``;
        returns the two (normalised torch) networks."""
        out, torch, bar, log = self.out, self.torch, self.progress_bar, self.log
        value = train_value(value_data, self.cfg, out, torch, bar, log)
        potential = train_potential(deviations, self.cfg, value, out, torch, bar, log)
        # the stages' seconds summed over the invocations that ran them: a run resumed after
        # both stages finished adds only its loading, not a new (short) training time
        timing = out / TIMING_FILE
        before = json.loads(timing.read_text())["train_seconds"] if timing.exists() else 0.0
        self.train_seconds = before + time.perf_counter() - self.t_start
        write_json(timing, {"train_seconds": self.train_seconds})
        self._fitted_at = time.perf_counter()
        return value, potential

    def finish(self, value, potential, meta: dict, data: dict, gaps, rollouts, card_text) -> dict:
        """The numpy model of the fitted networks with ``meta`` (then the policy space, the
        config, ``data`` and the training time), validated by ``gaps(model)`` and, unless
        ``rollout_pairs`` is 0, ``rollouts(model, value_range)``; saves it with its metrics and
        card (:func:`save_model`) and returns the metrics."""
        sp, cfg = self.space, self.cfg
        meta = {
            **meta,
            "space": sp.name,
            "theta_low": sp.low.tolist(),
            "theta_high": sp.high.tolist(),
            "gamma": cfg.gamma,
            "config": asdict(cfg),
            "data": data,
            "train_seconds": self.train_seconds,
        }
        model = numpy_model(value, potential, meta)
        self.log("validation on held-out races ...")
        metrics = {"train_seconds": self.train_seconds, **value.metrics, **gaps(model)}
        if cfg.rollout_pairs:
            metrics.update(rollouts(model, metrics["value_range"]))
        # training (over every invocation) plus this invocation's validation
        metrics["total_seconds"] = self.train_seconds + time.perf_counter() - self._fitted_at
        save_model(model, metrics, self.out, card_text, self.command)
        self.log(summary_text(metrics))
        return metrics
