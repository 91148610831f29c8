"""The one feature function of the alpha-potential: joint state and thetas -> network inputs.

Training (``experiments/potential/train.py``) and racing (``agents/alpha_agent.py``) both call these
functions, so the inputs a network sees online are built by the same code as those it was
trained on (the authors' code used different lookaheads in training and at test time).
Bump :data:`FEATURE_VERSION` whenever the output changes; checkpoints record it and loading a
checkpoint of another version is an error.

Inputs: ``states`` (..., N, 6) joint Frenet states ``(s, n, mu, vx, vy, omega)`` with s
unwrapped [m], ``thetas`` (..., N, dim) policy parameters of one policy space
(:data:`agents.theta.SPACES`): ``(q, zeta, s1, s2, s3)`` (dim 5, the paper's) or
``(q, zeta, s1, s2, s3, b)`` (dim 6, the extended space). Every function takes ``space`` (a
name or :class:`agents.theta.PolicySpace`); ``None`` (the default) reads it from the thetas'
last dimension, a given space must match it. The layout is the same in both spaces, each
theta block ``dim`` wide; the paper's features are those of the first release, bit for bit.

* :func:`value_features` (ego-centric, for V_i): the ego's own state without s, the track's
  curvature ahead of it, its theta; then every other car, sorted by progress relative to the
  ego (the nearest ahead first), as progress difference ``s_j - s_i`` [m] (unwrapped), its
  state and its theta. Swapping the other cars' indices does not change the features.
* :func:`potential_features` (joint, for Phi): the cars sorted by progress (leader first),
  each as progress relative to the pack's mean, its state, the curvature ahead and its theta.
  Any reordering of the cars gives the same features, so Phi is symmetric by construction.

Thetas enter scaled to [-1, 1] by their space's bounds (:func:`scale_theta`), so the gradient of a
network with respect to its theta slots is the gradient with respect to the scaled theta.

Vehicle classes: the features are in the race's own units (metres, m/s, rad, 1/m), and the
networks standardise every input by the mean and spread of their training features
(:func:`experiments.potential.nets.input_scale`), so a model of the full-size class, trained on
full-size races, needs no other scale. The one length the features choose, the curvature
look-ahead :data:`PREVIEW` (0 to 2 m: 0 to 17 lengths of the 1:43 car), is in lengths of the
1:43 car and scales with the track's class (:func:`preview_distances`: times the car's length
ratio, 39.2 at full size, so 0 to 78 m); on a 1:43 track it is :data:`PREVIEW` itself, so the
features there are those of the first release, bit for bit. Theta needs no scaling: the box
is the same in every class (:func:`agents.theta.theta_length_scales`).

These are the ``fixed`` feature set (one track, a fixed number of cars: the paper's models).
The ``general`` set (:mod:`agents.general_features`: any track, any N up to 8, sorted and
padded) is a second feature set; a model records its set's name and version in its metadata and
:func:`agents.feature_sets.feature_set` gives the functions it was trained with.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from .theta import SPACES, PolicySpace, policy_space, space_of_dim

if TYPE_CHECKING:
    from collections.abc import Sequence

    from racing_env.track import Track

FEATURE_VERSION = 1
PREVIEW = np.array([0.0, 0.5, 1.0, 2.0])  # curvature look-ahead distances [m] at 1:43
N_STATE = 5  # n, mu, vx, vy, omega
N_THETA = 5  # the paper's space; theta_dim(space) in general


def theta_dim(space: str | PolicySpace = "paper") -> int:
    """Number of parameters of a theta of policy space ``space`` (5 paper, 6 extended)."""
    return policy_space(space).dim


def theta_space(
    thetas: np.ndarray | Sequence[float], space: str | PolicySpace | None = None
) -> PolicySpace:
    """The policy space of ``thetas`` (..., dim): ``space`` when given (``ValueError`` naming
    both when the thetas' last dimension is not its dim), else the space of that dimension
    (:func:`agents.theta.space_of_dim`)."""
    dim = np.shape(thetas)[-1] if np.ndim(thetas) else None
    if space is not None:
        sp = policy_space(space)
        if dim != sp.dim:
            raise ValueError(
                f"thetas of the {sp.name!r} policy space have {sp.dim} parameters "
                f"{sp.names}, got thetas of shape {np.shape(thetas)}"
            )
        return sp
    found = space_of_dim(dim)
    if found is not None:
        return found
    raise ValueError(
        f"thetas must have {_either([str(sp.dim) for sp in SPACES.values()])} "
        f"parameters in the last dimension ("
        f"{', '.join(f'{sp.name!r}: {sp.names}' for sp in SPACES.values())}), got "
        f"shape {np.shape(thetas)}"
    )


def _either(items: list[str]) -> str:
    """``"a, b or c"``."""
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} or {items[-1]}"


def scale_theta(
    theta: np.ndarray | Sequence[float], space: str | PolicySpace | None = None
) -> np.ndarray:
    """Theta (..., dim) -> [-1, 1] (..., dim) by the bounds of its policy space (``space``, or
    the space of the last dimension: 5 the paper's, 6 the extended one)."""
    sp = theta_space(theta, space)
    return 2.0 * (np.asarray(theta, dtype=float) - sp.low) / (sp.high - sp.low) - 1.0


def unscale_theta(
    z: np.ndarray | Sequence[float], space: str | PolicySpace | None = None
) -> np.ndarray:
    """Inverse of :func:`scale_theta`."""
    sp = theta_space(z, space)
    return sp.low + 0.5 * (np.asarray(z, dtype=float) + 1.0) * (sp.high - sp.low)


@functools.cache
def _preview_of_class(vehicle_class: str) -> np.ndarray:
    from racing_env.scaling import size_ratios

    if vehicle_class == "orca":
        return PREVIEW
    ahead = PREVIEW * size_ratios(vehicle_class)[0]
    ahead.setflags(write=False)
    return ahead


def preview_distances(track: Track) -> np.ndarray:
    """The curvature look-ahead distances [m] on ``track``: :data:`PREVIEW` (lengths of the
    1:43 car) times the length ratio of the track's class's car to it
    (:func:`racing_env.scaling.size_ratios`); :data:`PREVIEW` itself on a 1:43 track."""
    from racing_env.vehicles import track_class

    return _preview_of_class(track_class(track))


def curvature_preview(track: Track, s: float | np.ndarray) -> np.ndarray:
    """Track curvature [1/m] at ``s`` plus the look-ahead distances of the track's class
    (:func:`preview_distances`; :data:`PREVIEW` on a 1:43 track): shape
    ``s.shape + (len(PREVIEW),)``."""
    ahead = np.asarray(s, dtype=float)[..., None] + preview_distances(track)
    return track.interp(track.kappa, ahead)


def check_joint(
    states: np.ndarray,
    thetas: np.ndarray,
    max_cars: int | None = None,
    space: str | PolicySpace | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``states`` (..., N, 6) and ``thetas`` (..., N, dim) as float arrays, checked: matching
    shapes, thetas of a policy space (``space`` when given, see :func:`theta_space`) and
    2 <= N (<= ``max_cars`` when given)."""
    states = np.asarray(states, dtype=float)
    thetas = np.asarray(thetas, dtype=float)
    if states.ndim < 2 or states.shape[-1] != 6:
        raise ValueError(f"states must have shape (..., N, 6), got {states.shape}")
    dim = theta_space(thetas, space).dim
    if thetas.shape != states.shape[:-1] + (dim,):
        raise ValueError(
            f"thetas must have shape {states.shape[:-1] + (dim,)} to match states "
            f"{states.shape}, got {thetas.shape}"
        )
    n = states.shape[-2]
    if max_cars is not None and not 2 <= n <= max_cars:
        raise ValueError(f"these features take 2..{max_cars} cars, got {n}")
    if n < 2:
        raise ValueError(f"the alpha-potential needs at least 2 cars, got {n}")
    return states, thetas


def value_dim(n_cars: int, space: str | PolicySpace = "paper") -> int:
    """Size of :func:`value_features` for ``n_cars`` cars and thetas of ``space``."""
    d = theta_dim(space)
    return N_STATE + len(PREVIEW) + d + (n_cars - 1) * (1 + N_STATE + d)


def potential_dim(n_cars: int, space: str | PolicySpace = "paper") -> int:
    """Size of :func:`potential_features` for ``n_cars`` cars and thetas of ``space``."""
    return n_cars * (1 + N_STATE + len(PREVIEW) + theta_dim(space))


def potential_theta_slots(n_cars: int, space: str | PolicySpace = "paper") -> np.ndarray:
    """Column indices of the scaled thetas in :func:`potential_features`, (N, dim) in the
    features' (progress-sorted) car order."""
    d = theta_dim(space)
    per = 1 + N_STATE + len(PREVIEW) + d
    return np.arange(n_cars)[:, None] * per + (per - d) + np.arange(d)


def relative_to_ego(
    states: np.ndarray, thetas: np.ndarray, ego: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The field as car ``ego`` sees it, the start of both feature sets' value features.

    Parameters
    ----------
    states : np.ndarray
        Joint states (..., N, 6), s unwrapped [m].
    thetas : np.ndarray
        Joint thetas (..., N, dim) of one policy space (5 the paper's, 6 the extended one).
    ego : np.ndarray
        The ego's index (...), int64, broadcast to the batch shape.

    Returns
    -------
    ego_state, ego_theta : np.ndarray
        The ego's state (..., 6) and theta (..., dim), unscaled.
    rel : np.ndarray
        Every car's progress relative to the ego's, ``s_j - s_i`` (..., N) [m].
    key : np.ndarray
        Sort key (..., N) of the others, nearest ahead first: the cars ahead (``rel > 0``)
        ascending, then those behind descending; the ego itself last (``inf``).
    """
    e_state = np.take_along_axis(states, ego[..., None, None], axis=-2)[..., 0, :]
    e_theta = np.take_along_axis(thetas, ego[..., None, None], axis=-2)[..., 0, :]
    rel = states[..., 0] - e_state[..., None, 0]
    is_ego = np.arange(states.shape[-2]) == ego[..., None]
    key = np.where(rel > 0, rel, 1e6 - rel)
    key = np.where(is_ego, np.inf, key)
    return e_state, e_theta, rel, key


def others_in_order(
    states: np.ndarray,
    thetas: np.ndarray,
    rel: np.ndarray,
    order: np.ndarray,
    space: str | PolicySpace | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The other cars, in ``order`` (..., M) (indices of cars), as the value features hold them:
    progress relative to the ego (..., M, 1) [m] (from ``rel`` of :func:`relative_to_ego`),
    state without s (..., M, 5) and theta (..., M, dim) scaled by the box of its policy space
    (``space``, or the space of the thetas' last dimension; see :func:`scale_theta`)."""
    o_rel = np.take_along_axis(rel, order, axis=-1)[..., None]
    o_state = np.take_along_axis(states, order[..., None], axis=-2)[..., 1:]
    o_theta = scale_theta(np.take_along_axis(thetas, order[..., None], axis=-2), space)
    return o_rel, o_state, o_theta


def value_features(
    states: np.ndarray,
    thetas: np.ndarray,
    track: Track,
    ego: int | np.ndarray,
    space: str | PolicySpace | None = None,
) -> np.ndarray:
    """Features of car ``ego`` (int or int array broadcast over the batch): (..., value_dim)."""
    states, thetas = check_joint(states, thetas, space=space)
    N = states.shape[-2]
    batch = states.shape[:-2]
    ego = np.broadcast_to(np.asarray(ego, dtype=np.int64), batch)
    e_state, e_theta, rel, key = relative_to_ego(states, thetas, ego)
    order = np.argsort(key, axis=-1, kind="stable")[..., : N - 1]  # the ego (last) dropped
    o_rel, o_state, o_theta = others_in_order(states, thetas, rel, order, space)
    others = np.concatenate([o_rel, o_state, o_theta], axis=-1).reshape(batch + (-1,))
    return np.concatenate(
        [
            e_state[..., 1:],
            curvature_preview(track, e_state[..., 0]),
            scale_theta(e_theta, space),
            others,
        ],
        axis=-1,
    )


def progress_order(states: np.ndarray) -> np.ndarray:
    """Car indices sorted by progress, leader first (..., N)."""
    return np.argsort(-np.asarray(states)[..., 0], axis=-1, kind="stable")


def potential_features(
    states: np.ndarray,
    thetas: np.ndarray,
    track: Track,
    order: np.ndarray | None = None,
    space: str | PolicySpace | None = None,
) -> np.ndarray:
    """Joint features (..., potential_dim) with cars in ``order`` (default progress order)."""
    states, thetas = check_joint(states, thetas, space=space)
    batch = states.shape[:-2]
    order = progress_order(states) if order is None else order
    st = np.take_along_axis(states, order[..., None], axis=-2)
    th = np.take_along_axis(thetas, order[..., None], axis=-2)
    rel = st[..., 0] - st[..., 0].mean(axis=-1, keepdims=True)
    per_car = np.concatenate(
        [rel[..., None], st[..., 1:], curvature_preview(track, st[..., 0]), scale_theta(th)],
        axis=-1,
    )
    return per_car.reshape(batch + (-1,))
