"""A chain's factors and its online filter: what the scan engine, the public chain functions and the
recogniser share (stages/mln/chain.py says what the distribution is).

Numbers: each unary row and each pairwise matrix is scaled by its maximum and finite entries more than
``CLIP`` below it count as ``CLIP`` below (e^-300: far below any probability that matters), so a product of
one step never underflows to zero while a class is possible. Dead ends (no class possible given the previous
frames) restart the chain at that frame from its unary alone; a frame whose unary is -inf everywhere becomes
uniform: ``Filter`` does this one frame at a time, ``_restarted`` marks the same frames as chain starts.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

CLIP = 300.0


@dataclass(frozen=True)
class ChainFactors:
    unary: np.ndarray  # [T, C] float64 log-potentials of each frame's class; -inf: impossible
    pairwise: np.ndarray  # [P, C, C] float64 log-potentials of (class at t-1, class at t); -inf forbids
    link: np.ndarray  # [T] int64: the row of `pairwise` joining frame t-1 to frame t; -1 where frame t starts a chain

    def __post_init__(self) -> None:
        unary, pairwise, link = (np.asarray(self.unary, dtype=np.float64), np.asarray(self.pairwise, dtype=np.float64),
                                 np.asarray(self.link, dtype=np.int64))
        object.__setattr__(self, "unary", unary)
        object.__setattr__(self, "pairwise", pairwise)
        object.__setattr__(self, "link", link)
        if unary.ndim != 2 or pairwise.ndim != 3 or pairwise.shape[1:] != (unary.shape[1],) * 2 \
                or link.shape != (len(unary),):
            raise ValueError(f"chain factors of mismatched shapes: unary {unary.shape}, pairwise {pairwise.shape}, "
                             f"link {link.shape}")
        if len(link) and (link[0] != -1 or link.min() < -1 or link.max() >= len(pairwise)):
            raise ValueError("link must be -1 at frame 0 and index a row of pairwise (or be -1) elsewhere")
        for name, values in (("unary", unary), ("pairwise", pairwise)):
            if not (values < np.inf).all():  # NaN and +inf fail the comparison
                raise ValueError(f"{name} log-potentials must be finite or -inf")

    @property
    def n_classes(self) -> int:
        return self.unary.shape[1]

    @classmethod
    def joined(cls, parts: Sequence[ChainFactors]) -> ChainFactors:
        """Several chains' factors one after another, as one (each part's chains stay its own: a part starts a
        chain at its first frame)."""
        offsets = np.cumsum([0] + [len(part.pairwise) for part in parts[:-1]])
        link = [np.where(part.link >= 0, part.link + offset, -1) for part, offset in zip(parts, offsets)]
        return cls(np.concatenate([part.unary for part in parts]), np.concatenate([part.pairwise for part in parts]),
                   np.concatenate(link))


def _scaled(values: np.ndarray, axes: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """exp(values - max) over ``axes`` with finite entries clipped at -CLIP, and the max (-inf: all -inf)."""
    top = values.max(axis=axes, keepdims=True)
    if (values > -np.inf).all():
        return np.exp(np.maximum(values - top, -CLIP)), np.squeeze(top, axis=axes)
    finite_top = np.where(np.isfinite(top), top, 0.0)
    linear = np.exp(np.clip(values - finite_top, -CLIP, 0.0)) * np.isfinite(values)
    return linear, np.squeeze(top, axis=axes)


class Filter:
    """The online filter, one frame at a time (for live streams): the same numbers as ``filtered``."""

    def __init__(self, n_classes: int):
        self.n_classes = n_classes
        self._alpha: np.ndarray | None = None
        self.restarted = False
        self._pairwise = b""  # the last pairwise matrix passed (its bytes), and its scaled form
        self._transition = np.ones((n_classes, n_classes))

    def reset(self) -> None:
        """The next frame starts a new chain."""
        self._alpha = None

    def step(self, unary: np.ndarray, pairwise: np.ndarray | None) -> np.ndarray:
        """log p(y_t | frames so far) [C]; pairwise [C, C] joins the previous frame (None: first frame).
        ``restarted`` then says whether the frame was a dead end (no class possible: the chain starts anew)."""
        self.restarted = self._advance(unary, pairwise)
        if self._alpha.min() > 0.0:
            return np.log(self._alpha)
        with np.errstate(divide="ignore"):
            return np.log(self._alpha)

    def _advance(self, unary: np.ndarray, pairwise: np.ndarray | None) -> bool:
        """Advance by one frame; whether it was a dead end (no class possible: restarted)."""
        unary = np.asarray(unary, dtype=np.float64)
        top = unary.max()
        if top == -np.inf:
            linear = np.zeros(self.n_classes)
        else:
            shifted = unary - top
            linear = np.exp(shifted) if shifted.min() >= -CLIP else _scaled(unary, (0,))[0]
        total = 0.0
        joined = self._alpha is not None and pairwise is not None
        if joined:
            pairwise = np.asarray(pairwise, dtype=np.float64)
            key = pairwise.tobytes()
            if key != self._pairwise:  # a stream passes the same few matrices again and again
                self._transition, self._pairwise = _scaled(pairwise, (0, 1))[0], key
            alpha = (self._alpha @ self._transition) * linear
            total = alpha.sum()
        dead = total == 0.0 and (joined or top == -np.inf)
        if total == 0.0:  # a chain start, or a dead end: restart from the unary alone (uniform if all -inf)
            alpha = linear if top > -np.inf else np.ones(self.n_classes)
            total = alpha.sum()
        self._alpha = alpha / total
        return bool(dead)


def _restarted(factors: ChainFactors) -> ChainFactors:
    """The factors with chain starts where ``Filter`` meets a dead end, and uniform unaries where all were
    -inf (a plain loop over the frames: only run when the fast pass met a dead end)."""
    chain = Filter(factors.n_classes)
    dead = np.array([chain._advance(row, None if link < 0 else factors.pairwise[link])
                     for row, link in zip(factors.unary, factors.link)], dtype=bool)
    unary = factors.unary.copy()
    unary[dead & ~np.isfinite(unary).any(axis=1)] = 0.0
    return ChainFactors(unary, factors.pairwise, np.where(dead, -1, factors.link))
