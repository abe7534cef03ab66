"""The method vocabulary: the networks, the methods built from them and the MLN, the decodings, and how a
method with a decoding is named in predictions, metrics, model files and on the command line."""

from __future__ import annotations

from mlnseq.catalog.errors import BadInput

NETWORKS = ("lstm", "priorlayer")
METHODS = ("lstm", "mln", "priorlayer", "conflation", "combined")
FUSED = {"conflation": "lstm", "combined": "priorlayer"}  # a fused method -> the network it conflates
PRIORS = ("paper", "logprob")  # the c2c input of PriorLayer: clamped MLN sums (the authors') or log-probs
MLN_MODES = ("paper", "exact")
DECODES = ("none", "filter", "viterbi")  # none: per frame; filter: online chain; viterbi: offline chain


def network_of(method: str) -> str | None:
    """The network a method runs (None for the MLN alone)."""
    return FUSED.get(method, method if method in NETWORKS else None)


def needs_mln(method: str, decode: str) -> bool:
    """Whether a method with this decoding uses the MLN (and so the predicate spec and the weights)."""
    return method != "lstm" or decode != "none"


def decoded_name(method: str, decode: str) -> str:
    """How predictions and metrics name a method with a decoding: ``lstm``, ``lstm+filter``, ``mln+viterbi``."""
    return method if decode == "none" else f"{method}+{decode}"


def method_names() -> list[str]:
    """Every method name predictions.parquet may hold, decoded ones included."""
    return [decoded_name(m, d) for d in DECODES for m in METHODS]


def parse_method(name: str, option: str = "--method") -> tuple[str, str]:
    """(method, decode) of a name such as ``combined+viterbi``; an unknown one is a BadInput naming ``option``."""
    from mlnseq.catalog.decoders import Decoder, parse_decoding

    method, plus, decode = name.partition("+")
    known = plus and decode not in DECODES[1:] and decode.partition("@")[0] in {d.value for d in Decoder} - {"none"}
    if known:
        parse_decoding(decode, option)  # a lagged decoder names its lag: smooth@5
    if method not in METHODS or (plus and decode not in DECODES[1:] and not known):
        raise BadInput(f"unknown {option} {name!r}: choose one of {', '.join(METHODS)}, "
                       f"optionally with +filter or +viterbi (e.g. combined+filter), or another decoder "
                       f"(e.g. conflation+smooth-legal@5)")
    return method, decode or "none"
