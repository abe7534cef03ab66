"""`mlnseq conflate`: run every trained model and the MLN classifier on all frames and combine them."""

from __future__ import annotations

from typing import Annotated

import typer
from rich.markup import escape

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, reported_errors
from mlnseq import conflate as stage


def conflate(
    mln_mode: Annotated[str, typer.Option(help="MLN class probabilities: paper (the authors' normalised floored sums, "
                                               "floored as the networks were trained: train --paper-floor) or exact "
                                               "(softmax of the scores).")] = stage.ConflateOptions.mln_mode.value,
    decode: Annotated[str, typer.Option(help="none (per frame, the paper), filter (online), filter-legal, smooth and "
                                             "lagviterbi (fixed lag, each at every --lags), their -legal forms (never "
                                             "a transition the chain forbids), posterior, posterior-legal and viterbi "
                                             "(offline), all, or a comma list; a decoder as names print it "
                                             "(smooth-legal@5) brings its lag.")] = "none",
    lags: Annotated[str, typer.Option(help="Lags in frames at which smooth and lagviterbi decode (frame t decided "
                                           "once t + LAG has arrived), comma-separated.")]
    = stage.LAGS_TEXT,
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
        result = stage.run(workdir, stage.options_from(mln_mode, decode, lags, network_weight))
    summary(result, workdir)


SHOWN = 3  # methods the cross-validation ranks first, named in the summary


def summary(result: stage.ConflateResult, workdir) -> None:
    """conflate's summary, brief: its notes, the network factor's weights once per method (each decoder shares its
    method's), the methods counted by kind, the few the cross-validation ranks first by the criterion export --method
    auto chooses on (every method's figures: --verbose, and the metadata)."""
    from mlnseq_cli.console import verbose
    from mlnseq.choosing.cross_validation import figures_said
    from mlnseq.choosing.folds import describe

    for note in result.notes:
        console.print(f"[yellow]note[/]: {escape(note.text)}")
    weights = weight_lines(result.choices)
    for line in (weights if verbose() else weights[:1]):
        console.print(line, highlight=False)
    cross, order = stage.ranking(result.path)
    counts = kinds(result.methods)
    console.print(f"[green]conflate[/]: wrote {result.path}: {counted(len(result.methods), 'method')} ({counts})"
                  + (f"; cross-validated over {describe(cross['folds'])}" if cross else ""), highlight=False)
    if not cross:
        return
    for candidate in order if verbose() else order[:SHOWN]:
        console.print(f"  {candidate.name:<26} {figures_said(candidate.figures, candidate.score[0])}", highlight=False)
    if not verbose() and len(order) > SHOWN:
        console.print(f"  ... and {len(order) - SHOWN} more (--verbose, or the figures in {result.path.name}'s "
                      "metadata: cross_validation)", highlight=False)


def kinds(methods: list[str]) -> str:
    """The methods counted by kind: ``5 undecoded, 10 online (filter, smooth@5 ...), 8 offline``."""
    from mlnseq.catalog.decoders import Decoder, parse_decoding

    undecoded = [m for m in methods if "+" not in m]
    decodings = [parse_decoding(m.partition("+")[2], "decoding") for m in methods if "+" in m]
    online = [d for d in decodings if not d.decoder.offline]
    offline = [d for d in decodings if d.decoder.offline]
    names = sorted({d.decoder.value for d in online}, key=[x.value for x in Decoder].index)
    lags = sorted({d.lag for d in online if d.lag})
    return ", ".join(part for part in (
        f"{len(undecoded)} undecoded" if undecoded else "",
        f"{len(online)} online ({', '.join(names)}" + (f"; lags {', '.join(map(str, lags))}" if lags else "") + ")"
        if online else "",
        f"{len(offline)} offline ({', '.join(sorted({d.decoder.value for d in offline}))})" if offline else "") if part)


def weight_lines(choices: dict) -> list[str]:
    """The network factor's weight of each decoded network method, once per method (its decoders share it): one line
    of them all, then (--verbose) one per method with how it was set."""
    per_method: dict[str, tuple[float, str, float | None]] = {}
    for name, choice in choices.items():
        per_method.setdefault(name.partition("+")[0], (choice.weight, str(choice.how), choice.accuracy))
    if not per_method:
        return []
    how = {h for _, h, _ in per_method.values()}
    said = "learned on out-of-fold predictions" if how == {"learned"} else "chosen on the validation part" \
        if how == {"validation"} else "set"
    lines = [f"network factor weight ({said}; the weight of the network's log-probabilities in each decoded method): "
             + ", ".join(f"{method} {weight:.3g}" for method, (weight, _, _) in per_method.items())]
    for method, (weight, how_set, accuracy) in per_method.items():
        lines.append(f"  {method}: {weight:.3g} ({how_set}"
                     + (f", validation frame accuracy {accuracy:.1%}" if accuracy is not None else "") + ")")
    return lines
