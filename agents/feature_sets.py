"""The feature sets a model can be trained with, chosen by name: ``fixed``
(:mod:`agents.features`, the paper's: one track, a fixed number of cars) and ``general``
(:mod:`agents.general_features`: any track, any N up to 8). This module imports both; neither
imports it, so the two feature modules do not import each other."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from . import features as f
from . import general_features


@dataclass(frozen=True)
class FeatureSet:
    """One feature function pair and its layout, as a model needs it.

    ``value_features(states, thetas, track, ego, space=None)`` and
    ``potential_features(states, thetas, track, order=None, space=None)`` as in
    :mod:`agents.features`; ``value_dim(N, space)``, ``potential_dim(N, space)``,
    ``potential_theta_slots(N, space)`` (N, dim) and ``progress_order(states)`` (..., N);
    ``space`` a policy space (name or :class:`agents.theta.PolicySpace`, default the paper's).
    ``general``: the features take any N from 2 to ``max_cars`` and any track; otherwise the
    model is tied to its training track and number of cars.
    """

    name: str
    version: int
    general: bool
    max_cars: int | None
    value_features: Callable
    potential_features: Callable
    value_dim: Callable
    potential_dim: Callable
    potential_theta_slots: Callable
    progress_order: Callable


FIXED = FeatureSet(
    "fixed",
    f.FEATURE_VERSION,
    False,
    None,
    f.value_features,
    f.potential_features,
    f.value_dim,
    f.potential_dim,
    f.potential_theta_slots,
    f.progress_order,
)
FEATURE_SETS = ("fixed", "general")


def feature_set(name: str = "fixed") -> FeatureSet:
    """The feature set called ``name`` (``fixed``: :mod:`agents.features`; ``general``:
    :mod:`agents.general_features`). An unknown name is a ValueError."""
    if name == "fixed":
        return FIXED
    if name == "general":
        g = general_features
        return FeatureSet(
            "general",
            g.FEATURE_VERSION,
            True,
            g.N_MAX,
            g.value_features,
            g.potential_features,
            g.value_dim,
            g.potential_dim,
            g.potential_theta_slots,
            g.progress_order,
        )
    raise ValueError(f"unknown feature set {name!r}; expected one of {FEATURE_SETS}")
