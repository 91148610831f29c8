"""A trained alpha-potential model: value network V and potential network Phi, and the
maximisation of Phi over the joint theta that the alpha agent runs at every step.

``load_model("default")`` loads the model shipped in ``agents/models`` (see its model card,
``agents/models/MODEL_CARD.md``); any path to a ``model.npz`` written by ``alpha-racer train``
works too. A model records its feature set (``fixed``, the paper's single-track models, or
``general``, any track and any field size up to 8 cars; see :func:`agents.feature_sets.feature_set`)
and that set's version; a model of another version is refused. It also records the policy space
its thetas live in (``space``: ``paper``, the paper's five parameters, or ``extended``, with
``b``; :data:`agents.theta.SPACES`) and that space's box; a model without a recorded space
(trained before spaces existed) is the paper's.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .feature_sets import feature_set
from .features import scale_theta, unscale_theta
from .mlp import MLP
from .theta import PolicySpace, policy_space
from .threads import single_blas_thread

if TYPE_CHECKING:
    import os

    from racing_env.track import Track

MODEL_DIR = Path(__file__).parent / "models"
SHIPPED = {
    "default": "alpha_default.npz",
    "gamma0.98": "alpha_gamma098.npz",
    "gamma0.995": "alpha_gamma0995.npz",
    "races400": "alpha_races400.npz",
    "general": "alpha_general.npz",
    "extended": "alpha_extended.npz",
    "extended_gamma0.98": "alpha_extended_gamma098.npz",
    "extended_gamma0.995": "alpha_extended_gamma0995.npz",
    "extended_races400": "alpha_extended_races400.npz",
    "extended_general": "alpha_extended_general.npz",
    "fullsize_monza": "alpha_fullsize_monza.npz",
    "fullsize_monza_gamma0.98": "alpha_fullsize_monza_gamma098.npz",
    "fullsize_monza_gamma0.995": "alpha_fullsize_monza_gamma0995.npz",
    "fullsize_monza_races400": "alpha_fullsize_monza_races400.npz",
    "fullsize_monza_wake": "alpha_fullsize_monza_wake.npz",
}
#: How to make a shipped model that is missing (the general model is trained by the user).
HOW_TO_TRAIN = {
    "general": "collect races over a family of tracks and field sizes and train on them, e.g. "
    "`alpha-racer collect --tracks default oval random:0-299 --cars 2-6 --races 7000 "
    "--out data/family && alpha-racer train --data data/family --out "
    "data/model_general`, then copy data/model_general/model.npz to {path} (the "
    "docs' page on the alpha-potential agent has the full plan and its compute)",
    "extended_general": "collect races of the extended space over a family of tracks and "
    "field sizes and train on them, e.g. `alpha-racer collect --tracks default oval "
    "random:0-299 --cars 2-6 --races 2000 --space extended --start close --pace close --out "
    "data/family_extended && alpha-racer train --data data/family_extended --out "
    "data/model_extended_general`, then copy data/model_extended_general/model.npz to {path} "
    "(the docs' page on the alpha-potential agent has the full plan and its compute)",
}


def model_space(meta: dict) -> PolicySpace:
    """The policy space of a model's thetas from its metadata (a model without a recorded
    ``space``, trained before spaces existed, is the paper's)."""
    return policy_space(meta.get("space", "paper"))


class PotentialModel:
    """V (ego-centric value, one network shared by all cars) and Phi (joint potential).

    ``meta`` holds the training config, the data it saw, gamma, the feature version, the policy
    space (``space``, default ``"paper"``: :attr:`space`) and the theta box the features were
    normalised with (``theta_low``, ``theta_high``) and the validation metrics. A model of
    another feature version, or whose box is not its space's, is refused: its inputs would
    silently mean other thetas. Its thetas (inputs, warm starts, maximisers) are
    ``(..., N, space.dim)``.
    """

    def __init__(self, value: MLP, potential: MLP, meta: dict):
        self.features = feature_set(meta.get("feature_set", "fixed"))
        if meta.get("feature_version") != self.features.version:
            raise ValueError(
                f"model built with feature version {meta.get('feature_version')} "
                f"of the {self.features.name!r} features, this code computes version "
                f"{self.features.version}; retrain it"
            )
        #: the policy space of the model's thetas (a model without one is the paper's)
        self.space: PolicySpace = model_space(meta)
        self.vehicle_class: str = str(meta.get("vehicle_class", "orca"))
        """The vehicle class of the races it was trained on (``"orca"`` when not recorded:
        every model before the full-size class)."""
        ceiling = meta.get("zeta_ceiling")
        self.zeta_ceiling: float | None = None if ceiling is None else float(ceiling)
        """The highest zeta of its races (the class's ceiling, e.g. 1.0 at full size, below
        the box's top), or None: the box's top. Every car's zeta in :meth:`maximise` should
        stay under it (:class:`~agents.alpha_agent.AlphaAgent` does), since the potential
        has seen no race above it."""
        sp = self.space
        box = (meta.get("theta_low"), meta.get("theta_high"))
        if box[0] is None or box[1] is None:
            warnings.warn(
                "model metadata has no theta box (trained before it was recorded); "
                f"assuming this package's box of the {sp.name!r} policy space "
                f"{sp.low.tolist()}..{sp.high.tolist()}",
                stacklevel=2,
            )
        elif not (
            len(box[0]) == len(box[1]) == sp.dim
            and np.allclose(box[0], sp.low)
            and np.allclose(box[1], sp.high)
        ):
            raise ValueError(
                f"model trained on the theta box {box[0]}..{box[1]}, this package's "
                f"box of the {sp.name!r} policy space is {sp.low.tolist()}.."
                f"{sp.high.tolist()}; retrain it"
            )
        self.value_net = value
        self.potential_net = potential
        self.meta = meta
        if self.features.general:
            # any field of 2..max_cars; the range it was trained on, for warnings
            self.n_cars: int | None = None
            lo, hi = meta["n_cars_range"]
            self.trained_cars: tuple[int, int] = (int(lo), int(hi))
        else:
            n = int(meta["n_cars"])
            self.n_cars = n
            self.trained_cars = (n, n)

    @property
    def general(self) -> bool:
        """Whether the model takes any track and any field of 2..8 cars."""
        return self.features.general

    # ------------------------------------------------------------------ io
    def save(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        arrays = {**self.value_net.to_arrays("v_"), **self.potential_net.to_arrays("p_")}
        arrays["meta"] = np.array(json.dumps(self.meta))
        tmp = path.with_suffix(".tmp.npz")
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> PotentialModel:
        with np.load(path) as z:
            meta = json.loads(str(z["meta"]))
            return cls(MLP.from_arrays(z, "v_"), MLP.from_arrays(z, "p_"), meta)

    # ------------------------------------------------------------------ evaluation
    def _check_cars(self, states) -> int:
        n = np.shape(states)[-2]
        if self.general:
            if not 2 <= n <= self.features.max_cars:
                raise ValueError(
                    f"this general model takes 2..{self.features.max_cars} cars, got states of {n}"
                )
        elif n != self.n_cars:
            raise ValueError(f"this model was trained for {self.n_cars} cars, got states of {n}")
        return n

    def value(self, states: np.ndarray, thetas: np.ndarray, track: Track, ego: int) -> np.ndarray:
        """V_ego(x, theta) [m of discounted relative progress], shape of the batch."""
        self._check_cars(states)
        return self.value_net(
            self.features.value_features(states, thetas, track, ego, space=self.space)
        )

    def potential(self, states: np.ndarray, thetas: np.ndarray, track: Track) -> np.ndarray:
        """Phi(x, theta), shape of the batch."""
        self._check_cars(states)
        return self.potential_net(
            self.features.potential_features(states, thetas, track, space=self.space)
        )

    @staticmethod
    def _check_ascent(restarts: int, iterations: int) -> None:
        if restarts < 1 or iterations < 0:
            raise ValueError(
                f"maximise needs restarts >= 1 and iterations >= 0, got {restarts}, {iterations}"
            )

    def _ascent_setup(self, state, track, restarts: int, iterations: int, rng):
        """Shared by the ascents: checks, ``(rng, slots (N, dim), base features (D,))`` where
        ``slots[c]`` are the potential-feature columns of car c's theta (cars sorted by
        progress) and ``base`` the features at theta = 0 (their theta columns get overwritten)."""
        n = self._check_cars(np.asarray(state)[None])
        self._check_ascent(restarts, iterations)
        state = np.asarray(state, dtype=float)
        f = self.features
        order = f.progress_order(state)
        slots = f.potential_theta_slots(n, self.space)[np.argsort(order)]  # row c: car c's columns
        base = f.potential_features(
            state, np.zeros((n, self.space.dim)), track, order, space=self.space
        )
        return rng or np.random.default_rng(0), slots, base

    def restricted_at(self, state: np.ndarray, track: Track) -> MLP:
        """Phi(x, .) at the joint state ``state`` (N, 6) as a network of the joint theta alone,
        scaled to [-1, 1] and car-major (inputs N * dim): the state's features and their share
        of the first layer computed once (:meth:`agents.mlp.MLP.restricted`). What
        :meth:`maximise` ascends and :meth:`best_candidate` ranks with; a decision that does
        both passes it to each (``at``) so that it is built once."""
        _, slots, base = self._ascent_setup(state, track, 1, 0, None)
        with single_blas_thread():
            return self.potential_net.restricted(base, slots.ravel())

    def _scaled_bound(self, name: str, bound, N: int, default: float):
        """Per-car bounds ``bound`` (N, dim) within the box, scaled to [-1, 1] and flattened
        car-major; ``default`` when None; a ValueError naming ``name`` otherwise."""
        if bound is None:
            return default
        sp = self.space
        d = sp.dim
        bound = np.asarray(bound, dtype=float)
        if bound.shape != (N, d) or not (np.all(bound >= sp.low) and np.all(bound <= sp.high)):
            raise ValueError(
                f"{name} must be (N, {d}) = ({N}, {d}) {'upper' if name == 'high' else 'lower'} "
                f"bounds within the theta box of the {sp.name!r} policy space "
                f"{sp.low.tolist()}..{sp.high.tolist()}, got "
                f"{bound.tolist() if bound.size <= 40 else bound.shape}"
            )
        return scale_theta(bound, sp).ravel()

    def maximise(
        self,
        state: np.ndarray,
        track: Track,
        theta0: np.ndarray | None = None,
        restarts: int | None = None,
        iterations: int | None = None,
        rng: np.random.Generator | None = None,
        step: float = 0.5,
        warm_step: float = 0.15,
        decay: float = 0.8,
        high: np.ndarray | None = None,
        low: np.ndarray | None = None,
        at: MLP | None = None,
    ) -> tuple[np.ndarray, float]:
        """Projected gradient ascent (Adam steps) of Phi(x, .) over the joint theta within its
        bounds (the box of the model's policy space, :attr:`space`, of ``dim`` parameters:
        5 in the paper's space, 6 in the extended one); returns ``(theta* (N, dim), Phi*)``,
        the best iterate seen.

        ``high`` (N, dim), optional: per-car upper bounds within the box (e.g. a car's zeta
        ceiling); every start and iterate is projected onto the lowered box. Without it the
        ascent is the same, bit for bit. ``low`` (N, dim), optional: per-car lower bounds the
        same way; a car with ``low = high`` keeps that theta (its row is not maximised over:
        the ego's best reply to thetas the others are taken to race). ``at``: Phi at ``state``
        from :meth:`restricted_at`, when the caller has it already.

        ``state`` (N, 6) joint state; ``theta0`` (N, dim) warm start (e.g. the last step's
        maximiser), else the box centre; the other ``restarts - 1`` starts are uniform random
        draws from ``rng``. All starts ascend together (one matrix product per layer and
        step) on theta scaled to [-1, 1]: ``iterations`` Adam steps (moment decays 0.2 and 0.9:
        little momentum measured best for these short runs), each projected onto the box, of
        length ``warm_step`` for the warm start (usually close to the maximum: short steps
        refine it) and ``step`` for the others (they explore), both shrinking by ``decay`` per
        step. The network's first layer is multiplied with the state's features once per call
        (:meth:`agents.mlp.MLP.restricted`); only the dim N theta columns change during the
        ascent.

        ``restarts`` and ``iterations`` default to 4 and 3 with a warm start (the agent's
        decisions) and to 32 and 12 without one: from the box centre and random starts alone
        the ascent needs many more starts and steps to come close to the maximum.
        Matrix products run on one BLAS thread (:func:`agents.threads.single_blas_thread`):
        the result does not depend on the process's thread count. Versus
        :meth:`maximise_reference` (6 steps) on 200 states of an alpha race with the same warm
        starts: 3 + 1 network passes instead of 6 + 1 and a smaller shortfall from a dense
        search (median, 95th percentile and maximum); ``benchmarks/alpha_speed.py`` measures
        both.
        """
        if restarts is None:
            restarts = 32 if theta0 is None else 4
        if iterations is None:
            iterations = 12 if theta0 is None else 3
        N = np.shape(state)[0]
        sp = self.space
        d = sp.dim
        self._check_ascent(restarts, iterations)
        rng = rng or np.random.default_rng(0)
        phi = self.restricted_at(state, track) if at is None else at
        top = self._scaled_bound("high", high, N, 1.0)
        bottom = self._scaled_bound("low", low, N, -1.0)
        Z = np.empty((restarts, N * d))
        Z[0] = 0.0 if theta0 is None else scale_theta(theta0, sp).ravel()
        for k in range(1, restarts):  # the draws of maximise_reference
            Z[k] = rng.uniform(-1.0, 1.0, (N, d)).ravel()
        if high is not None or low is not None:
            Z = np.clip(Z, bottom, top)
        lr = np.full((restarts, 1), step)
        if theta0 is not None:
            lr[0] = warm_step
        with single_blas_thread():
            best_val, best_z = -np.inf, Z[0]
            m = np.zeros_like(Z)
            v = np.zeros_like(Z)
            for it in range(iterations + 1):
                if it < iterations:
                    val, g = phi.value_and_input_grad(Z)
                else:
                    val = phi(Z)
                k = int(np.argmax(val))
                if val[k] > best_val:
                    best_val, best_z = float(val[k]), Z[k].copy()
                if it == iterations:
                    break
                m = 0.2 * m + 0.8 * g
                v = 0.9 * v + 0.1 * g * g
                m_hat = m / (1.0 - 0.2 ** (it + 1))
                v_hat = v / (1.0 - 0.9 ** (it + 1))
                Z = np.clip(Z + lr * m_hat / (np.sqrt(v_hat) + 1e-12), bottom, top)
                lr *= decay
        return unscale_theta(best_z.reshape(N, d), sp), best_val

    def best_candidate(
        self,
        state: np.ndarray,
        track: Track,
        theta: np.ndarray,
        candidates: np.ndarray,
        at: MLP | None = None,
    ) -> tuple[int, np.ndarray]:
        """The ego's (car 0's) best reply among ``candidates`` by the potential: Phi(x, .) of
        the joint theta ``theta`` (N, dim) with car 0's row replaced by each candidate
        (M, dim), the other cars' thetas held. Returns ``(index of the largest Phi, Phi (M,))``
        (the first of equals). In an alpha-potential game a unilateral change of theta moves
        Phi as it moves the ego's value, up to alpha, so this is the candidate the ego's value
        prefers against the others' ``theta``. ``at``: as for :meth:`maximise`."""
        sp = self.space
        theta = np.asarray(theta, dtype=float)
        candidates = np.asarray(candidates, dtype=float)
        N = np.shape(state)[0]
        if theta.shape != (N, sp.dim) or candidates.ndim != 2 or candidates.shape[1] != sp.dim:
            raise ValueError(
                f"best_candidate takes a joint theta ({N}, {sp.dim}) and candidates (M, "
                f"{sp.dim}) of the {sp.name!r} space, got {theta.shape} and {candidates.shape}"
            )
        net = self.restricted_at(state, track) if at is None else at
        Z = np.repeat(scale_theta(theta, sp)[None], len(candidates), axis=0)
        Z[:, 0] = scale_theta(candidates, sp)
        with single_blas_thread():
            phi = net(Z.reshape(len(Z), -1))
        return int(np.argmax(phi)), np.asarray(phi)

    def maximise_reference(
        self,
        state: np.ndarray,
        track: Track,
        theta0: np.ndarray | None = None,
        restarts: int = 4,
        iterations: int = 8,
        rng: np.random.Generator | None = None,
        step: float = 0.4,
        decay: float = 0.7,
        per_coordinate: bool = False,
    ) -> tuple[np.ndarray, float]:
        """The maximisation of the first release (6 RMS-normalised steps from 4 starts), kept as
        the baseline that ``benchmarks/alpha_speed.py`` compares :meth:`maximise` with.

        Projected gradient ascent of Phi(x, .) over the joint theta within its bounds.

        ``state`` (N, 6) joint state; ``theta0`` (N, dim) warm start (e.g. the last step's
        maximiser); the other ``restarts - 1`` starts are uniform random draws from ``rng``
        (plus the box centre when there is no warm start). Steps are taken on theta scaled
        to [-1, 1], normalised by the gradient's RMS, starting at ``step`` and shrinking by
        ``decay`` per iteration; every iterate is projected onto the box and the best one
        seen is returned as ``(theta* (N, dim), Phi*)``. With ``per_coordinate`` every coordinate
        steps by ``step`` in the direction of its own gradient (sign steps), so parameters of
        small gradient move as far as those of large gradient (slower to settle; used for
        careful offline maximisation).
        """
        N = np.shape(state)[0]
        sp = self.space
        rng, slots, base = self._ascent_setup(state, track, restarts, iterations, rng)
        starts = []
        if theta0 is not None:
            starts.append(scale_theta(theta0, sp))
        else:
            starts.append(np.zeros((N, sp.dim)))
        while len(starts) < restarts:
            starts.append(rng.uniform(-1.0, 1.0, (N, sp.dim)))
        Z = np.stack(starts)  # (B, N, dim) scaled
        X = np.repeat(base[None], len(Z), axis=0)
        best_val, best_z = -np.inf, Z[0]
        lr = step
        for it in range(iterations + 1):
            X[:, slots] = Z
            if it < iterations:
                val, grad = self.potential_net.value_and_input_grad(X)
            else:
                val = self.potential_net(X)
            k = int(np.argmax(val))
            if val[k] > best_val:
                best_val, best_z = float(val[k]), Z[k].copy()
            if it == iterations:
                break
            g = grad[:, slots]  # (B, N, dim)
            if per_coordinate:
                Z = np.clip(Z + lr * np.sign(g), -1.0, 1.0)
            else:
                rms = np.sqrt(np.mean(g**2, axis=(1, 2), keepdims=True)) + 1e-12
                Z = np.clip(Z + lr * g / rms, -1.0, 1.0)
            lr *= decay
        return unscale_theta(best_z, sp), best_val


def cached_model(name_or_path: str | os.PathLike = "default") -> PotentialModel:
    """:func:`load_model`, loaded once per process and name (agents and workers share it;
    treat it as read-only)."""
    key = str(name_or_path)
    if key not in _LOADED:
        _LOADED[key] = load_model(name_or_path)
    return _LOADED[key]


_LOADED: dict = {}


def load_model(name_or_path: str | os.PathLike = "default") -> PotentialModel:
    """A shipped model by name (``default``, ``gamma0.98``, ``gamma0.995``, ``races400``,
    ``general``; ``extended`` and its variants ``extended_gamma0.98``, ``extended_gamma0.995``,
    ``extended_races400`` and the track-general ``extended_general``: the extended policy
    space's) or a path to a ``model.npz``."""
    if str(name_or_path) in SHIPPED:
        path = MODEL_DIR / SHIPPED[str(name_or_path)]
        if not path.exists():
            how = HOW_TO_TRAIN.get(str(name_or_path), "train one with `alpha-racer train`")
            raise FileNotFoundError(
                f"shipped alpha-potential model {name_or_path!r} is missing "
                f"({path}); " + how.format(path=path)
            )
    else:
        path = Path(name_or_path)
        if not path.exists():
            raise FileNotFoundError(
                f"model {str(name_or_path)!r} is neither a shipped "
                f"alpha-potential model ({', '.join(sorted(SHIPPED))}) nor "
                f"the path of a model.npz"
            )
    return PotentialModel.load(path)
