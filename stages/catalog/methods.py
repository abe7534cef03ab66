"""The method vocabulary: the networks, the methods built from them and the MLN, the decodings, and how a
method with a decoding is named in predictions, metrics, model files and on the command line."""

from __future__ import annotations

from enum import Enum, StrEnum
from typing import TypeVar

from mlnseq.catalog.errors import BadInput


class Method(StrEnum):
    """What recognises: a network alone, the MLN alone, or the two fused (eq. 16, PriorLayer)."""

    NETWORK = "lstm"  # the network alone, of any cell (LSTM, GRU, TCN); ``lstm`` in artifacts and file names
    MLN = "mln"
    PRIORLAYER = "priorlayer"  # a network with the MLN's PriorLayer input
    CONFLATION = "conflation"  # the network alone fused with the MLN
    COMBINED = "combined"  # PriorLayer fused with the MLN


ALIASES = {"network": Method.NETWORK}  # command-line names beside the stored ones
NETWORKS = (Method.NETWORK, Method.PRIORLAYER)
METHODS = tuple(Method)
FUSED = {Method.CONFLATION: Method.NETWORK, Method.COMBINED: Method.PRIORLAYER}  # fused method -> its network


class Prior(StrEnum):
    """The c2c input of PriorLayer: the MLN's class sums as the authors passed them, or its log-probabilities."""

    PAPER = "paper"
    LOGPROB = "logprob"


class PaperFloor(StrEnum):
    """How the authors' code made an MLN's per-class formula sums non-negative (PriorLayer's ``paper`` input and
    mln-mode ``paper``): their DESK code clamps negative sums to 0, their Fetch code shifts each frame's sums by
    their minimum. A dataset's choice, recorded with every network trained on it and in every model file."""

    CLAMP = "clamp"
    SHIFT = "shift"

    @classmethod
    def for_recordings(cls, source: str) -> PaperFloor:
        """The authors' floor for a dataset: shift for their Fetch simulation, clamp for DESK and any other."""
        return cls.SHIFT if source == "fetch" else cls.CLAMP


class MLNMode(StrEnum):
    """The MLN's class probabilities: the authors' normalised floored sums (eq. 12-13), or the exact softmax."""

    PAPER = "paper"
    EXACT = "exact"


PRIORS = tuple(Prior)
MLN_MODES = tuple(MLNMode)
DECODES = ("none", "filter", "viterbi")  # none: per frame; filter: online chain; viterbi: offline chain

E = TypeVar("E", bound=Enum)


def member(kind: type[E], value: object, aliases: dict[str, E] | None = None) -> E | object:
    """``value`` as a member of ``kind`` when it names one (or an alias); else as it is, for ``validate`` to
    refuse in one line (options are built before they are checked)."""
    if isinstance(value, str) and value in (aliases or {}):
        return aliases[value]
    try:
        return kind(value)
    except ValueError:
        return value


def as_method(name: str) -> Method | str:
    """A method name as written (``network`` included) as a Method, else unchanged."""
    return member(Method, name, ALIASES)


def network_of(method: str) -> Method | None:
    """The network a method runs (None for the MLN alone)."""
    method = as_method(method)
    return FUSED.get(method, method if method in NETWORKS else None)


def needs_mln(method: str, decode: str) -> bool:
    """Whether a method with this decoding uses the MLN (and so the predicate spec and the weights)."""
    return as_method(method) != Method.NETWORK or decode != "none"


def decoded_name(method: str, decode: str) -> str:
    """How predictions and metrics name a method with a decoding: ``lstm``, ``lstm+filter``, ``mln+viterbi``."""
    method = str(as_method(method))
    return method if decode == "none" else f"{method}+{decode}"


def method_names() -> list[str]:
    """Every method name predictions.parquet may hold, decoded ones included."""
    return [decoded_name(m, d) for d in DECODES for m in METHODS]


def parse_method(name: str, option: str = "--method") -> tuple[Method, str]:
    """(method, decode) of a name such as ``combined+viterbi``, ``network+filter`` or ``conflation+smooth-legal@5``;
    an unknown one is a BadInput naming ``option``."""
    from mlnseq.catalog.decoders import Decoder, parse_decoding

    method, plus, decode = name.partition("+")
    method = as_method(method)
    known = plus and decode not in DECODES[1:] and decode.partition("@")[0] in {d.value for d in Decoder} - {"none"}
    if known:
        parse_decoding(decode, option)  # a lagged decoder names its lag: smooth@5
    if method not in METHODS or (plus and decode not in DECODES[1:] and not known):
        raise BadInput(f"unknown {option} {name!r}: choose one of network (or lstm), "
                       f"{', '.join(METHODS[1:])}, optionally with +filter or +viterbi (e.g. combined+filter), or "
                       f"another decoder (e.g. conflation+smooth-legal@5)")
    return method, decode or "none"


class WeightSource(StrEnum):
    """How a decoded network method's network factor weight was set."""

    VALIDATION = "validation"  # the best of a grid on the network's validation part
    FIXED = "fixed"  # given (--network-weight), or 1 with nothing to choose on
    LEARNED = "learned"  # by the chain's CLL on out-of-fold predictions


def split_name(method: str, decode: str, lag: int | None, option: str = "--method") -> tuple[str, str, int | None]:
    """``--method``, ``--decode`` and ``--lag`` as any command prints a name: ``conflation+smooth-legal@25`` (a
    method with its decoder and lag), ``smooth-legal@5`` (a decoder with its lag), or each apart; a part given twice
    and differently is a BadInput."""
    from mlnseq.catalog.decoders import parse_decoding

    name, plus, named_decode = str(method).partition("+")
    if plus:
        from mlnseq.catalog.decoders import Decoder

        if name not in (*(m.value for m in METHODS), *ALIASES) or named_decode.partition("@")[0] not in {
                d.value for d in Decoder}:
            parse_method(str(method), option)  # refused with the names it takes
        if decode not in ("none", named_decode.partition("@")[0], named_decode):
            raise BadInput(f"{option} {method} names its decoder; --decode {decode} names another: give one")
        method, decode = name, named_decode
    if "@" in decode:
        decoding = parse_decoding(decode, option if plus else "--decode")
        if lag is not None and lag != decoding.lag:
            raise BadInput(f"{decode} waits {decoding.lag} frames; --lag {lag} says another: give the lag once")
        decode, lag = decoding.decoder.value, decoding.lag
    return method, decode, lag


def decoders_named(names: tuple[str, ...], option: str = "--decode") -> tuple[tuple[str, ...], tuple[int, ...]]:
    """Decoders as any command prints them (``smooth-legal@5``, ``conflation+viterbi``: its decoder) and the lags
    named after their @, in order."""
    decoders, lags = [], []
    for text in names:
        name, plus, decode = text.partition("+")
        if plus:
            parse_method(text, option)
        _, decode, lag = split_name(name, decode if plus else text, None, option)
        decoders.append(decode)
        lags += [] if lag is None else [lag]
    return tuple(dict.fromkeys(decoders)), tuple(dict.fromkeys(lags))


def decoder_of(text: str | None, method: str, option: str = "--decode") -> str | None:
    """A decoder given to a model of ``method``: ``smooth-legal@5``, or the model's name as commands print it
    (``conflation+smooth-legal@5``): its decoder; a name of another method is a BadInput."""
    if text is None or "+" not in text:
        return text
    named, decode = parse_method(text, option)
    if named != as_method(method):
        raise BadInput(f"{option} {text}: this model recognises with {as_method(method)}, not {named}; give its "
                       f"decoder alone (--decode {decode})")
    return decode
