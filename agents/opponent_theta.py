"""The opponents' thetas estimated from their observed play (the alpha agent's ``others="estimate"``).

An opponent is taken to be an MPC car of the package's kind (:class:`agents.mpc_agent.MPCAgent`)
racing one of a few *types*: thetas known to the ego, by default the track's best fixed theta
(the published control, :mod:`agents.best_theta`) and its one-parameter moves
(:data:`agents.theta.MOVES`). :class:`ThetaEstimator` drives one copy of the MPC per opponent and
type from that opponent's seat: every control period each copy plans from the opponent's
observed state (with the other cars, the ego among them, where they are), and at the next
period its predicted state is compared with where the opponent went. A type's *score* is its
discounted sum of squared prediction errors (position, and velocity times the period, in car
widths); the estimate is the type of least score, but the first type (the published control)
before any evidence and unless another type beats it clearly (:data:`PRIOR_RATIO`,
:data:`PRIOR_FLOOR`). This is inverse planning over a
finite set of types: the copy of the opponent's own type replays its plans, so its errors stay
at the model's mismatch (the wake, contacts), while a type that would have braked, turned or
blocked differently is found out once the two plans part.

It costs one MPC step per opponent and type per decision (2 opponents x 5 types: 10 steps).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from racing_env.track import Track
from racing_env.vehicles import vehicle_for_track

from .mpc_agent import MPCAgent
from .theta import Theta

#: How far another type must predict better than the first (the published control) to be
#: chosen: its score below ``(1 - PRIOR_RATIO)`` of the first's, less ``PRIOR_FLOOR`` [car
#: widths^2]. Types whose plans agree (an overtaking clearance with no car to pass) score the
#: same up to rounding, and a contact, which no copy predicts, raises every score alike.
PRIOR_RATIO = 0.5
PRIOR_FLOOR = 1e-4

#: Per control period, the weight of past evidence in a type's score (a time constant of
#: 1 / (1 - FORGET) = 20 periods, 2 s at the MPC's 0.1 s): long enough to tell types whose
#: plans part only near another car, short enough to follow an opponent that changes its theta
#: (an alpha agent).
FORGET = 0.95


class ThetaEstimator:
    """Estimate each opponent's theta among ``types`` from its observed states.

    ``types``: the candidate thetas (each one a :class:`Theta`; the first is the prior, kept on
    ties); ``space``: the policy space the copies drive them in (``"paper"``, ``"extended"`` or
    ``"wake"``); ``n_preview``: the length of the curvature preview of the observations the
    copies get (their MPC does not read it); ``forget``: :data:`FORGET`.

    Call :meth:`reset` at every race's start and :meth:`update` once per decision with the
    ego's view of the joint state; :attr:`index` holds each opponent's estimated type.
    """

    def __init__(self, types: Sequence[Theta], space: str, n_preview: int, forget: float = FORGET):
        if not len(types):
            raise ValueError("the estimator needs at least one type")
        if not 0.0 <= forget < 1.0:
            raise ValueError(f"forget must be in [0, 1), got {forget!r}")
        self.types = list(types)
        self.space = space
        self.n_preview = int(n_preview)
        self.forget = float(forget)
        self.track: Track | None = None
        self.copies: list[list[MPCAgent]] = []  # [opponent][type]
        self._width = 1.0  # the cars' width [m], set at reset
        self.scores = np.zeros((0, len(self.types)))  # (N-1, K) discounted squared errors [w^2]
        self._predicted: np.ndarray | None = None  # (N-1, K, 4) (s, n, vx, vy) at the next period
        self.index = np.zeros(0, dtype=int)  # (N-1,) each opponent's estimated type

    def reset(self, track: Track, ego_index: int = 0) -> None:
        """Forget the last race: the copies are built (or reset) at the first :meth:`update`.
        ``ego_index``: the ego's place in the field's agent order (the opponents' observations
        list the other cars in that order)."""
        self.track = track
        self.ego_index = int(ego_index)
        self._width = float(vehicle_for_track(track, None, "ThetaEstimator").width)  # [m]
        for row in self.copies:
            for copy in row:
                copy.reset(track)
        self._predicted = None
        self.scores = np.zeros((len(self.copies), len(self.types)))
        self.index = np.zeros(len(self.copies), dtype=int)

    def _build(self, n_opponents: int) -> None:
        assert self.track is not None  # reset() first
        self.copies = []
        for _ in range(n_opponents):
            row = []
            for theta in self.types:
                copy = MPCAgent(space=self.space, n_preview=self.n_preview)
                copy.theta = theta
                copy.reset(self.track)
                row.append(copy)
            self.copies.append(row)
        self.scores = np.zeros((n_opponents, len(self.types)))
        self.index = np.zeros(n_opponents, dtype=int)

    def observation_of(self, j: int, ego: np.ndarray, others: np.ndarray) -> np.ndarray:
        """Opponent ``j``'s observation (``6 N + n_preview``, the preview zero) rebuilt from the
        ego's view: its own state (``s`` wrapped), then every other car's state minus its own,
        in the field's agent order (the ego at ``ego_index``)."""
        assert self.track is not None
        at = min(self.ego_index, len(others))  # the ego's row in the field
        field = np.insert(others, at, ego, axis=0)
        me = others[j]
        rest = np.delete(field, j + (j >= at), axis=0)
        rel = rest - me[None, :]
        rel[:, 2] = np.angle(np.exp(1j * rel[:, 2]))
        own = me.copy()
        own[0] = own[0] % self.track.length
        return np.concatenate([own, rel.ravel(), np.zeros(self.n_preview)])

    def update(self, ego: np.ndarray, others: np.ndarray) -> np.ndarray:
        """Score the types' last predictions against the opponents' states ``others`` (N-1, 6),
        plan every copy from them, and return each opponent's estimated type (N-1,) (also
        :attr:`index`). ``ego`` (6,): the ego's state."""
        assert self.track is not None, "reset(track) before update()"
        others = np.asarray(others, dtype=float)
        if len(self.copies) != len(others):
            self._build(len(others))
            self._predicted = None
        L = self.track.length
        if self._predicted is not None:
            seen = others[:, [0, 1, 3, 4]]
            err = self._predicted - seen[:, None, :]
            err[..., 0] = (err[..., 0] + 0.5 * L) % L - 0.5 * L  # arc length on the lap
            dt = self.copies[0][0].config.dt
            err[..., 2:] *= dt  # velocity errors as the distance they make in one period
            sq = np.sum(err**2, axis=-1) / self._width**2
            missing = ~np.isfinite(sq)  # a copy whose step failed made no prediction
            if missing.any():  # it scores as the worst type of that opponent this period
                worst = np.nanmax(np.where(missing, np.nan, sq), axis=1, initial=0.0)
                sq = np.where(missing, worst[:, None], sq)
            self.scores = self.forget * self.scores + sq
        predicted = np.full((len(others), len(self.types), 4), np.nan)
        for j, row in enumerate(self.copies):
            obs = self.observation_of(j, ego, others)
            for k, copy in enumerate(row):
                copy.act(obs)
                assert copy.mpc is not None  # act() checked reset()
                X = copy.mpc.last_prediction
                if X is not None:
                    predicted[j, k] = X[[0, 1, 3, 4], 0]  # the state one period on
        self._predicted = predicted
        self.index = self.choose(self.scores)
        return self.index

    @staticmethod
    def choose(scores: np.ndarray) -> np.ndarray:
        """Each row's estimated type of ``scores`` (M, K): the least score's column if it is
        clearly below the first column's (:data:`PRIOR_RATIO`, :data:`PRIOR_FLOOR`), else 0."""
        scores = np.asarray(scores, dtype=float)
        best = np.argmin(scores, axis=1)
        least = scores[np.arange(len(scores)), best]
        clear = least < (1.0 - PRIOR_RATIO) * scores[:, 0] - PRIOR_FLOOR
        return np.where(clear, best, 0)
