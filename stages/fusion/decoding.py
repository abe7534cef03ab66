"""Decoding a method's chain with any decoder (stages/catalog/decoders.py): the filter and Viterbi of
stages/mln/chain.py, the lagged, posterior and legal decoders of stages/mln/lag.py; the chain's start
distribution; and the figures a choice among decoders reads beside the accuracies (the forbidden transitions
emitted, the log-likelihood of the true labels).

The start distribution is fitted, not learned jointly: the classes the training split's episodes begin with,
counted with one added to every class (Laplace), as log-probabilities added to each chain's first frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mlnseq.catalog.decoders import Decoder, Decoding, parse_decoding
from mlnseq.mln import chain, lag

LIKELIHOOD_FLOOR = 1e-4  # a true label's probability counts as at least this in the log-likelihood


@dataclass(frozen=True)
class Decoded:
    """A decoded chain: classes [T], class probabilities [T, C], dead ends [R] and forbidden transitions emitted."""

    path: np.ndarray
    probabilities: np.ndarray
    restarts: np.ndarray
    forbidden: int


def decoding_of(name: str | Decoding) -> Decoding:
    """A decoding from its name as methods carry it (``filter``, ``smooth-legal@5``)."""
    return name if isinstance(name, Decoding) else parse_decoding(name, "decoding")


def decode(factors: chain.ChainFactors, decoding: str | Decoding) -> Decoded:
    """Decode ``factors`` (its start distribution already added: ``lag.with_start``) with ``decoding``."""
    return decode_all(factors, [decoding])[0]


def decode_all(factors: chain.ChainFactors, decodings: Sequence[str | Decoding]) -> list[Decoded]:
    """``decode`` with each of ``decodings``; the lagged, posterior and legal ones share their passes
    (``lag.decode_all``)."""
    return decode_each([factors], decodings)[0]


def decode_each(parts: Sequence[chain.ChainFactors], decodings: Sequence[str | Decoding]) -> list[list[Decoded]]:
    """``decode_all`` of each of ``parts``. The lagged, posterior and legal decoders run every part at once, as one
    chain of the parts one after another (lag.py's passes are row by row, so each part gets the classes it gets
    alone); filter and Viterbi, whose scan spans its whole input, run each part alone."""
    wanted = [decoding_of(d) for d in decodings]
    lagged = [d for d in wanted if d.decoder not in (Decoder.FILTER, Decoder.VITERBI)]
    together = lag.decode_all(chain.ChainFactors.joined(parts), lagged) if lagged and parts else []
    ends = np.cumsum([len(part.link) for part in parts])
    out = []
    for part, stop in zip(parts, ends):
        start = stop - len(part.link)
        shared = {d: lag.LagDecoded(got.path[start:stop], got.probabilities[start:stop],
                                    got.restarts[(got.restarts >= start) & (got.restarts < stop)] - start)
                  for d, got in zip(lagged, together)}
        decoded = []
        for decoding in wanted:
            got = shared[decoding] if decoding in shared else chain.decode(part, decoding.decoder.value)
            forbidden = lag.forbidden_transitions(part, got.path)
            decoded.append(Decoded(got.path, got.probabilities, got.restarts, forbidden))
        out.append(decoded)
    return out


def forbidden_in(factors: chain.ChainFactors, path: np.ndarray, rows: np.ndarray) -> int:
    """Forbidden transitions ``path`` emits into the frames ``rows`` (bool [T]) selects."""
    keep = np.asarray(rows, dtype=bool) & (factors.link >= 0)
    link = np.where(keep, factors.link, -1)
    return lag.forbidden_transitions(chain.ChainFactors(factors.unary, factors.pairwise, link), path)


def start_of(labels: np.ndarray, episodes: np.ndarray, rows: np.ndarray, n_classes: int) -> np.ndarray:
    """The start distribution (log [C]) from the episodes' first frames among ``rows`` (bool or indices)."""
    rows = np.flatnonzero(rows) if np.asarray(rows).dtype == bool else np.asarray(rows)
    first = chain.chain_starts(np.asarray(episodes)[rows])
    return lag.fit_start(np.asarray(labels)[rows], first, n_classes)
