"""Decoding a method's chain with any decoder (stages/catalog/decoders.py): the filter and Viterbi of
stages/mln/chain.py, the lagged, posterior and legal decoders of stages/mln/lag.py; the chain's start
distribution; and the figures a choice among decoders reads beside the accuracies (the forbidden transitions
emitted, the log-likelihood of the true labels).

The start distribution is fitted, not learned jointly: the classes the training split's episodes begin with,
counted with one added to every class (Laplace), as log-probabilities added to each chain's first frame.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from mlnseq.catalog.decoders import Decoder, Decoding, parse_decoding
from mlnseq.catalog.parts import Part
from mlnseq.mln import chain, lag

LIKELIHOOD_FLOOR = 1e-4  # a true label's probability counts as at least this in the log-likelihood

WHOLE_CHAIN = {Decoder.FILTER: chain.decode_filter, Decoder.VITERBI: chain.decode_viterbi}  # the others: lag.py


def decoding_of(name: str | Decoding) -> Decoding:
    """A decoding from its name as methods carry it (``filter``, ``smooth-legal@5``)."""
    return name if isinstance(name, Decoding) else parse_decoding(name, "decoding")


def decode(factors: chain.ChainFactors, decoding: str | Decoding) -> chain.Decoded:
    """Decode ``factors`` (its start distribution already added: ``lag.with_start``) with ``decoding``: class
    probabilities [T, C], classes [T] and the frames where a dead end restarted the chain. Filter is online (each
    frame from the frames up to it), viterbi offline (the most probable path, with forward-backward marginals as
    probabilities); the lagged, posterior and legal decoders are stages/mln/lag.py's."""
    return decode_all(factors, [decoding])[0]


def decode_all(factors: chain.ChainFactors, decodings: Sequence[str | Decoding]) -> list[chain.Decoded]:
    """``decode`` with each of ``decodings``; the lagged, posterior and legal ones share their passes
    (``lag.decode_all``)."""
    return decode_each([factors], decodings)[0]


def decode_each(parts: Sequence[chain.ChainFactors], decodings: Sequence[str | Decoding]) -> list[list[chain.Decoded]]:
    """``decode_all`` of each of ``parts``. The lagged, posterior and legal decoders run every part at once, as one
    chain of the parts one after another (lag.py's passes are row by row, so each part gets the classes it gets
    alone); filter and Viterbi, whose scan spans its whole input, run each part alone."""
    wanted = [decoding_of(d) for d in decodings]
    lagged = [d for d in wanted if d.decoder not in WHOLE_CHAIN]
    together = lag.decode_all(chain.ChainFactors.joined(parts), lagged) if lagged and parts else []
    ends = np.cumsum([len(part.link) for part in parts])
    out = []
    for part, stop in zip(parts, ends):
        start = stop - len(part.link)
        shared = {d: chain.Decoded(got.probabilities[start:stop], got.path[start:stop],
                                   got.restarts[(got.restarts >= start) & (got.restarts < stop)] - start)
                  for d, got in zip(lagged, together)}
        out.append([shared[d] if d in shared else WHOLE_CHAIN[d.decoder](part) for d in wanted])
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


def training_start(labels: np.ndarray, episodes: np.ndarray, splits: np.ndarray, n_classes: int) -> np.ndarray:
    """The start distribution a recogniser decodes with (log [C]): ``start_of`` the frames outside the test split
    (conflate fits it, export writes it)."""
    return start_of(labels, episodes, np.asarray(splits) != Part.TEST, n_classes)
