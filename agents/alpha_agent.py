"""The alpha-potential agent (paper section 3, online phase).

At every step the agent rebuilds the joint state from its observation, maximises the learned
potential Phi(x_t, .) over the joint theta of all cars within the bounds (projected gradient
ascent warm-started from the last step's maximiser, plus random restarts; see
:meth:`agents.potential.PotentialModel.maximise`), and drives its MPC with its own part
theta*_ego. The joint theta lives in the model's policy space (the paper's five parameters,
or the extended space's six with ``b``, the blend of the lap-time line; see
:data:`agents.theta.SPACES`). ``stats`` reports the maximisation and MPC times, the potential value and the
theta chosen. A decision runs numpy's BLAS on one thread
(:func:`agents.threads.single_blas_thread`, ~10 us): the same race gives the same states
bit for bit whatever the process's thread count.
"""

from __future__ import annotations

import time
import warnings
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .base import median_p99, register_agent
from .best_theta import best_theta
from .mpc_agent import BEST, MPCAgent, split_observation
from .opponent_theta import ThetaEstimator
from .potential import PotentialModel, cached_model
from .reference import Theta, policy_space
from .theta import check_moves, moved_thetas

if TYPE_CHECKING:
    from racing_env.track import Track

AUTO = "auto"
AUTO_MODELS = {"paper": ("default", "general"), "extended": ("extended", None)}
"""The shipped models ``model="auto"`` chooses from, per policy space: ``(single-track,
track-general)`` (names of :data:`agents.potential.SHIPPED`). The extended space's
track-general model, ``extended_general``, ships but is not raced by ``auto``: on held-out
tracks and on the strategy benchmark it races worse than the single-track ``extended`` model
and the fixed theta at the limit (docs: the alpha-potential page); ``model=extended_general``
races it."""


#: How alpha takes the others' thetas: maximised over with its own (the paper's), held at
#: the track's best fixed theta, or held at their estimates from their observed play
#: (:class:`agents.opponent_theta.ThetaEstimator`).
OTHERS = ("maximise", "best", "estimate")

#: The shipped model of a vehicle class other than the paper's (named when ``alpha`` is
#: asked to race a model of another class there).
CLASS_MODELS = {"fullsize": "fullsize_monza"}


def auto_model(track_name: str, n_cars: int, space: str = "paper") -> str:
    """The shipped model that ``model="auto"`` races with in policy space ``space``
    (:data:`AUTO_MODELS`): the space's single-track model on the track and field size it was
    trained for (``default`` and ``extended``: track ``default``, 3 cars), where
    specialisation is possible; the space's track-general model everywhere else (the
    single-track model again if the space has none or it is not installed, which then
    refuses another field size and warns on another track)."""
    from .potential import MODEL_DIR, SHIPPED

    single_name, general = AUTO_MODELS[policy_space(space).name]
    single = cached_model(single_name)
    if track_name == single.meta.get("track") and n_cars == single.n_cars:
        return single_name
    if general is not None and (MODEL_DIR / SHIPPED[general]).exists():
        return general
    return single_name


def _agent_index(agent_id: str) -> int:
    """The place of ``agent_id`` (``"car_<i>"``) in the field's agent order; 0 for another
    name."""
    head, _, tail = agent_id.rpartition("_")
    return int(tail) if head and tail.isdigit() else 0


def _spec_names(spec: str) -> set[str]:
    """The names a track built from the spec ``spec`` may have: the spec itself (``default``,
    ``random:3``), a TUMFTM circuit's name (``tumftm:Monza``: ``Monza``), a CSV file's stem."""
    return {spec, spec.removeprefix("tumftm:"), Path(spec).stem}


@register_agent("alpha")
class AlphaAgent(MPCAgent):
    """MPC whose theta is chosen by maximising the alpha-potential at every step.

    Parameters: ``model`` (``"auto"``, the default: see :func:`auto_model`; a shipped model
    name, see :func:`agents.potential.load_model`; a path to a ``model.npz``; or a
    :class:`PotentialModel`), ``restarts`` (starts of the gradient
    ascent, the first being the warm start; 4), ``iterations`` (gradient steps per start; 3),
    ``cold_restarts`` and ``cold_iterations`` (the same for the first decision of a race, which
    has no warm start; 32 and 12), and the :class:`MPCAgent` keywords (``config``,
    ``vehicle``, ``n_preview``, ``line``). A single-track model must have been trained for the race's
    number of cars (and warns on another track); a general model (``model="general"``, see
    :mod:`agents.general_features`) races any field of 2..8 cars on any track, and warns when
    the field size is outside the range it was trained on. With ``zeta_max`` (an
    :class:`MPCAgent` keyword) the maximisation runs in the box with the agent's own zeta
    capped there (the others' thetas keep the full box): the best theta the potential finds
    under the ceiling, not the unconstrained one clipped afterwards.

    ``anchor="best"`` (default ``None``: the paper's agent) restricts the ego's own theta to a
    few candidates: the track's best fixed theta of ``anchor_space`` (the agent's space by
    default; the extended space's for a wake model racing the extended control, its thetas
    taken into the wake space with ``h = p = c = 0``) and its first ``moves`` one-parameter
    moves (:data:`agents.theta.MOVES`, 4 by default: the rollout oracle's candidates of
    ``alpha-racer room``). Every decision still maximises Phi over the joint theta (the
    others' part is the agent's model of their play), then drives the candidate of largest
    Phi against the others' maximising thetas (:meth:`PotentialModel.best_candidate`): the
    potential's choice where the oracle chooses by rollouts. Each candidate's zeta is capped
    at ``zeta_max`` and the model's ceiling, as the MPC drives it.

    ``others="best"`` (default ``"maximise"``: the paper's joint maximisation) holds the other
    cars' thetas at the track's best fixed theta of ``anchor_space`` (the published control,
    :mod:`agents.best_theta`) and maximises over the ego's alone: the potential's best reply
    to opponents taken to race that theta (a level-1 reasoner, not the paper's agent). With
    an anchor it is the candidates' ranking that is made against them. ``others="estimate"``
    holds each other car at the type that best predicts its play so far, among the best fixed
    theta of ``anchor_space`` and its first ``moves`` moves
    (:class:`agents.opponent_theta.ThetaEstimator`: one MPC copy per opponent and type, scored
    on its one-period predictions; the best fixed theta until the evidence parts them): the
    others' thetas are no longer assumed but read from how they race.

    ``space``: the policy space maximised over and driven in (``"paper"`` or ``"extended"``,
    :data:`agents.theta.SPACES`); by default the model's (:attr:`PotentialModel.space
    <agents.potential.PotentialModel.space>`), the paper's with ``model="auto"``. A model of
    another space than the one asked for is a ``ValueError`` naming both. With
    ``model="auto"`` the space picks the shipped models (:data:`AUTO_MODELS`):
    ``space="extended"`` races the shipped ``extended`` model (trained on
    ``alpha-racer collect --space extended --start close --pace close`` races on ``default``,
    3 cars; agents/models/MODEL_CARD.md), maximising over the six-dimensional box (``b`` in
    [0, 1]) with its MPC built for the extended space; ``model=PATH`` races another model
    of that space.
    """

    param_notes = {
        **MPCAgent.param_notes,
        "space": "policy space maximised over: 'paper' or 'extended'; default: the model's",
        "anchor": "'best': choose the ego's theta among the track's best fixed theta and its "
        "moves by the potential (default: over the whole box)",
        "anchor_space": "policy space of the anchor's best fixed theta (default: the agent's)",
        "moves": "one-parameter moves of the anchor among the candidates (0..8, default 4)",
        "others": "the others' thetas: 'maximise' (with the ego's, default), 'best' (held at "
        "the track's best fixed theta) or 'estimate' (held at the type among the best theta and "
        "its moves that predicts their play best)",
    }

    def __init__(
        self,
        model=AUTO,
        restarts: int = 4,
        iterations: int = 3,
        cold_restarts: int = 32,
        cold_iterations: int = 12,
        space: str | None = None,
        anchor: str | None = None,
        anchor_space: str | None = None,
        moves: int = 4,
        others: str = "maximise",
        **mpc_kwargs,
    ):
        if mpc_kwargs.get("theta") is not None:
            raise ValueError(
                f"alpha chooses its theta online by maximising the potential; "
                f"theta={mpc_kwargs['theta']!r} is for the mpc agent"
            )
        self.model_name = model
        self.auto = isinstance(model, str) and model == AUTO
        self.model: PotentialModel | None = None  # model="auto": chosen at a race's first decision
        if not self.auto:
            self.model = model if isinstance(model, PotentialModel) else cached_model(model)
        if space is None:  # the model's (the shipped ones: the paper's)
            space = "paper" if self.auto else self._model().space.name
        space = policy_space(space).name  # names the choices if unknown
        if self.auto and space not in AUTO_MODELS:
            raise ValueError(
                f"model='auto' races the shipped models of the "
                f"{', '.join(map(repr, AUTO_MODELS))} policy spaces; space={space!r} "
                f"needs model=<the model.npz of a model trained on races of the "
                f"{space!r} space>"
            )
        if not self.auto:
            self._check_space(space)
        super().__init__(space=space, **mpc_kwargs)
        for name, v in (("restarts", restarts), ("cold_restarts", cold_restarts)):
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        for name, v in (("iterations", iterations), ("cold_iterations", cold_iterations)):
            if not (isinstance(v, int) and v >= 0):
                raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
        self.restarts, self.iterations = restarts, iterations
        self.cold_restarts, self.cold_iterations = cold_restarts, cold_iterations
        self._theta_joint: np.ndarray | None = None
        self._max_ms: deque = deque(maxlen=100_000)
        self._estimate_ms: deque = deque(maxlen=100_000)
        self._type_counts: np.ndarray | None = None  # others="estimate": (K,) per type
        self._type_arrays: np.ndarray | None = None  # others="estimate": (K, dim) the types
        if anchor not in (None, BEST):
            raise ValueError(f"anchor must be {BEST!r} or left out, got {anchor!r}")
        self.anchor = anchor
        self.anchor_space = policy_space(anchor_space or space).name
        if policy_space(self.anchor_space).dim > policy_space(space).dim:
            raise ValueError(
                f"anchor_space={self.anchor_space!r} has more parameters than the agent's "
                f"space {space!r}: its best theta cannot be driven there"
            )
        self.moves = check_moves(moves)
        if others not in OTHERS:
            raise ValueError(f"others must be one of {OTHERS}, got {others!r}")
        self.others = others
        self._reads_best = anchor is not None or others != "maximise"  # the best-theta table
        self.estimator: ThetaEstimator | None = None  # others="estimate": built at reset
        self._candidates: np.ndarray | None = None  # (M, dim) with an anchor, after reset
        self._best_others: np.ndarray | None = None  # (dim,) with others="best", after reset
        self.choices: list[int] = []  # the candidate driven at each decision (anchor only)

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        from racing_env.tracks import make_track

        track = make_track(track)
        self._check_class(track)  # before the MPC is built for it
        super().reset(track, agent_id, seed)
        if self.auto:
            self.model = None
        else:
            self._check_track()
        self._rng = np.random.default_rng(seed)
        self._theta_joint = None
        self.last_potential = float("nan")
        self.choices = []
        if self._reads_best:
            base = best_theta(track, space=self.anchor_space)
            self._best_others = base.as_array(self.space)
        if self.others == "estimate":
            types = moved_thetas(base, self.moves)
            if self.estimator is None or self.estimator.types != types:
                self.estimator = ThetaEstimator(types, self.anchor_space, self.n_preview)
            self.estimator.reset(track, ego_index=_agent_index(agent_id))
            self._type_arrays = np.array([t.as_array(self.space) for t in types])
            self._type_counts = np.zeros(len(types), dtype=int)
        if self.anchor is not None:
            self._candidates = np.array(
                [t.as_array(self.space) for t in moved_thetas(base, self.moves)]
            )

    def check_track(self, track: Track) -> None:
        """Also the best theta that ``anchor="best"`` or ``others="best"`` reads: a track
        without one fails before its races."""
        super().check_track(track)
        if self._reads_best:
            best_theta(track, space=self.anchor_space)

    def _model(self) -> PotentialModel:
        """The potential model (with model="auto", once a race's first decision chose it)."""
        if self.model is None:
            raise RuntimeError("alpha's model='auto' is chosen at a race's first decision")
        return self.model

    def _check_space(self, space: str) -> None:
        """Refuse a model of another policy space than ``space`` (naming both)."""
        have = self._model().space.name
        if have != space:
            name = self.model_name if isinstance(self.model_name, str) else "given"
            raise ValueError(
                f"alpha-potential model {name!r} was trained on the {have!r} "
                f"policy space ({self._model().space.dim} parameters), space={space!r} "
                f"was asked for; train a model on races of the {space!r} space "
                f"(alpha-racer collect --space {space}) or drop space (alpha then "
                f"takes its model's)"
            )

    def _check_class(self, track: Track) -> None:
        """Refuse a track of another vehicle class than the model's (``ValueError`` naming the
        model, its class and the track's): a potential learnt from races of one class knows
        nothing of another's (DESIGN section 7). ``model="auto"`` races the paper's shipped
        models, trained for the ``"orca"`` class; a shipped model of the track's class is
        named in the message (``fullsize_monza`` at full size)."""
        from racing_env.vehicles import track_class

        cls = track_class(track)
        if self.auto:
            have, name = "orca", f"{AUTO!r} (the shipped models)"
        else:
            have = self._model().vehicle_class
            name = repr(self.model_name if isinstance(self.model_name, str) else "given")
        if have != cls:
            shipped = CLASS_MODELS.get(cls)
            hint = f"race alpha:model={shipped}, " if shipped else ""
            raise ValueError(
                f"alpha-potential model {name} was trained for the {have!r} vehicle class; "
                f"track {track.name!r} is sized for the {cls!r} class. {hint.capitalize()}"
                f"{'t' if hint else 'T'}rain a model on races of the {cls!r} class, or race "
                f"mpc / ibr / raceline there"
            )

    def _check_track(self) -> None:
        model, track = self._model(), self.track
        assert track is not None  # after reset()
        trained_on = model.meta.get("track")  # a spec: tumftm:Monza builds a track 'Monza'
        if not model.general and trained_on and track.name not in _spec_names(trained_on):
            warnings.warn(
                f"alpha-potential model trained on track {trained_on!r}, racing on {track.name!r}",
                stacklevel=3,
            )

    def _check_field(self, n: int) -> None:
        """Refuse a field a single-track model was not trained for; warn when a general
        model races a field size outside its training range."""
        m = self._model()
        if not m.general:
            if n != m.n_cars:
                raise ValueError(
                    f"alpha-potential model trained for {m.n_cars} cars, the race has {n}"
                )
            return
        lo, hi = m.trained_cars
        max_cars = m.features.max_cars
        assert max_cars is not None  # general features bound the field
        if not 2 <= n <= max_cars:
            raise ValueError(
                f"the general alpha-potential model takes 2..{max_cars} cars, the race has {n}"
            )
        if not lo <= n <= hi:
            warnings.warn(
                f"general alpha-potential model trained on fields of {lo}..{hi} cars, racing {n}",
                stacklevel=3,
            )

    @property
    def stats(self) -> dict:
        st = super().stats
        med, p99 = median_p99(self._max_ms)
        st.update(
            {
                "maximise_ms_median": med,
                "maximise_ms_p99": p99,
                "potential": self.last_potential,
                "theta": dict(
                    zip(policy_space(self.space).names, map(float, self.theta.as_array(self.space)))
                ),
            }
        )
        if self._candidates is not None:  # share of the decisions that drove each candidate
            counts = np.bincount(self.choices, minlength=len(self._candidates))
            st["candidate_share"] = (counts / max(1, len(self.choices))).round(4).tolist()
        if self._type_counts is not None and self._type_counts.any():  # per estimated type
            med, p99 = median_p99(self._estimate_ms)
            st["estimate_ms_median"], st["estimate_ms_p99"] = med, p99
            st["type_share"] = (self._type_counts / self._type_counts.sum()).round(4).tolist()
        return st

    def _before_solve(self, observation: np.ndarray) -> None:
        """Choose this step's theta: the joint theta that maximises the potential at the
        observed joint state (warm-started from the last one), the ego's row driven."""
        t0 = time.perf_counter()
        ego, others = split_observation(observation, self.n_preview)
        joint = np.vstack([ego[None], others])  # ego first, then the others
        cold = self._theta_joint is None
        track = self.track
        assert track is not None  # act() checked reset()
        if cold:
            if self.model is None:  # model="auto"
                self.model = cached_model(auto_model(track.name, len(joint), self.space))
                self._check_space(self.space)
                self._check_track()
            self._check_field(len(joint))
        model = self._model()
        box = model.space
        high = None
        if self.zeta_max is not None or model.zeta_ceiling is not None:
            high = np.tile(box.high, (len(joint), 1))
            if model.zeta_ceiling is not None:  # no car above the model's races
                high[:, 1] = np.minimum(high[:, 1], model.zeta_ceiling)
            if self.zeta_max is not None:  # the ego's zeta ceiling
                high[0, 1] = min(high[0, 1], self.zeta_max)
        low = held = None
        if self.others != "maximise":  # the others' rows pinned: low = high = their theta
            high = np.tile(box.high, (len(joint), 1)) if high is None else high
            if self.estimator is not None:  # each opponent's type, from its play so far
                t1 = time.perf_counter()
                index = self.estimator.update(ego, others)
                spent = time.perf_counter() - t1
                t0 += spent  # the maximisation's time is reported without the estimate's
                self._estimate_ms.append(1e3 * spent)
                assert self._type_arrays is not None and self._type_counts is not None
                self._type_counts += np.bincount(index, minlength=len(self._type_counts))
                theirs = self._type_arrays[index]  # (N-1, dim)
            else:
                assert self._best_others is not None  # reset() set it
                theirs = self._best_others  # (dim,), every other car's
            held = np.minimum(theirs, high[1:])
            low = np.tile(box.low, (len(joint), 1))
            low[1:] = high[1:] = held
        at = model.restricted_at(joint, track)  # Phi at this state: built once per decision
        if self._candidates is not None and held is not None:
            # the others are held and the ego picks among candidates: nothing to maximise
            theta, phi = np.vstack([self._candidates[:1], held]), float("nan")
        else:
            theta, phi = model.maximise(
                joint,
                track,
                self._theta_joint,
                rng=self._rng,
                restarts=self.cold_restarts if cold else self.restarts,
                iterations=self.cold_iterations if cold else self.iterations,
                high=high,
                low=low,
                at=at,
            )
            if held is not None:  # exactly, not through the ascent's scaling
                theta[1:] = held
        self._theta_joint = theta
        self.theta = Theta.from_array(np.clip(theta[0], box.low, box.high))
        self.last_potential = phi
        if self._candidates is not None:
            candidates = self._candidates.copy()
            if high is not None:  # the zeta the MPC drives
                candidates[:, 1] = np.minimum(candidates[:, 1], high[0, 1])
            k, phis = model.best_candidate(joint, track, theta, candidates, at=at)
            self.theta = Theta.from_array(candidates[k])
            self.last_potential = float(phis[k])
            self.choices.append(k)
        self._max_ms.append(1e3 * (time.perf_counter() - t0))
