"""`mlnseq conflate`: run every trained model and the MLN classifier on all frames and combine them."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.markup import escape

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, reported_errors
from mlnseq import conflate as stage
from mlnseq.catalog.decoders import parse_lags


def conflate(
    mln_mode: Annotated[str, typer.Option(help="MLN class probabilities: paper (the authors' normalised floored sums, "
                                               "floored as the networks were trained: train --paper-floor) or exact "
                                               "(softmax of the scores).")] = stage.ConflateOptions.mln_mode.value,
    decode: Annotated[str, typer.Option(help="none (per frame, the paper), filter (online), filter-legal, smooth and "
                                             "lagviterbi (fixed lag, each at every --lags), their -legal forms (never "
                                             "a transition the chain forbids), posterior, posterior-legal and viterbi "
                                             "(offline), all, or a comma list.")] = "none",
    lags: Annotated[str, typer.Option(help="Lags in frames at which smooth and lagviterbi decode (frame t decided "
                                           "once t + LAG has arrived), comma-separated.")]
    = ",".join(map(str, stage.DEFAULT_LAGS)),
    network_weight: Annotated[str, typer.Option(help="Decoded methods: the weight of the network's log-probabilities, "
                                                     "auto (chosen on the validation part) or a number.")] = "auto",
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Read WORKDIR/frames.parquet, models/*.pt, predicates.parquet and weights.parquet; write
    WORKDIR/predictions.parquet (keys, then per method METHOD_pred and METHOD_p0.. class probabilities for lstm, mln,
    priorlayer, conflation = lstm+MLN and combined = priorlayer+MLN, eq. 16; with --decode also METHOD+DECODER
    (METHOD+DECODER@LAG for the lagged ones, their classes only), decoded over each episode with the MLN's temporal
    formulas, the network factor's weight learned on the out-of-fold predictions of networks trained with --folds,
    else chosen on the validation part; with fold networks also every method's cross-validated figures on the
    training split, in the metadata, with the log-likelihood of the true labels and the forbidden transitions each
    decoded method emits)."""
    with reported_errors():
        options = stage.ConflateOptions(mln_mode=mln_mode, decode=stage.parse_decode(decode),
                                        network_weight=stage.parse_network_weight(network_weight),
                                        lags=parse_lags(lags))
    from mlnseq.catalog import artifacts
    from mlnseq.recognition.folds import describe

    with reported_errors():
        result = stage.run(workdir, options)
    for note in result.notes:
        console.print(f"[yellow]note[/]: {escape(note.text)}")
    for name, choice in result.choices.items():
        if choice.how == "learned":
            console.print(f"{name}: network factor weight {choice.weight:.3g} (learned on out-of-fold predictions)")
        elif choice.accuracy is not None:
            console.print(f"{name}: network factor weight {choice.weight:g} "
                          f"(validation frame accuracy {choice.accuracy:.1%})")
    cross = artifacts.read_metadata(result.path).get("cross_validation")
    said = f"; cross-validated figures over {describe(cross['folds'])}" if cross else ""
    console.print(f"[green]conflate[/]: wrote {result.path} ({', '.join(result.methods)}){said}")
