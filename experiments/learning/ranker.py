"""Train a ranker (:mod:`agents.ranked`) on a rollout oracle's choices: value targets from
paired rollouts (issue 48).

Every choice of an ``alpha-racer room`` run keeps the oracle's observation and every
candidate's look-ahead score (``room/<setting>/choices/*.npz``, relative progress [m] after
``lookahead`` s from the same state). The targets are the candidates' gains over the first
candidate (the base) at that state: paired, so what every candidate shares (the state's own
outlook) cancels. A small network learns the gain of (features, candidate) and the ranked
agent drives the candidate of the largest predicted gain.

Races, not choices, are held out: every ``holdout``-th race of the folders (sorted by
bench, track and race) is the validation set, whose figures the model keeps:

* ``gain_m``: the mean gain over the base of the candidates the ranker picks, beside the
  oracle's (the best candidate at every choice, what the rollouts know) and the best single
  candidate's (one fixed move of the base, the strongest simple choice);
* ``r2``: how much of the gains' variance the predictions explain.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from agents.ranked import RankerModel, ranker_features
from experiments.evaluation.room import choices_file
from experiments.infra.artifacts import read_jsonl, write_json, write_npz
from experiments.potential.nets import to_numpy_mlp, torch_mlp
from racing_env.config import RaceConfig
from racing_env.tracks import make_track

__all__ = ["RankerConfig", "load_choices", "train_ranker"]


@dataclass(frozen=True)
class RankerConfig:
    """Training settings: ``hidden`` units per layer, ``layers`` hidden layers, ``epochs`` of
    full-batch Adam at ``lr`` with ``weight_decay``, every ``holdout``-th race held out for
    validation (and for early stopping: the weights of the best validation loss), ``seed``."""

    hidden: int = 64
    layers: int = 2
    epochs: int = 600
    lr: float = 3e-3
    weight_decay: float = 1e-3
    holdout: int = 4
    seed: int = 0

    def __post_init__(self):
        for name, lo in (("hidden", 1), ("layers", 1), ("epochs", 1), ("holdout", 2)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < lo:
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")
        for name in ("lr", "weight_decay"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a non-negative number, got {v!r}")


@dataclass
class Choices:
    """The choices of room folders: ``features`` (S, F) float32, ``gains`` (S, M) [m] every
    candidate's score minus the base's, ``race`` (S,) the index of the race each choice came
    from, ``candidates`` (M specs), ``every``, ``lookahead``, ``track``, ``vehicle_class``."""

    features: np.ndarray
    gains: np.ndarray
    race: np.ndarray
    candidates: list[str]
    every: int
    lookahead: float
    track: str
    vehicle_class: str


def load_choices(folders: list) -> Choices:
    """Every kept choice of the room folders ``folders`` (``SUITE/room/<setting>``); a
    ValueError when they hold none or differ in candidates, look-ahead, choice period, track
    or class."""
    rows, gains, race_ids, setting = [], [], [], None
    n_preview = RaceConfig().n_preview
    lengths: dict = {}  # (track, class) -> length [m]
    k = 0
    for folder in map(Path, folders):
        manifest = folder / "manifest.json"
        if not manifest.exists():
            raise ValueError(f"{folder} is not a room folder (no manifest.json)")
        meta = json.loads(manifest.read_text())
        room, suite = meta["room"], meta["suite"]
        vclass = suite.get("vehicle_class") or "orca"
        records = {
            (r["bench"], r["track"], r["race"]): r for r in read_jsonl(folder / "races.jsonl")
        }
        for key in sorted(records):
            rec = records[key]
            path = choices_file(folder, rec)
            if not path.exists():
                continue  # a race of a folder written before the choices were kept
            this = (tuple(rec["candidates"]), room["every"], room["lookahead"], key[1], vclass)
            if setting is None:
                setting = this
            elif this != setting:
                raise ValueError(
                    f"{path}: its oracle's setting {this} differs from {setting}; train on "
                    f"room folders of one setting"
                )
            with np.load(path) as z:
                obs, scores = z["observations"], z["scores"]
            if (key[1], vclass) not in lengths:
                lengths[key[1], vclass] = float(make_track(key[1], vehicle_class=vclass).length)
            rows += [ranker_features(o, n_preview, lengths[key[1], vclass]) for o in obs]
            gains.append(scores - scores[:, :1])
            race_ids += [k] * len(obs)
            k += 1
    if setting is None or not rows:
        raise ValueError(
            f"no kept choices in {[str(f) for f in folders]}: run alpha-racer room there first"
        )
    return Choices(
        features=np.array(rows, dtype=np.float32),
        gains=np.concatenate(gains).astype(np.float64),
        race=np.array(race_ids),
        candidates=list(setting[0]),
        every=int(setting[1]),
        lookahead=float(setting[2]),
        track=setting[3],
        vehicle_class=setting[4],
    )


def _pairs(features: np.ndarray, gains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows (S M, F + M): every choice's features with each candidate's one-hot, and its gain."""
    s, m = gains.shape
    x = np.concatenate(
        [np.repeat(features, m, axis=0), np.tile(np.eye(m, dtype=np.float32), (s, 1))], axis=1
    )
    return x, gains.reshape(-1)


def _figures(pred: np.ndarray, gains: np.ndarray, fixed: int) -> dict:
    """Validation figures of predicted gains ``pred`` (S, M) against the true ``gains``."""
    pick = np.argmax(pred, axis=1)
    rows = np.arange(len(gains))
    resid = pred - gains
    var = float(np.var(gains[:, 1:])) if gains.shape[1] > 1 else 0.0
    return {
        "choices": int(len(gains)),
        "gain_m": {
            "ranker": round(float(gains[rows, pick].mean()), 3),
            "oracle": round(float(gains.max(axis=1).mean()), 3),
            "best_fixed_candidate": round(float(gains[:, fixed].mean()), 3),
        },
        "best_fixed_candidate": int(fixed),
        "r2": round(1.0 - float(np.mean(resid[:, 1:] ** 2)) / var, 4) if var > 0 else None,
        "pick_share": [round(float(np.mean(pick == c)), 4) for c in range(gains.shape[1])],
    }


def train_ranker(folders: list, out, config: RankerConfig = RankerConfig()) -> dict:
    """Train a ranker on the kept choices of ``folders`` and write ``out`` (a
    ``ranker.npz``, loaded by ``ranked:model=OUT``) and ``OUT.json`` (its figures); returns
    the figures (module docstring)."""
    import torch

    data = load_choices(folders)
    races = np.unique(data.race)
    if len(races) < config.holdout:
        raise ValueError(
            f"{len(races)} races of kept choices: at least holdout = {config.holdout} needed "
            f"to hold one out"
        )
    val_races = races[config.holdout - 1 :: config.holdout]
    val = np.isin(data.race, val_races)
    train = ~val
    # the best single candidate on the training races: the simple rival of a state-dependent pick
    fixed = int(np.argmax(data.gains[train].mean(axis=0)))
    x_tr, y_tr = _pairs(data.features[train], data.gains[train])
    x_va, y_va = _pairs(data.features[val], data.gains[val])
    mean = x_tr.mean(axis=0)
    std = np.maximum(x_tr.std(axis=0), 1e-3)
    y_scale = float(max(np.std(y_tr), 1e-3))

    torch.manual_seed(config.seed)
    net = torch_mlp(x_tr.shape[1], (config.hidden,) * config.layers, torch)
    opt = torch.optim.AdamW(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)

    def tensor(x, y):
        xt = torch.tensor((x - mean) / std, dtype=torch.float32)
        return xt, torch.tensor(y / y_scale, dtype=torch.float32)

    xt, yt = tensor(x_tr, y_tr)
    xv, yv = tensor(x_va, y_va)
    best_loss, best_state, best_epoch = np.inf, None, 0
    for epoch in range(config.epochs):
        net.train()
        opt.zero_grad()
        loss = torch.mean((net(xt)[:, 0] - yt) ** 2)
        loss.backward()
        opt.step()
        with torch.no_grad():
            v = float(torch.mean((net(xv)[:, 0] - yv) ** 2))
        if not np.isfinite(v):
            raise FloatingPointError(f"the ranker's validation loss is {v} at epoch {epoch}")
        if v < best_loss:
            best_loss, best_epoch = v, epoch
            best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
    assert best_state is not None
    net.load_state_dict(best_state)
    mlp = to_numpy_mlp(net, mean, std, y_scale, 0.0)
    m = len(data.candidates)

    def predict(features):
        x, _ = _pairs(features, np.zeros((len(features), m)))
        return mlp(x).reshape(len(features), m)

    figures = {
        "config": asdict(config),
        "folders": [str(f) for f in folders],
        "candidates": data.candidates,
        "track": data.track,
        "vehicle_class": data.vehicle_class,
        "every": data.every,
        "lookahead": data.lookahead,
        "races": {"train": int(len(races) - len(val_races)), "validation": int(len(val_races))},
        "best_epoch": int(best_epoch),
        "train": _figures(predict(data.features[train]), data.gains[train], fixed),
        "validation": _figures(predict(data.features[val]), data.gains[val], fixed),
    }
    out = Path(out)
    write_npz(out, meta=np.array(json.dumps(figures)), **mlp.to_arrays(""))
    write_json(out.with_suffix(".json"), figures)
    RankerModel.load(out)  # what the agent will read
    return figures
