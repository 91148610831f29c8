"""Multi-layer perceptrons evaluated in numpy (no torch needed to race).

Weights come from the torch models of ``experiments/potential/train.py``; the layout is a list of
``(W (in, out), b (out,))`` with SiLU between layers and a linear output, after an input
normalisation ``(x - mean) / std`` and followed by an output scale ``y * y_scale + y_shift``.
:meth:`MLP.value_and_input_grad` gives the output and its gradient with respect to the input,
which the alpha agent's gradient ascent over theta needs.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

# float32 throughout: for the small batches of online maximisation, numpy's float64 products
# with these layer sizes measured 3-4x slower (and transposed ones 15x) than float32 ones on
# contiguous weights
_F = np.float32


def _silu(z):
    return z / (1.0 + np.exp(-z))


class MLP:
    """``y = MLP(x)`` for x (..., in) -> y (...,)."""

    def __init__(self, layers, mean, std, y_scale: float = 1.0, y_shift: float = 0.0):
        self.layers = [
            (np.ascontiguousarray(W, dtype=_F), np.ascontiguousarray(b, dtype=_F))
            for W, b in layers
        ]
        self._WT = [np.ascontiguousarray(W.T) for W, _ in self.layers]
        # None in a restricted() network, which takes its inputs unnormalised
        self.mean: np.ndarray | None = np.asarray(mean, dtype=_F)
        self.inv_std: np.ndarray | None = (1.0 / np.asarray(std, dtype=np.float64)).astype(_F)
        self.y_scale = float(y_scale)
        self.y_shift = float(y_shift)
        if self.layers[-1][0].shape[1] != 1:
            raise ValueError(f"the last layer must have one output, got {self.layers[-1][0].shape}")

    @property
    def in_dim(self) -> int:
        return self.layers[0][0].shape[0]

    def _check(self, x):
        x = np.asarray(x, dtype=_F)
        if x.shape[-1] != self.in_dim:
            raise ValueError(f"input has {x.shape[-1]} features, this network takes {self.in_dim}")
        if self.mean is None or self.inv_std is None:
            return x
        return (x - self.mean) * self.inv_std

    def _scaling(self) -> tuple[np.ndarray, np.ndarray]:
        """(mean, inv_std) of the input normalisation (a restricted() network has none)."""
        if self.mean is None or self.inv_std is None:
            raise ValueError("a restricted network has no input normalisation")
        return self.mean, self.inv_std

    def __call__(self, x) -> np.ndarray:
        h = self._check(x)
        for W, b in self.layers[:-1]:
            h = _silu(h @ W + b)
        W, b = self.layers[-1]
        return (h @ W + b)[..., 0].astype(np.float64) * self.y_scale + self.y_shift

    def value_and_input_grad(self, x: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(y (B,), dy/dx (B, in)) for x (B, in)."""
        h = self._check(x)
        dsilu = []
        for W, b in self.layers[:-1]:
            z = h @ W + b
            sig = 1.0 / (1.0 + np.exp(-z))
            h = z * sig
            dsilu.append(sig * (1.0 + z * (1.0 - sig)))
        W, b = self.layers[-1]
        y = (h @ W + b)[..., 0].astype(np.float64) * self.y_scale + self.y_shift
        g = W[:, 0] * _F(self.y_scale)
        for WT, d in zip(reversed(self._WT[:-1]), reversed(dsilu)):
            g = (g * d) @ WT
        if self.inv_std is not None:
            g = g * self.inv_std
        if g.shape != h.shape[:-1] + (self.in_dim,):  # no hidden layer: g is constant
            g = np.broadcast_to(g, h.shape[:-1] + (self.in_dim,))
        return y, g.astype(np.float64)

    def restricted(self, x: float | np.ndarray, free: Sequence[int] | np.ndarray) -> MLP:
        """This network as a function of the inputs ``free`` (column indices, F) alone, the
        others fixed at ``x`` (in,): an MLP of F inputs (unnormalised) sharing the deeper
        layers' weights. The fixed inputs' share of the first layer is computed here once, so
        each later evaluation multiplies F columns instead of ``in``: the alpha agent's ascent
        over theta at a fixed state. For evaluation only (it is not saved)."""
        x = np.asarray(x, dtype=_F)
        free = np.asarray(free, dtype=np.int64)
        if x.shape != (self.in_dim,):
            raise ValueError(f"x must have shape ({self.in_dim},), got {x.shape}")
        W0, b0 = self.layers[0]
        mean, inv_std = self._scaling()
        xn = (x - mean) * inv_std
        xn[free] = 0.0
        W0f = inv_std[free, None] * W0[free]  # (F, out0)
        b0f = xn @ W0 + b0 - (mean[free] * inv_std[free]) @ W0[free]
        out = MLP.__new__(MLP)
        out.layers = [(W0f, b0f.astype(_F))] + self.layers[1:]
        out._WT = [np.ascontiguousarray(W0f.T)] + self._WT[1:]
        out.mean, out.inv_std = None, None
        out.y_scale, out.y_shift = self.y_scale, self.y_shift
        return out

    def to_arrays(self, prefix: str) -> dict:
        mean, inv_std = self._scaling()
        out = {
            f"{prefix}mean": mean,
            f"{prefix}std": 1.0 / inv_std.astype(np.float64),
            f"{prefix}y": np.array([self.y_scale, self.y_shift]),
            f"{prefix}n_layers": np.array(len(self.layers)),
        }
        for i, (W, b) in enumerate(self.layers):
            out[f"{prefix}W{i}"] = W.astype(np.float32)
            out[f"{prefix}b{i}"] = b.astype(np.float32)
        return out

    @classmethod
    def from_arrays(cls, z: Mapping[str, np.ndarray], prefix: str) -> MLP:
        n = int(z[f"{prefix}n_layers"])
        layers = [(z[f"{prefix}W{i}"], z[f"{prefix}b{i}"]) for i in range(n)]
        ys = z[f"{prefix}y"]
        return cls(layers, z[f"{prefix}mean"], z[f"{prefix}std"], float(ys[0]), float(ys[1]))
