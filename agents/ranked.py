"""The ranked agent: an MPC that chooses its theta among a rollout oracle's candidates by a
network trained on the oracle's look-ahead scores (issue 48, "value targets from paired
rollouts").

The room's oracle (:mod:`experiments.evaluation.oracle`) simulates each candidate theta from
the exact state of the race and keeps the best; its scores at every choice are paired
rollouts of the same state, the targets a value estimate of "this theta here" needs. A
ranker (:mod:`experiments.learning.ranker`) learns from them the gain [m] of each candidate
over the first (the base, a fixed theta) from what the car observes. This agent asks it
every ``every`` control periods, as the oracle chose, and drives the candidate with the
largest predicted gain until the next choice: the oracle's choice without its rollouts, so
its margin over the base in the same seats is the part of the room that the state alone
tells.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from racing_env.observation import cars_in_observation
from racing_env.track import Track
from racing_env.tracks import make_track

from .base import make_agent_spec, parse_value, register_agent, spec_params
from .mlp import MLP
from .mpc_agent import MPCAgent

__all__ = ["RankedAgent", "RankerModel", "ranker_features"]


def ranker_features(observation: np.ndarray, n_preview: int, track_length: float) -> np.ndarray:
    """The ranker's input (7 + 6 (N - 1) + n_preview,) float32 from a car's env observation
    (``6 N + n_preview``: its state, the others' relative states, the curvature preview):
    where it is on the lap as ``(sin, cos)`` of ``2 pi s / L`` (``track_length`` L [m]), its
    ``n, mu, vx, vy, omega``, the others' relative states sorted by relative progress (the
    car furthest ahead first, so car numbering does not matter), and the preview."""
    obs = np.asarray(observation, dtype=np.float64)
    n_cars = cars_in_observation(len(obs), n_preview)
    if not track_length > 0:
        raise ValueError(f"track_length must be a positive length [m], got {track_length!r}")
    phase = 2.0 * np.pi * obs[0] / track_length
    others = obs[6 : 6 * n_cars].reshape(n_cars - 1, 6)
    others = others[np.argsort(-others[:, 0], kind="stable")]
    return np.concatenate(
        [[np.sin(phase), np.cos(phase)], obs[1:6], others.ravel(), obs[6 * n_cars :]]
    ).astype(np.float32)


class RankerModel:
    """A trained ranker (``ranker.npz`` of :func:`experiments.learning.ranker.train_ranker`):
    ``net`` (an :class:`~agents.mlp.MLP` of the features followed by a one-hot candidate
    index, predicting the candidate's gain [m] over the base), ``candidates`` (``mpc`` agent
    specs, the first the base), ``every`` (periods between choices), ``lookahead`` [s] and
    ``meta`` (track, vehicle class, training figures)."""

    def __init__(self, net: MLP, candidates: list[str], every: int, lookahead: float, meta: dict):
        if net.in_dim <= len(candidates):
            raise ValueError(
                f"a ranker of {len(candidates)} candidates needs more inputs than that, "
                f"got {net.in_dim}"
            )
        self.net = net
        self.candidates = list(candidates)
        self.every = int(every)
        self.lookahead = float(lookahead)
        self.meta = dict(meta)

    @classmethod
    def load(cls, path: str | Path) -> RankerModel:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"ranker model {str(path)!r} does not exist (a ranker.npz)")
        with np.load(path) as z:
            net = MLP.from_arrays(z, "")
            meta = json.loads(str(z["meta"]))
        return cls(net, meta["candidates"], meta["every"], meta["lookahead"], meta)

    def gains(self, features: np.ndarray) -> np.ndarray:
        """Predicted gain [m] over the base (M,) of every candidate, from one feature row."""
        m = len(self.candidates)
        x = np.concatenate([np.repeat(features[None, :], m, axis=0), np.eye(m)], axis=1)
        return np.asarray(self.net(x), dtype=np.float64).reshape(m)


@register_agent("ranked")
class RankedAgent(MPCAgent):
    """An MPC choosing its theta every ``every`` periods among a ranker's candidates (module
    docstring). ``model``: the path of a ``ranker.npz``; ``every``: periods between choices
    (default: the model's, the oracle's); ``margin`` [m]: a candidate replaces the base only
    when its predicted gain exceeds the base's by more than this (default 0). ``zeta_max``
    as for :class:`~agents.mpc_agent.MPCAgent`. ``stats`` adds ``candidate_share``: how often
    each candidate was chosen."""

    def __init__(
        self,
        model: str = "",
        every: int | None = None,
        margin: float = 0.0,
        zeta_max: float | None = None,
    ):
        if not model:
            raise ValueError("ranked needs model=PATH, a ranker.npz of alpha-racer ranker train")
        self.model = RankerModel.load(model)
        bases = []
        for spec in self.model.candidates:
            agent = make_agent_spec(spec)
            if type(agent) is not MPCAgent:
                raise ValueError(f"ranker candidate {spec!r} is not an mpc agent spec")
            bases.append(agent)
        # the MPC the oracle drove: its first candidate's, all its settings, the theta swapped
        settings: dict[str, Any] = {
            k: parse_value(v) for k, v in spec_params(self.model.candidates[0])[1].items()
        }
        if zeta_max is not None:
            settings["zeta_max"] = zeta_max
        super().__init__(**settings)
        self.thetas = [b.theta for b in bases]
        meta = self.model.meta
        own = make_track(meta["track"], vehicle_class=meta["vehicle_class"])
        self._own_track = (own.name, own.vehicle_class)
        if every is not None and not (isinstance(every, int) and every >= 1):
            raise ValueError(f"every must be a positive number of periods, got {every!r}")
        self.every = self.model.every if every is None else every
        if not np.isfinite(margin) or margin < 0:
            raise ValueError(f"margin must be a non-negative distance [m], got {margin!r}")
        self.margin = float(margin)
        self._periods = 0
        self._counts = np.zeros(len(self.thetas), dtype=np.int64)

    def check_track(self, track: Track) -> None:
        """A ``ValueError`` on a track or class other than the ranker's (its features place
        the car on the lap it learned)."""
        super().check_track(track)
        if (track.name, track.vehicle_class) != self._own_track:
            meta = self.model.meta
            raise ValueError(
                f"this ranker was trained on {meta['track']!r} ({meta['vehicle_class']}), "
                f"not on {track.name!r} ({track.vehicle_class})"
            )

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        track = make_track(track)
        self.check_track(track)  # before the MPC is built
        super().reset(track, agent_id, seed)
        self.theta = self.thetas[0]
        self._periods = 0
        self._counts[:] = 0

    def _before_solve(self, observation: np.ndarray) -> None:
        if self._periods % self.every == 0:
            assert self.track is not None
            x = ranker_features(observation, self.n_preview, float(self.track.length))
            gains = self.model.gains(x)
            best = int(np.argmax(gains))
            if gains[best] - gains[0] <= self.margin:
                best = 0
            self.theta = self.thetas[best]
            self._counts[best] += 1
        self._periods += 1

    @property
    def stats(self) -> dict:
        total = max(1, int(self._counts.sum()))
        return {**super().stats, "candidate_share": [round(c / total, 4) for c in self._counts]}
