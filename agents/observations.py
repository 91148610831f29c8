"""Observations of one field size read by an agent made for another, and the field sizes an
agent declares.

An agent may declare ``field_sizes``: the numbers of cars (whole field, itself included) it
can race in, as any container of ints (``range(2, 9)``, ``{3}``); without the attribute it is
taken to race in any field. Races check the declaration before the start
(:func:`check_field_size`), so a policy made for 3 cars fails in a 2-car race with a message
naming it and its car, not with ``operands could not be broadcast together``. An agent that
reads a fixed layout can instead accept any field by :func:`adapt_observation`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from racing_env.agent_protocol import act_named, agent_label  # noqa: F401  (re-exported)
from racing_env.observation import cars_in_observation

if TYPE_CHECKING:
    from typing import Any


def adapt_observation(
    obs: np.ndarray, n_cars: int, n_preview: int, track_length: float
) -> np.ndarray:
    """Observations of races with M cars in the layout of ``n_cars`` cars.

    Parameters
    ----------
    obs : numpy.ndarray
        Env observations, shape ``(..., 6 M + n_preview)`` (see
        :class:`racing_env.RacingParallelEnv`).
    n_cars : int
        The field size of the layout wanted (the one a policy was trained on).
    n_preview : int
        Number of curvature preview values at the end of the observation.
    track_length : float
        Track length [m] (phantoms are placed half a lap behind).

    Returns
    -------
    numpy.ndarray
        float32, shape ``(..., 6 n_cars + n_preview)``: with fewer cars (M < n_cars), the
        missing ones are *phantoms* half a lap behind and otherwise level with this car (they
        can neither touch it nor lead); with more, the ``n_cars - 1`` nearest others by
        progress difference, in index order. Unchanged when M == n_cars.

    Raises
    ------
    ValueError
        An observation length that is not ``6 M + n_preview`` for some M >= 1.
    """
    obs = np.asarray(obs, dtype=np.float32)
    m = cars_in_observation(obs.shape[-1], n_preview)
    if m == n_cars:
        return obs
    own, preview = obs[..., :6], obs[..., 6 * m :]
    others = obs[..., 6 : 6 * m].reshape(obs.shape[:-1] + (m - 1, 6))
    if m < n_cars:
        phantom = np.zeros(obs.shape[:-1] + (n_cars - m, 6), dtype=np.float32)
        phantom[..., 0] = -0.5 * track_length
        others = np.concatenate([others, phantom], axis=-2)
    else:
        near = np.sort(
            np.argsort(np.abs(others[..., 0]), axis=-1, kind="stable")[..., : n_cars - 1], axis=-1
        )
        others = np.take_along_axis(others, near[..., None], axis=-2)
    return np.concatenate([own, others.reshape(obs.shape[:-1] + (-1,)), preview], axis=-1)


_adapt_observation = adapt_observation
"""The former private name, kept as an alias."""


def check_field_size(agent: Any, n_cars: int, car: str, spec: str | None = None) -> None:
    """Raise ``ValueError`` naming the agent, its car and the sizes it supports when ``agent``
    declares ``field_sizes`` that do not include ``n_cars``; agents without a declaration pass."""
    sizes = getattr(agent, "field_sizes", None)
    if sizes is None:
        return
    try:
        ok = n_cars in sizes
    except TypeError:
        raise ValueError(
            f"agent {agent_label(agent, spec)}: field_sizes must be a container of "
            f"car counts (e.g. range(2, 9)), got {sizes!r}"
        ) from None
    if not ok:
        shown = (
            f"{sizes.start}..{sizes.stop - 1}"
            if isinstance(sizes, range) and sizes.step == 1
            else ", ".join(map(str, sorted(sizes)))
        )
        raise ValueError(
            f"agent {agent_label(agent, spec)} driving {car} cannot race in a field of "
            f"{n_cars} cars: it supports {shown} cars (its field_sizes)"
        )
