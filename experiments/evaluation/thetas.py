"""The thetas a policy map races: the box of a policy space (:mod:`agents.reference`, read
when a map starts), scrambled-Sobol points in it, and a theta as an ``mpc`` agent spec."""

from __future__ import annotations

import warnings

import numpy as np


def theta_box(space: str = "paper") -> tuple[np.ndarray, np.ndarray]:
    """The current box ``(low, high)`` of policy space ``space`` (for the paper's space
    ``THETA_LOW, THETA_HIGH``, looked up at call time, never copied)."""
    from agents import reference

    if space == "paper":
        return np.array(reference.THETA_LOW, dtype=float), np.array(
            reference.THETA_HIGH, dtype=float
        )
    sp = reference.policy_space(space)
    return np.array(sp.low, dtype=float), np.array(sp.high, dtype=float)


def theta_names(space: str = "paper") -> tuple:
    """Parameter names of policy space ``space``, in array order."""
    from agents.reference import policy_space

    return policy_space(space).names


def sample_thetas(n: int, seed: int, low=None, high=None) -> np.ndarray:
    """``n`` thetas (n, 5) of a scrambled Sobol sequence (scipy.stats.qmc.Sobol, scrambled by a
    ``numpy.random.default_rng(seed)``) scaled to ``[low, high)`` (default: the current theta
    box). The first ``n`` points of the sequence: a power of two keeps Sobol's balance."""
    from scipy.stats import qmc

    if not (isinstance(n, int) and n >= 1):
        raise ValueError(f"number of thetas must be a positive integer, got {n!r}")
    if low is None or high is None:
        low, high = theta_box()
    sobol = qmc.Sobol(d=len(low), scramble=True, seed=np.random.default_rng(seed))
    with warnings.catch_warnings():  # "balance properties ... n = 2^m": documented above
        warnings.simplefilter("ignore", UserWarning)
        u = sobol.random(n)
    return qmc.scale(u, low, high)


def theta_spec(theta) -> str:
    """The ``mpc`` agent spec of a theta, exact (floats in ``repr`` form): shape (5,) of the
    paper's space, or (6,) of the extended space (the spec then says ``space=extended``)."""
    from agents.theta import space_of

    space = space_of(theta)
    head = "mpc:" if space.name == "paper" else f"mpc:space={space.name},"
    return head + ",".join(f"{name}={float(v)!r}" for name, v in zip(space.names, theta))


def theta_dict(theta) -> dict:
    from agents.theta import space_of

    return {name: float(v) for name, v in zip(space_of(theta).names, theta)}
