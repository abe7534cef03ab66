"""conflate: run every trained model and the MLN classifier on all frames, combine them (eq. 16) and,
on request, decode each over the frame chain with the MLN's temporal factors.

Conflation of two class distributions, per class k (eq. 16):
    P_C(k) = P_L(k)·P_K(k) / (P_L(k)·P_K(k) + (1 − P_L(k))·(1 − P_K(k)))
and the prediction is argmax_k P_C(k). The stored conflated values are eq. 16 as it stands, not
renormalised to sum to 1 (the argmax is the same either way).

Methods: lstm, priorlayer (the networks), mln (the MLN classifier alone), conflation (lstm + MLN)
and combined (priorlayer + MLN); with ``--decode filter`` or ``viterbi`` also METHOD+filter (online
forward filtering) and METHOD+viterbi (offline: the most probable path, forward-backward marginals).
A method whose inputs are absent is left out with a note. The work is stages/recognizer.py's.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from stages import artifacts, recognizer
from stages.errors import BadInput, check_choice
from stages.recognizer import DECODES, MLN_MODES


@dataclass(frozen=True)
class ConflateOptions:
    """Options of `mlnseq conflate`."""

    mln_mode: str = "paper"
    decode: tuple[str, ...] = ("none",)  # any of none, filter, viterbi
    network_weight: float | None = None  # decoded methods' network factor: None = chosen on validation

    def validate(self) -> None:
        check_choice("mln-mode", self.mln_mode, MLN_MODES)
        for kind in self.decode:
            check_choice("decode", kind, DECODES, "all, or a comma list such as none,viterbi")
        if self.network_weight is not None and not self.network_weight > 0:
            raise BadInput(f"--network-weight must be positive (or auto), got {self.network_weight}")

    @property
    def decodes(self) -> tuple[str, ...]:
        """The decodings asked for, undecoded first; undecoded methods are always predicted."""
        return tuple(dict.fromkeys(("none", *self.decode)))


def parse_decode(text: str) -> tuple[str, ...]:
    """``--decode`` as written: one name, ``all``, or a comma list."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    return DECODES if names == ("all",) else names


def parse_network_weight(text: str) -> float | None:
    """``--network-weight`` as written: auto (None: chosen on validation) or a number."""
    if text == "auto":
        return None
    try:
        return float(text)
    except ValueError:
        raise BadInput(f"--network-weight must be auto or a number, got {text!r}") from None


def predictions_table(keys: pl.DataFrame, probabilities: dict[str, np.ndarray],
                      predicted: dict[str, np.ndarray]) -> pl.DataFrame:
    """Keys, then per method its predicted class (int16) and its class probabilities (float32)."""
    columns = [keys]
    for method, probs in probabilities.items():
        columns.append(pl.DataFrame(
            [pl.Series(artifacts.pred_column(method), predicted[method], dtype=pl.Int16)]
            + [pl.Series(name, probs[:, k], dtype=pl.Float32)
               for k, name in enumerate(artifacts.prob_columns(method, probs.shape[1]))]
        ))
    return pl.concat(columns, how="horizontal")


@dataclass(frozen=True)
class ConflateResult:
    path: Path
    methods: list[str]
    notes: list[str]
    choices: dict[str, recognizer.WeightChoice]


def run(workdir: Path, options: ConflateOptions) -> ConflateResult:
    """Read frames, models and MLN weights from ``workdir``; write ``predictions.parquet``."""
    options.validate()
    workdir = Path(workdir)
    predicted = recognizer.predict_workdir(workdir, options.mln_mode, options.decodes,
                                           network_weight=options.network_weight)
    methods = [recognizer.decoded_name(m, d) for d in options.decodes for m in recognizer.METHODS
               if recognizer.decoded_name(m, d) in predicted.probabilities]
    table = predictions_table(predicted.keys, {m: predicted.probabilities[m] for m in methods}, predicted.predicted)
    meta = predicted.meta
    path = artifacts.write_table(
        table, workdir / artifacts.PREDICTIONS, "predictions",
        {"methods": methods, "modes": {m: predicted.modes[m] for m in methods}, "mln_mode": options.mln_mode,
         "decode": list(options.decodes), "network_weight_option": options.network_weight, "classes": meta["classes"], "source": meta.get("source", ""),
         "network_weights": {m: {"weight": c.weight, "validation_frame_accuracy": c.accuracy,
                                 "tried": {str(w): a for w, a in c.tried.items()}}
                             for m, c in predicted.choices.items()},
         "validation_frame_accuracy": {m: predicted.validation[m] for m in methods if m in predicted.validation},
         "notes": predicted.notes},
        inputs=predicted.inputs,
    )
    return ConflateResult(path, methods, predicted.notes, predicted.choices)
