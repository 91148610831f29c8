"""The PPO self-play agent (paper appendix, "Self-play RL training"): a stable-baselines3 PPO
policy trained by ``alpha-racer selfplay`` (:mod:`experiments.learning.selfplay`), driving one car.

Checkpoint format: the zip file of ``PPO.save`` with two more members, which SB3 ignores:

* ``alpha_racer.json``: schema version, the observation layout the policy was trained on
  (``n_cars``, ``n_preview``), the race and self-play configs, which car / turn / cycle it is,
  step counts and the evaluation at save time;
* ``vecnormalize.pkl``: the pickled SB3 ``VecNormalize`` (observation statistics) of the
  training env, which the agent applies before the policy.

The observation is the env's (own Frenet state, every other car relative to it, curvature
preview; see :class:`racing_env.RacingParallelEnv`). A policy trained with ``n_cars`` cars
reads ``n_cars - 1`` other cars. In a race with fewer cars the missing ones are filled in as
*phantoms*: a car half a lap behind at the same speed, lateral offset and heading (it can
neither touch nor be the leader); in a race with more cars the policy sees the ``n_cars - 1``
nearest others (by progress difference), in index order.
"""

from __future__ import annotations

import json
import pickle
import zipfile
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from racing_env.files import atomic_path

from .base import register_agent
from .observations import adapt_observation  # noqa: F401  (also importable from here, as before)

if TYPE_CHECKING:
    import os
    from typing import Any

    from racing_env.track import Track

CHECKPOINT_SCHEMA = 1
META_NAME = "alpha_racer.json"
VECNORM_NAME = "vecnormalize.pkl"
DEFAULT_CHECKPOINT = "ppo_default.zip"
"""The shipped checkpoint, package data in ``agents/models/``."""
CLASS_CHECKPOINTS = {"orca": DEFAULT_CHECKPOINT, "fullsize": "ppo_fullsize_monza.zip"}
"""The shipped checkpoint of each vehicle class (its card: the same name with ``.md``)."""


def default_checkpoint(vehicle_class: str = "orca") -> Path:
    """Path of the checkpoint shipped with the package for ``vehicle_class``
    (``agents/models/ppo_default.zip`` for the ORCA car, ``ppo_fullsize_monza.zip`` at full
    size)."""
    return Path(str(resources.files("agents") / "models" / CLASS_CHECKPOINTS[vehicle_class]))


# ---------------------------------------------------------------------- checkpoint files
def save_checkpoint(model: Any, vec_normalize: Any, path: str | os.PathLike, meta: dict) -> Path:
    """Write ``model`` (SB3 PPO), its ``VecNormalize`` (or None) and ``meta`` to one zip,
    atomically (temporary file in the same folder, then rename). Returns the path.

    ``meta`` must give the observation layout the policy reads, ``{"n_cars": N, "n_preview":
    K}`` (``HeadToHead-v2``'s defaults: 3 and 10), and may hold anything JSON-serialisable
    (the training config, step counts). The file races as ``ppo:checkpoint=PATH``."""
    missing = {"n_cars", "n_preview"} - set(meta)
    if missing:
        raise ValueError(
            f"save_checkpoint meta must give the observation layout; missing "
            f"{sorted(missing)} (e.g. {{'n_cars': 3, 'n_preview': 10}})"
        )
    path = Path(path)
    with atomic_path(path, ".zip") as tmp:
        with open(tmp, "wb") as f:  # a file object: SB3 would append ".zip" to a name
            model.save(f)
        meta = {"schema_version": CHECKPOINT_SCHEMA, "kind": "alpha_racer.ppo", **meta}
        with zipfile.ZipFile(tmp, "a") as z:
            z.writestr(META_NAME, json.dumps(meta, indent=2, default=_jsonable))
            if vec_normalize is not None:
                z.writestr(VECNORM_NAME, pickle.dumps(vec_normalize))
    return path


def _jsonable(o):
    if isinstance(o, (np.integer, np.floating)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


SAVE_HINT = (
    "write one with agents.ppo_agent.save_checkpoint(model, vec_normalize, path, meta), "
    "or race a plain SB3 zip with ppo:checkpoint=PATH,vecnormalize=PATH_OR_none"
)


def is_sb3_zip(path: str | os.PathLike) -> bool:
    """True for a zip written by SB3's ``model.save`` (members ``data`` and ``policy.pth``)."""
    try:
        with zipfile.ZipFile(path) as z:
            return {"data", "policy.pth"} <= set(z.namelist())
    except (zipfile.BadZipFile, OSError):
        return False


def read_checkpoint_meta(path: str | os.PathLike) -> dict:
    """The ``alpha_racer.json`` of a checkpoint; a clear ``ValueError`` if the file is not an
    alpha-racer PPO checkpoint (naming :func:`save_checkpoint`) or has another schema version."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"PPO checkpoint {str(path)!r} does not exist")
    try:
        with zipfile.ZipFile(path) as z:
            meta = json.loads(z.read(META_NAME))
    except KeyError:
        what = "a plain SB3 model zip" if is_sb3_zip(path) else "an alpha-racer PPO checkpoint"
        raise ValueError(f"{str(path)!r} is {what} without {META_NAME}: {SAVE_HINT}") from None
    except (zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise ValueError(
            f"{str(path)!r} is not an alpha-racer PPO checkpoint ({exc}); {SAVE_HINT}"
        ) from None
    if meta.get("schema_version") != CHECKPOINT_SCHEMA:
        raise ValueError(
            f"PPO checkpoint {str(path)!r} has schema version "
            f"{meta.get('schema_version')!r}; this code reads {CHECKPOINT_SCHEMA}"
        )
    return meta


def load_vecnormalize(path: str | os.PathLike) -> Any:
    """The checkpoint's pickled SB3 ``VecNormalize`` (without a venv), or None."""
    with zipfile.ZipFile(path) as z:
        if VECNORM_NAME not in z.namelist():
            return None
        return pickle.loads(z.read(VECNORM_NAME))


def load_ppo(path: str | os.PathLike, env: Any = None, **kwargs) -> Any:
    """``PPO.load`` of a checkpoint on the CPU (schedules replaced by constants, so a model
    saved by another SB3 version loads); ``kwargs`` go to ``PPO.load``."""
    from racing_env.extras import require

    PPO = require("stable_baselines3", "the 'ppo' agent").PPO
    if not is_sb3_zip(path):
        read_checkpoint_meta(path)  # the clear error for what is not a checkpoint
    custom = {"lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    custom.update(kwargs.pop("custom_objects", {}))
    return PPO.load(path, env=env, device="cpu", custom_objects=custom, **kwargs)


# ---------------------------------------------------------------------- the frozen policy
class FrozenPolicy:
    """A fixed SB3 actor-critic policy as an agent: deterministic action (the Gaussian mean,
    clipped to [-1, 1], as ``policy.predict(obs, deterministic=True)``) of the
    ``VecNormalize``-normalised observation.

    For the standard MLP policy the actor runs as numpy matrix products (no torch call; the
    shipped policy measured 28 us per call for 1 observation, 32 us for 8, 58 us for 64), and
    copies and pickles leave the torch policy behind; any other policy runs through
    ``policy.predict``. Implements
    the agent protocol (``reset``, ``act``) and ``act_batch(observations (B, D)) -> (B, 2)``
    for :class:`racing_env.vec_env.HeadToHeadVecEnv`.
    """

    def __init__(
        self,
        policy,
        vec_normalize=None,
        n_cars: int | None = None,
        n_preview: int = 10,
        name: str = "ppo",
    ):
        self.policy = policy
        self.name = name
        self.n_preview = n_preview
        dim = int(np.prod(policy.observation_space.shape))
        self.n_cars = n_cars if n_cars is not None else (dim - n_preview) // 6
        if 6 * self.n_cars + n_preview != dim:
            raise ValueError(
                f"policy observation size {dim} does not fit n_cars = {self.n_cars}, "
                f"n_preview = {n_preview}"
            )
        self.norm = None
        if vec_normalize is not None and getattr(vec_normalize, "norm_obs", False):
            rms = vec_normalize.obs_rms
            self.norm = (
                rms.mean.astype(np.float32),
                (1.0 / np.sqrt(rms.var + vec_normalize.epsilon)).astype(np.float32),
                np.float32(vec_normalize.clip_obs),
            )
        self.layers = _numpy_actor(policy)
        self.track_length: float | None = None
        self.agent_id: str | None = None

    @property
    def obs_dim(self) -> int:
        """Length of the observations the policy reads: ``6 n_cars + n_preview``."""
        return 6 * self.n_cars + self.n_preview

    def __getstate__(self):
        state = self.__dict__.copy()
        if self.layers is not None:
            state["policy"] = None  # the numpy actor suffices: light to copy to workers
        return state

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        from racing_env.tracks import make_track

        self.track_length = make_track(track).length
        self.agent_id = agent_id

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        """VecNormalize's observation normalisation (clipped standard score), float32."""
        x = np.array(obs, dtype=np.float32)
        if self.norm is not None:
            mean, inv_std, clip = self.norm
            x -= mean
            x *= inv_std
            np.minimum(x, clip, out=x)
            np.maximum(x, -clip, out=x)
        return x

    def act_batch(self, observations: np.ndarray) -> np.ndarray:
        """Actions (B, 2) float32 for observations (B, D): in this policy's layout, or of
        another field size once :meth:`reset` gave the track (adapted as :meth:`act` does)."""
        observations = np.asarray(observations)
        if observations.shape[-1] != self.obs_dim:
            if self.track_length is None:
                raise ValueError(
                    f"agent {self.name!r}: observations of {observations.shape[-1]} "
                    f"values, its policy reads {self.obs_dim} ({self.n_cars} cars); "
                    f"call reset(track, ...) first to adapt other field sizes"
                )
            observations = adapt_observation(
                observations, self.n_cars, self.n_preview, self.track_length
            )
        h = self.normalize(observations)
        if self.layers is None:
            a, _ = self.policy.predict(h, deterministic=True)
            return np.clip(a, -1.0, 1.0).astype(np.float32)
        for kind, w, b in self.layers:
            if kind == "linear":
                h = h @ w
                h += b
            elif kind == "tanh":
                np.tanh(h, out=h)
            else:  # relu
                np.maximum(h, 0.0, out=h)
        np.minimum(h, 1.0, out=h)
        np.maximum(h, -1.0, out=h)
        return h

    def act(self, observation: np.ndarray) -> np.ndarray:
        if self.track_length is None:
            raise RuntimeError(f"{self.name}.act() before reset(track, ...)")
        obs = adapt_observation(observation, self.n_cars, self.n_preview, self.track_length)
        return self.act_batch(obs[None])[0]


def _numpy_actor(policy):
    """[(kind, W, b)] of the actor for a flatten-MLP policy with a Gaussian head, else None."""
    import torch.nn as nn
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.torch_layers import FlattenExtractor

    fe = getattr(policy, "pi_features_extractor", policy.features_extractor)
    if not (
        isinstance(fe, FlattenExtractor)
        and isinstance(policy.action_dist, DiagGaussianDistribution)
        and not getattr(policy, "squash_output", False)
    ):
        return None
    layers = []
    for mod in list(policy.mlp_extractor.policy_net) + [policy.action_net]:
        if isinstance(mod, nn.Linear):
            layers.append(
                (
                    "linear",
                    mod.weight.detach().cpu().numpy().T.astype(np.float32).copy(),
                    mod.bias.detach().cpu().numpy().astype(np.float32).copy(),
                )
            )
        elif isinstance(mod, nn.Tanh):
            layers.append(("tanh", None, None))
        elif isinstance(mod, nn.ReLU):
            layers.append(("relu", None, None))
        else:
            return None
    return layers


@register_agent("ppo")
class PPOAgent(FrozenPolicy):
    """PPO self-play policy loaded from a checkpoint (default: the one shipped with the
    package for the track's vehicle class, ``agents/models/ppo_default.zip`` for the ORCA car
    and ``ppo_fullsize_monza.zip`` at full size, chosen at :meth:`reset`; their model cards,
    the same names with ``.md``, say how they were trained). Runs on the CPU; deterministic
    actions.

    ``checkpoint``: path of a checkpoint written by ``alpha-racer selfplay`` (files
    ``checkpoints/*.zip``, ``final/car_K.zip``, ``best.zip`` of its output folder) or by
    :func:`save_checkpoint` (an SB3 ``PPO``, its ``VecNormalize`` and the layout in one zip), or
    a plain SB3 zip of ``model.save`` (for example from a run on ``HeadToHead-v2``): then
    ``vecnormalize`` is required, the path of the file of its ``VecNormalize.save`` or
    ``"none"`` if it was trained without one, and the field size is read from the policy's
    observation size (``n_preview`` curvature values, 10 as the env's default).
    """

    def __init__(
        self,
        checkpoint: str | Path | None = None,
        vecnormalize: str | Path | None = None,
        n_preview: int = 10,
    ):
        path = Path(checkpoint) if checkpoint else default_checkpoint()
        self.checkpoint = path
        self._shipped = not checkpoint  # the class's shipped policy, chosen at reset
        self.vecnormalize = None
        if path.is_file() and is_sb3_zip(path) and not _has_meta(path):
            if vecnormalize is None:
                raise ValueError(
                    f"{str(path)!r} is a plain SB3 zip: give its observation "
                    f"normalisation, ppo:checkpoint={path},vecnormalize=PATH (the file "
                    f"of VecNormalize.save) or vecnormalize=none if it was trained "
                    f"without VecNormalize; or {SAVE_HINT.split(', or')[0]}"
                )
            norm = None
            if str(vecnormalize).lower() != "none":
                self.vecnormalize = Path(vecnormalize)
                norm = _load_vecnormalize_file(self.vecnormalize)
            model = load_ppo(path)
            dim = int(np.prod(model.observation_space.shape))
            n_cars, rest = divmod(dim - int(n_preview), 6)
            if rest or n_cars < 1:
                raise ValueError(
                    f"{str(path)!r}: observation size {dim} is not 6 N + n_preview "
                    f"with n_preview = {n_preview}; pass ppo:...,n_preview=K"
                )
            self.meta: dict = {"kind": "sb3", "n_cars": n_cars, "n_preview": int(n_preview)}
        else:
            if vecnormalize is not None:
                raise ValueError(
                    f"vecnormalize={vecnormalize!r} is for plain SB3 zips; "
                    f"{str(path)!r} carries its own normalisation"
                )
            self.meta = read_checkpoint_meta(path)
            model = load_ppo(path)
            norm = load_vecnormalize(path)
        super().__init__(
            model.policy,
            norm,
            n_cars=int(self.meta["n_cars"]),
            n_preview=int(self.meta["n_preview"]),
        )
        self.policy.set_training_mode(False)

    @property
    def vehicle_class(self) -> str:
        """The vehicle class the policy was trained for: its checkpoint's ``vehicle_class``
        (``"orca"`` when not recorded: every checkpoint before the full-size class)."""
        return str(self.meta.get("vehicle_class", "orca"))

    def reset(self, track: Track | str, agent_id: str = "car_0", seed: int | None = None) -> None:
        """As :meth:`FrozenPolicy.reset`; a track of another vehicle class than the
        checkpoint's is a ``ValueError`` naming both (its observations' scales differ)."""
        from racing_env.tracks import make_track
        from racing_env.vehicles import track_class

        track = make_track(track)
        cls = track_class(track)
        if self._shipped and cls != self.vehicle_class and cls in CLASS_CHECKPOINTS:
            self.__init__(str(default_checkpoint(cls)))  # type: ignore[misc]
            self._shipped = True
        if cls != self.vehicle_class:
            raise ValueError(
                f"PPO checkpoint {str(self.checkpoint)!r} was trained for the "
                f"{self.vehicle_class!r} vehicle class; track {track.name!r} is sized for the "
                f"{cls!r} class. Train a policy on races of the {cls!r} class "
                f"(alpha-racer selfplay --vehicle-class {cls}), or race mpc / ibr / raceline there"
            )
        super().reset(track, agent_id, seed)

    def model_files(self) -> list[Path]:
        """The files this agent loaded (for a run's provenance: their content hashes)."""
        return [self.checkpoint] + ([self.vecnormalize] if self.vecnormalize else [])


def _has_meta(path) -> bool:
    with zipfile.ZipFile(path) as z:
        return META_NAME in z.namelist()


def _load_vecnormalize_file(path: Path):
    """A ``VecNormalize`` from the pickle file of SB3's ``VecNormalize.save``."""
    if not path.is_file():
        raise ValueError(f"vecnormalize file {str(path)!r} does not exist")
    try:
        with open(path, "rb") as fh:
            norm = pickle.load(fh)
    except Exception as exc:
        raise ValueError(
            f"{str(path)!r} is not a VecNormalize.save file ({type(exc).__name__}: {exc})"
        ) from None
    if not hasattr(norm, "obs_rms"):
        raise ValueError(f"{str(path)!r} holds a {type(norm).__name__}, not an SB3 VecNormalize")
    return norm
