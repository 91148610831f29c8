"""The ``general`` feature set of the alpha-potential: any track, any field size N <= N_MAX.

The single-track models (:mod:`agents.features`, the ``fixed`` set) see a fixed number of
cars and one track's curvature. A track-general, field-size-general model needs inputs of one
size for every N and enough of the track around each car to tell tracks apart locally. This
set sorts the cars and pads to :data:`N_MAX` slots with a presence flag per slot:

* :func:`value_features` (ego-centric, for V_i), shape (..., :data:`VALUE_DIM`): the ego's
  state without s (5), its local track (:data:`N_LOCAL`: curvature at ``s + PREVIEW`` [1/m]
  and the half widths left and right at s [m]) and its scaled theta (dim); then N_MAX - 1
  slots of the other cars, nearest ahead first (ahead ascending, then behind descending), each
  as presence (1), progress difference ``s_j - s_i`` [m] on unwrapped s, state without s (5)
  and scaled theta (dim); slots beyond the field are all zero.
* :func:`potential_features` (joint, for Phi), shape (..., :data:`POTENTIAL_DIM`): N_MAX slots
  of the cars sorted by progress, leader first, each as presence (1), progress relative to
  the field's mean [m], state without s (5), local track (N_LOCAL) and scaled theta (dim);
  empty slots are zero.

``dim`` is the number of parameters of the thetas' policy space (5 the paper's, 6 the
extended one; every function takes ``space`` as :mod:`agents.features` does). The module's
``*_DIM`` constants are the paper space's sizes; :func:`dims` gives those of any space.

Ties in the sort keys are broken by the rest of each car's state (and theta), so any
reordering of the cars gives the same features exactly, ties included. A field of N cars
padded to N_MAX is the same input as the same field given as N_MAX cars of which the
padding ones are absent: the model sees the field size only through the presence flags.

Track look-ups go through :class:`TrackSet`, which holds the grid tables of many tracks at
once, so training on races of many tracks computes features in one vectorised call per field
size; racing on one track uses the same code with one track. The numbers are those of
:meth:`racing_env.track.Track.widths` and the curvature table (periodic linear interpolation
on the track's grid).

Bump :data:`FEATURE_VERSION` whenever the output changes; models record it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from racing_env.interp import periodic_interp

from .features import (
    N_STATE,
    N_THETA,
    check_joint,
    others_in_order,
    relative_to_ego,
    scale_theta,
    theta_dim,
    theta_space,
)

if TYPE_CHECKING:
    from racing_env.track import Track

    from .theta import PolicySpace

FEATURE_VERSION = 1
N_MAX = 8  # slots: the env's largest field
PREVIEW = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0])  # curvature look-ahead distances [m]
N_LOCAL = len(PREVIEW) + 2  # preview + half widths (left, right)


def dims(space: str | PolicySpace = "paper") -> dict:
    """The feature sizes for thetas of policy space ``space``: ``ego``, ``other`` (presence,
    s_j - s_i, state, theta), ``slot`` (presence, s - mean s, state, local, theta), ``value``
    and ``potential``."""
    d = theta_dim(space)
    ego, other, slot = N_STATE + N_LOCAL + d, 2 + N_STATE + d, 2 + N_STATE + N_LOCAL + d
    return {
        "ego": ego,
        "other": other,
        "slot": slot,
        "value": ego + (N_MAX - 1) * other,
        "potential": N_MAX * slot,
    }


# the paper space's sizes (N_THETA = 5)
EGO_DIM = N_STATE + N_LOCAL + N_THETA
OTHER_DIM = 2 + N_STATE + N_THETA  # presence, s_j - s_i, state, theta
SLOT_DIM = 2 + N_STATE + N_LOCAL + N_THETA  # presence, s - mean s, state, local, theta
VALUE_DIM = EGO_DIM + (N_MAX - 1) * OTHER_DIM
POTENTIAL_DIM = N_MAX * SLOT_DIM


class TrackSet:
    """Grid tables (curvature, half widths) of ``tracks`` (specs or :class:`Track` objects),
    looked up for any mix of them; ``names`` the tracks' names, ``specs`` what rebuilds them.

    ``lookup(name, s, track_id)`` with ``name`` in ``kappa``, ``w_left``, ``w_right``, ``s``
    unwrapped arc length [m] of any shape and ``track_id`` an integer array broadcastable to
    it: the periodic linear interpolation of that track's table, as
    :meth:`racing_env.track.Track.interp` computes it.
    """

    def __init__(self, tracks):
        from racing_env.tracks import make_track

        self.tracks = [make_track(t) for t in tracks]
        if not self.tracks:
            raise ValueError("a TrackSet needs at least one track")
        self.names = [t.name for t in self.tracks]
        # the specs that rebuild each track: a track's name is not always one ('tumftm:Spa'
        # is named 'Spa', a CSV path by its stem)
        self.specs = [t if isinstance(t, str) else t.name for t in tracks]
        sizes = np.array([len(t.kappa) for t in self.tracks], dtype=np.int64)
        self._size = sizes
        self._offset = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        self._length = np.array([t.length for t in self.tracks], dtype=float)
        self._ds = np.array([t.ds for t in self.tracks], dtype=float)
        self._tables = {
            name: np.concatenate([getattr(t, name) for t in self.tracks])
            for name in ("kappa", "w_left", "w_right")
        }

    def __len__(self) -> int:
        return len(self.tracks)

    def lookup(self, name: str, s: float | np.ndarray, track_id: int | np.ndarray) -> np.ndarray:
        s = np.asarray(s, dtype=float)
        k = np.broadcast_to(np.asarray(track_id, dtype=np.int64), s.shape)
        return periodic_interp(
            self._tables[name],
            s,
            self._length[k],
            self._ds[k],
            size=self._size[k],
            offset=self._offset[k],
        )


_SINGLE: dict = {}


def track_set(track: Track | str) -> TrackSet:
    """A one-track :class:`TrackSet` of ``track`` (a Track or a name), memoised per track."""
    from racing_env.tracks import make_track

    track = make_track(track)
    hit = _SINGLE.get(id(track))
    if hit is None or hit[0] is not track:
        hit = _SINGLE[id(track)] = (track, TrackSet([track]))
    return hit[1]


def _tracks(track, track_id, batch):
    """(TrackSet, track ids broadcast to ``batch``) from a Track/name or a TrackSet and ids."""
    if isinstance(track, TrackSet):
        if track_id is None:
            if len(track) != 1:
                raise ValueError(f"a TrackSet of {len(track)} tracks needs track_id per sample")
            track_id = 0
        ids = np.broadcast_to(np.asarray(track_id, dtype=np.int64), batch)
        if ids.size and (ids.min() < 0 or ids.max() >= len(track)):
            raise ValueError(
                f"track_id must be in 0..{len(track) - 1}, got {int(ids.min())}..{int(ids.max())}"
            )
        return track, ids
    if track_id is not None:
        raise ValueError("track_id goes with a TrackSet, not with a single track")
    return track_set(track), np.zeros(batch, dtype=np.int64)


def local_track(tracks: TrackSet, s: float | np.ndarray, track_id: int | np.ndarray) -> np.ndarray:
    """Curvature at ``s + PREVIEW`` [1/m] and half widths (left, right) at s [m]:
    shape ``s.shape + (N_LOCAL,)``."""
    s = np.asarray(s, dtype=float)
    ids = np.broadcast_to(np.asarray(track_id, dtype=np.int64), s.shape)
    kappa = tracks.lookup("kappa", s[..., None] + PREVIEW, ids[..., None])
    return np.concatenate(
        [
            kappa,
            tracks.lookup("w_left", s, ids)[..., None],
            tracks.lookup("w_right", s, ids)[..., None],
        ],
        axis=-1,
    )


def _sort(primary, states, thetas=None) -> np.ndarray:
    """Indices (..., N) sorting cars by ``primary`` (..., N), ties broken by the rest of the
    state (n, mu, vx, vy, omega) and then theta: the same cars in any input order give the
    same sorted sequence."""
    keys = []
    if thetas is not None:
        keys += [thetas[..., k] for k in range(thetas.shape[-1] - 1, -1, -1)]
    keys += [states[..., k] for k in range(5, 0, -1)]
    keys.append(primary)
    return np.lexsort(keys, axis=-1)


def value_dim(n_cars: int | None = None, space: str | PolicySpace = "paper") -> int:
    """Size of :func:`value_features` for thetas of ``space``, the same for every N <= N_MAX
    (:data:`VALUE_DIM` in the paper's space)."""
    return dims(space)["value"]


def potential_dim(n_cars: int | None = None, space: str | PolicySpace = "paper") -> int:
    """Size of :func:`potential_features` for thetas of ``space``, the same for every
    N <= N_MAX (:data:`POTENTIAL_DIM` in the paper's space)."""
    return dims(space)["potential"]


def potential_theta_slots(n_cars: int, space: str | PolicySpace = "paper") -> np.ndarray:
    """Column indices (N, dim) of the scaled thetas of the first ``n_cars`` slots of
    :func:`potential_features` (the field's cars in progress order)."""
    if not 1 <= n_cars <= N_MAX:
        raise ValueError(f"n_cars must be in 1..{N_MAX}, got {n_cars}")
    d, slot = theta_dim(space), dims(space)["slot"]
    return np.arange(n_cars)[:, None] * slot + (slot - d) + np.arange(d)


def progress_order(states: np.ndarray, thetas: np.ndarray | None = None) -> np.ndarray:
    """Car indices (..., N) sorted by progress, leader first; ties broken by the rest of the
    state (and by theta when given)."""
    states = np.asarray(states, dtype=float)
    return _sort(-states[..., 0], states, thetas)


def value_features(
    states: np.ndarray,
    thetas: np.ndarray,
    track: Track | TrackSet,
    ego: int | np.ndarray,
    track_id: int | np.ndarray | None = None,
    space: str | PolicySpace | None = None,
) -> np.ndarray:
    """Features of car ``ego`` (int or int array broadcast over the batch), (..., VALUE_DIM)
    (the paper's space; ``value_dim(space=...)`` in general).

    ``states`` (..., N, 6) with s unwrapped [m], ``thetas`` (..., N, dim) of one policy space
    (``space``, default: read from the last dimension); ``track`` a Track (or name), or a
    :class:`TrackSet` with ``track_id`` (broadcast over the batch) naming each sample's track.
    """
    states, thetas = check_joint(states, thetas, N_MAX, space)
    other_dim = dims(theta_space(thetas))["other"]
    N = states.shape[-2]
    batch = states.shape[:-2]
    tracks, ids = _tracks(track, track_id, batch)
    ego = np.broadcast_to(np.asarray(ego, dtype=np.int64), batch)
    if ego.size and (ego.min() < 0 or ego.max() >= N):
        raise ValueError(f"ego must be in 0..{N - 1}, got {int(ego.min())}..{int(ego.max())}")
    e_state, e_theta, rel, key = relative_to_ego(states, thetas, ego)
    order = _sort(key, states, thetas)[..., : N - 1]  # the ego (last) dropped
    o_rel, o_state, o_theta = others_in_order(states, thetas, rel, order, space)
    others = np.zeros(batch + (N_MAX - 1, other_dim))
    others[..., : N - 1, :] = np.concatenate(
        [np.ones_like(o_rel), o_rel, o_state, o_theta], axis=-1
    )
    ego_part = np.concatenate(
        [e_state[..., 1:], local_track(tracks, e_state[..., 0], ids), scale_theta(e_theta, space)],
        axis=-1,
    )
    return np.concatenate([ego_part, others.reshape(batch + (-1,))], axis=-1)


def potential_features(
    states: np.ndarray,
    thetas: np.ndarray,
    track: Track | TrackSet,
    order: np.ndarray | None = None,
    track_id: int | np.ndarray | None = None,
    space: str | PolicySpace | None = None,
) -> np.ndarray:
    """Joint features (..., POTENTIAL_DIM) (the paper's space; ``potential_dim(space=...)`` in
    general) with the cars in ``order`` (default :func:`progress_order` of states and thetas)
    in the first N slots; ``track``, ``track_id`` and ``space`` as for :func:`value_features`."""
    states, thetas = check_joint(states, thetas, N_MAX, space)
    slot_dim = dims(theta_space(thetas))["slot"]
    N = states.shape[-2]
    batch = states.shape[:-2]
    tracks, ids = _tracks(track, track_id, batch)
    order = progress_order(states, thetas) if order is None else np.asarray(order)
    st = np.take_along_axis(states, order[..., None], axis=-2)
    th = np.take_along_axis(thetas, order[..., None], axis=-2)
    rel = st[..., 0] - st[..., 0].mean(axis=-1, keepdims=True)
    local = local_track(tracks, st[..., 0], ids[..., None])
    slots = np.zeros(batch + (N_MAX, slot_dim))
    slots[..., :N, :] = np.concatenate(
        [np.ones_like(rel[..., None]), rel[..., None], st[..., 1:], local, scale_theta(th)], axis=-1
    )
    return slots.reshape(batch + (-1,))
