"""The decoders: how a method's chain turns into one class per frame, with the lag each waits for.

A decoded method is named ``METHOD+DECODER`` (``mln+filter``, ``conflation+viterbi``) and, for the decoders
that wait a fixed number of frames, ``METHOD+DECODER@LAG`` (``mln+smooth-legal@5``): frame t is decided once
frame t + LAG has arrived. Offline decoders (viterbi, posterior) read the whole recording. A ``-legal`` form
never emits a transition the chain forbids: it takes the argmax among the classes allowed after the class it
emitted last (stages/mln/lag.py).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from mlnseq.catalog.errors import BadInput

DEFAULT_LAGS = (0, 1, 2, 5, 10, 25)  # frames: conflate --lags' default


class Decoder(str, enum.Enum):
    """A decoder of a method's chain."""

    NONE = "none"  # per frame, no chain
    FILTER = "filter"  # online, lag 0: argmax of p(y_t | frames up to t)
    FILTER_LEGAL = "filter-legal"
    SMOOTH = "smooth"  # fixed lag L: argmax of p(y_t | frames up to t + L)
    SMOOTH_LEGAL = "smooth-legal"
    LAGVITERBI = "lagviterbi"  # fixed lag L: the class at t of the best path up to t + L
    LAGVITERBI_LEGAL = "lagviterbi-legal"
    POSTERIOR = "posterior"  # offline: argmax of p(y_t | the whole recording)
    POSTERIOR_LEGAL = "posterior-legal"
    VITERBI = "viterbi"  # offline: the most probable path

    @property
    def lagged(self) -> bool:
        """Whether the decoder takes a lag in frames (smooth, lagviterbi and their legal forms)."""
        return self in (Decoder.SMOOTH, Decoder.SMOOTH_LEGAL, Decoder.LAGVITERBI, Decoder.LAGVITERBI_LEGAL)

    @property
    def offline(self) -> bool:
        """Whether it needs the whole recording (its lag is the recording's length)."""
        return self in (Decoder.POSTERIOR, Decoder.POSTERIOR_LEGAL, Decoder.VITERBI)

    @property
    def legal(self) -> bool:
        """Whether it never emits a transition the chain forbids (viterbi's path never does)."""
        return self.value.endswith("-legal") or self is Decoder.VITERBI

    @property
    def free(self) -> Decoder:
        """The form that ignores the rules at output (itself when it has no legal form)."""
        return Decoder(self.value.removesuffix("-legal"))

    @property
    def semiring(self) -> str:
        """sum (marginals) or max (best paths)."""
        return "max" if self.free in (Decoder.LAGVITERBI, Decoder.VITERBI) else "sum"


ONLINE = tuple(d for d in Decoder if d is not Decoder.NONE and not d.offline)
OFFLINE = tuple(d for d in Decoder if d.offline)


@dataclass(frozen=True)
class Decoding:
    """A decoder with its lag in frames (0 for filter; None for offline decoders and none)."""

    decoder: Decoder
    lag: int | None = None

    def __post_init__(self) -> None:
        lag = self.lag
        if self.decoder.lagged:
            if not isinstance(lag, int) or isinstance(lag, bool) or lag < 0:
                raise BadInput(f"decoder {self.decoder.value}: its lag must be a whole number of frames >= 0, "
                               f"got {lag!r}")
        elif self.decoder in (Decoder.FILTER, Decoder.FILTER_LEGAL):
            if lag not in (0, None):
                raise BadInput(f"decoder {self.decoder.value} has lag 0, got {lag!r}: use smooth for a lag")
            object.__setattr__(self, "lag", 0)
        elif lag is not None:
            raise BadInput(f"decoder {self.decoder.value} takes no lag (it reads the whole recording), got {lag!r}")

    @property
    def name(self) -> str:
        """``filter``, ``smooth@5``, ``viterbi``: how decoded method names end."""
        return self.decoder.value if not self.decoder.lagged else f"{self.decoder.value}@{self.lag}"

    def latency_s(self, rate_hz: float | None) -> float | None:
        """The lag in seconds at ``rate_hz`` frames per second (None where the rate is unknown; inf offline)."""
        if self.decoder.offline:
            return math.inf
        if not self.lag:  # lag 0, or none (per frame)
            return 0.0
        return None if not rate_hz else self.lag / rate_hz


def parse_decoding(text: str, option: str = "--decode") -> Decoding:
    """A decoding as written: ``filter``, ``smooth@5``, ``posterior-legal``; a bad one is a BadInput naming
    ``option``."""
    name, at, lag_text = text.partition("@")
    try:
        decoder = Decoder(name)
    except ValueError:
        raise BadInput(f"unknown {option} {text!r}: choose one of {', '.join(d.value for d in Decoder)}"
                       " (smooth and lagviterbi with @LAG frames, e.g. smooth-legal@5)") from None
    lag: int | None = None
    if at:
        try:
            lag = int(lag_text)
        except ValueError:
            raise BadInput(f"{option} {text!r}: the lag after @ must be a whole number of frames") from None
        if lag < 0:
            raise BadInput(f"{option} {text!r}: a lag is at least 0 frames")
    elif decoder.lagged:
        raise BadInput(f"{option} {text!r}: {decoder.value} needs a lag in frames, e.g. {decoder.value}@5")
    return Decoding(decoder, lag)


def parse_lags(text: str, option: str = "--lags") -> tuple[int, ...]:
    """``--lags`` as written: a comma list of whole numbers of frames >= 0."""
    try:
        lags = tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise BadInput(f"{option} {text!r}: give whole numbers of frames, comma-separated (e.g. 0,1,5,25)") from None
    if not lags or min(lags) < 0:
        raise BadInput(f"{option} {text!r}: give one or more lags of at least 0 frames")
    return tuple(sorted(set(lags)))


def decodings(decoders: tuple[Decoder, ...], lags: tuple[int, ...]) -> list[Decoding]:
    """Every decoding of ``decoders`` at ``lags`` (lag 0 smoothing is the filter, so it is left to it)."""
    out: list[Decoding] = []
    for decoder in decoders:
        if decoder is Decoder.NONE:
            continue
        if decoder.lagged:
            out += [Decoding(decoder, lag) for lag in lags
                    if not (lag == 0 and decoder.free is Decoder.SMOOTH)]
        else:
            out.append(Decoding(decoder))
    return out
