"""Choosing a method, a decoder and a lag within a latency budget, on the cross-validated figures conflate records
(never on test), and the recordings' frame rate that turns a lag into seconds.

Candidates: every method conflate cross-validated, undecoded (lag 0) and with every decoder at every lag it was
scored at, within the budget (offline decoders only without one). Where the chain has hard rules (a transition
factor of -inf), only decoders that keep them are candidates (the -legal forms and viterbi). Criterion: the mean
of the cross-validated segment accuracy, frame accuracy and edit score, ties broken by the out-of-fold
log-likelihood of the true labels. Segment accuracy alone moves in steps of 2-8 points on the few dozen
segments of a training split; frame accuracy moves by a frame at a time, and the mean of the three follows
what a live user reads (the segments, the frames and their order).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from mlnseq.catalog.decoders import Decoder, Decoding, parse_decoding
from mlnseq.catalog.errors import BadInput

RATES_HZ = {"fetch": 25.0}  # sources whose frame rate the frames do not record: FetchPickAndPlace-v4 steps 0.04 s
CRITERION = ("segment_accuracy", "frame_accuracy", "edit")


def rate_of(frames_meta: dict[str, Any]) -> float | None:
    """Frames per second of a workdir's recordings: the reading's rate (bags), the source's known rate, or None."""
    reading = frames_meta.get("reading") or {}
    rate = reading.get("rate") if isinstance(reading, dict) else None
    if isinstance(rate, (int, float)) and rate > 0:
        return float(rate)
    return RATES_HZ.get(frames_meta.get("source", ""))


@dataclass(frozen=True)
class Candidate:
    name: str  # as predictions name it: conflation+smooth-legal@5
    method: str
    decoding: Decoding
    figures: dict[str, float]

    @property
    def score(self) -> tuple[float, float]:
        accuracy = sum(self.figures.get(k, math.nan) for k in CRITERION) / len(CRITERION)
        return (accuracy if accuracy == accuracy else -math.inf, self.figures.get("log_likelihood", -math.inf))

    def record(self) -> dict[str, Any]:
        return {"name": self.name, "method": self.method, "decoder": self.decoding.decoder.value,
                "lag_frames": self.decoding.lag, "criterion": self.score[0], "log_likelihood": self.score[1],
                "cv": self.figures}


def candidates(figures: dict[str, dict[str, float]]) -> list[Candidate]:
    """Every cross-validated method of a predictions table's metadata, with its decoding."""
    out = []
    for name, values in figures.items():
        method, plus, decode = name.partition("+")
        decoding = parse_decoding(decode, "decoding") if plus else Decoding(Decoder.NONE)
        out.append(Candidate(name, method, decoding, values))
    return out


def budget_frames(lag: int | None, latency_s: float | None, rate_hz: float | None, where: str) -> int | None:
    """The budget in frames from --lag or --latency (None: no budget); --latency needs a known rate."""
    if lag is not None and latency_s is not None:
        raise BadInput("give --lag FRAMES or --latency SECONDS, not both")
    if lag is not None:
        if lag < 0:
            raise BadInput(f"--lag {lag}: a lag is at least 0 frames")
        return lag
    if latency_s is None:
        return None
    if not latency_s >= 0:
        raise BadInput(f"--latency {latency_s:g}: a latency is at least 0 seconds")
    if rate_hz is None:
        raise BadInput(f"--latency: the frame rate of {where}'s recordings is not known; give the budget as --lag "
                       "FRAMES instead")
    return int(math.floor(latency_s * rate_hz + 1e-9))


def within(candidate: Candidate, budget: int | None, decoder: Decoder | None, hard_rules: bool) -> bool:
    """Whether a candidate fits: its lag within ``budget`` frames (None: any, offline included), the decoder asked
    (None: any), and the hard rules kept where the chain has them."""
    decoding = candidate.decoding
    if decoder is not None and decoding.decoder is not decoder:
        return False
    if hard_rules and decoding.decoder is not Decoder.NONE and not decoding.decoder.legal:
        return False
    if hard_rules and decoding.decoder is Decoder.NONE:
        return False  # per-frame classes ignore the rules
    if budget is None:
        return True
    return not decoding.decoder.offline and (decoding.lag or 0) <= budget


def choose(figures: dict[str, dict[str, float]], budget: int | None, decoder: Decoder | None = None,
           hard_rules: bool = False, where: str = "the workdir") -> tuple[Candidate, list[Candidate]]:
    """The best candidate by the criterion, and all those that fitted; none fits: a BadInput saying why."""
    fitting = [c for c in candidates(figures) if within(c, budget, decoder, hard_rules)]
    if not fitting:
        what = f"{decoder.value} " if decoder is not None else ""
        limit = "" if budget is None else f" within {budget} frame(s)"
        raise BadInput(f"no cross-validated {what}candidate in {where}{limit}"
                       + (" that keeps its hard rules" if hard_rules else "")
                       + ": run `mlnseq conflate --decode all` (with --lags including smaller lags) or allow more")
    return max(fitting, key=lambda c: c.score), fitting


@dataclass(frozen=True)
class Timing:
    """A model file's decoding with its lag, latency, the recordings' rate and the chains' start distribution."""

    decoding: Decoding
    latency_s: float | None
    rate_hz: float | None
    start: Any  # np.ndarray [C] of log-probabilities, or None


def read_timing(manifest: dict[str, Any], where: str, n_classes: int) -> Timing:
    """The decoding a model file's manifest records; a malformed decoder, lag, latency or start is refused in one
    line naming the file."""
    import numpy as np

    again = "export it again with `mlnseq export`"
    decode, lag = manifest.get("decode"), manifest.get("lag")
    try:
        decoder = Decoder(decode)
    except ValueError:
        raise BadInput(f"{where}: its manifest's decoder {decode!r} is not one this mlnseq runs "
                       f"({', '.join(d.value for d in Decoder)}): {again}") from None
    if lag is not None and (not isinstance(lag, int) or isinstance(lag, bool)):
        raise BadInput(f"{where}: its manifest's lag {lag!r} is not a whole number of frames: {again}")
    try:
        decoding = Decoding(decoder, lag)
    except BadInput as error:
        raise BadInput(f"{where}: its manifest's {error}: {again}") from None
    numbers = {k: manifest.get(k) for k in ("latency_s", "rate_hz")}
    for key, value in numbers.items():
        if value is not None and (not isinstance(value, (int, float)) or isinstance(value, bool) or not value >= 0
                                  or value == math.inf):
            raise BadInput(f"{where}: its manifest's {key} {value!r} is not null or a number >= 0: {again}")
    start = manifest.get("start")
    if start is not None:
        if not (isinstance(start, list) and len(start) == n_classes
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in start)
                and all(math.isfinite(v) for v in start)):
            raise BadInput(f"{where}: its manifest's start is not a list of {n_classes} finite log-probabilities: "
                           f"{again}")
        start = np.asarray(start, dtype=np.float64)
    return Timing(decoding, numbers["latency_s"], numbers["rate_hz"], start)
