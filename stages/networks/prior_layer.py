"""The head every network type shares, in numpy: h2c, the MLN PriorLayer, log-softmax.

Paper (Rahman et al., RO-MAN 2021): a linear layer maps the network's hidden output to class scores
(h2c). PriorLayer: h2c' = W1·h2c + W2·c2c, where c2c is the frame's MLN class input; as in the authors'
code it is one linear layer over the concatenation [h2c, c2c]. The torch twin is in
stages/networks/classifier.py (``h2c`` and ``prior``, the state dict's names read here).
"""

from __future__ import annotations

import numpy as np


def log_softmax(x: np.ndarray) -> np.ndarray:
    shifted = x - x.max(axis=-1, keepdims=True)
    return shifted - np.log(np.exp(shifted).sum(axis=-1, keepdims=True))


def head(weights: dict[str, np.ndarray], hidden: np.ndarray, prior: np.ndarray | None) -> np.ndarray:
    """h2c, then the PriorLayer over [h2c, c2c] when the network has one, then log-softmax: [..., C]."""
    scores = hidden @ weights["h2c.weight"].T + weights["h2c.bias"]
    if "prior.weight" in weights:
        if prior is None:
            raise ValueError("a PriorLayer network needs the MLN class input of every frame")
        scores = np.concatenate([scores, prior], axis=-1) @ weights["prior.weight"].T + weights["prior.bias"]
    return log_softmax(scores)
