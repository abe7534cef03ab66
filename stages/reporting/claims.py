"""What the paper claims, checked on this run: plain statements computed from the numbers."""

from __future__ import annotations

import numpy as np
import polars as pl

from mlnseq.catalog.methods import METHODS
from mlnseq.reporting.loading import NETWORKS, PAPER_DATASETS, RICH, Run, present
from mlnseq.reporting.tables import (
    METHOD_NAMES, PAPER_TABLE_III, combined_gain, deploy_choices, fmt, lookup, method_name, method_stats,
)

HELP_FADES_BELOW = 1.0  # points of segment accuracy: a smaller gain of combined over LSTM counts as none
# The targets, stream mode, on test (%, edit as is): the online and the offline choice (made by cross-validation
# on the training split), and the stream LSTM (trained on the whole training split).
SEQUENCE_TARGETS = {"desk": {"online": {"segment_accuracy": 74.0, "frame_accuracy": 64.0},
                             "offline": {"edit": 90.0, "segment_accuracy": 70.0},
                             "lstm": {"segment_accuracy": 65.0}},
                    "fetch": {"online": {"segment_accuracy": 85.0, "frame_accuracy": 70.0},
                              "offline": {"edit": 90.0}}}
METRIC_NAMES = {"segment_accuracy": "segment accuracy", "frame_accuracy": "frame accuracy", "edit": "edit",
                "f1@50": "F1@50"}


def claims(run: Run) -> list[str]:
    """Plain statements, computed from the run, on whether each claim of the paper holds here."""
    stats = method_stats(run)
    lines = []
    for dataset in present(run, PAPER_DATASETS):
        mean = {m: lookup(stats, dataset=dataset, method=m)[0] for m in METHODS}
        if any(v is None for v in mean.values()):
            continue
        for better, worse, claim in (("priorlayer", "lstm", "PriorLayer improves on the LSTM"),
                                     ("conflation", "lstm", "Conflation improves on the LSTM"),
                                     ("combined", "lstm", "the combined model improves on the LSTM")):
            diff = mean[better] - mean[worse]
            paper = PAPER_TABLE_III[dataset][better] - PAPER_TABLE_III[dataset][worse]
            verdict = "holds" if diff > 0 else "does not hold"
            spread = max(np.nan_to_num(lookup(stats, dataset=dataset, method=m)[1] or 0.0) for m in (better, worse))
            noise = f" (within the seed-to-seed spread, std up to {spread:.1f})" if abs(diff) < spread else ""
            lines.append(f"{dataset}: {claim} (paper {paper:+d} points): {verdict} here, {diff:+.1f} points{noise}.")
        best = max(mean, key=lambda m: mean[m])
        verdict = "holds" if best == "combined" else f"does not hold: {METHOD_NAMES[best]} is best here"
        lines.append(f"{dataset}: the combined model is the best of the five: {verdict} "
                     f"({fmt(mean[best])} vs combined {fmt(mean['combined'])}).")
        weakest = min(mean, key=lambda m: mean[m])
        verdict = "holds" if weakest == "mln" else f"does not hold: {METHOD_NAMES[weakest]} is weakest here"
        figures = f"{fmt(mean['mln'])}" if weakest == "mln" else f"{fmt(mean[weakest])} vs MLN {fmt(mean['mln'])}"
        lines.append(f"{dataset}: the MLN alone is the weakest: {verdict} ({figures}).")
    lines += regularisation_claims(run)
    return lines


def regularisation_claims(run: Run) -> list[str]:
    """Fig. 8's claim: PriorLayer regularises (a smaller train - test gap than the LSTM at the last epoch)."""
    last = (run.logs.filter(pl.col("mode") == "segment")
            .filter(pl.col("epoch") == pl.col("epoch").max().over(["dataset", "seed", "method"]))
            .group_by(["dataset", "method", "split"])
            .agg((pl.col("accuracy") * 100).mean().alias("mean"), (pl.col("accuracy") * 100).std().alias("std")))
    lines = []
    for dataset in present(run, PAPER_DATASETS):
        gap = {}
        for method in NETWORKS:
            train, test = (lookup(last, dataset=dataset, method=method, split=s)[0] for s in ("train", "test"))
            if train is not None and test is not None:
                gap[method] = train - test
        if len(gap) == 2:
            verdict = "holds" if gap["priorlayer"] < gap["lstm"] else "does not hold"
            lines.append(f"{dataset}: PriorLayer narrows the train - test gap (Fig. 8): {verdict} here "
                         f"(last-epoch frame accuracy gap: LSTM {gap['lstm']:.1f}, "
                         f"PriorLayer {gap['priorlayer']:.1f} points).")
    return lines


def efficiency_claim(points: pl.DataFrame) -> str:
    """Where, as the training split grows, the combined model stops beating the LSTM."""
    gains = []
    for (share,), group in points.group_by(["train_share"], maintain_order=True):
        gain = combined_gain({r["method"]: r for r in group.iter_rows(named=True)})
        if gain is not None:
            gains.append((share, gain))
    if not gains:
        return "No data-efficiency runs with both the LSTM and the combined model were found."
    gains.sort()
    text = ", ".join(f"{share:.1%}: {gain:+.1f}" for share, gain in gains)
    helps = [gain >= HELP_FADES_BELOW for _, gain in gains]
    if helps[-1]:
        verdict = (f"the combined model still adds at least {HELP_FADES_BELOW:g} point at the largest training "
                   f"split run here ({gains[-1][0]:.1%})")
    elif not any(helps):
        verdict = f"the combined model adds less than {HELP_FADES_BELOW:g} point at every size run here"
    else:
        last_help = max(i for i, h in enumerate(helps) if h)
        verdict = (f"the gain stays below {HELP_FADES_BELOW:g} point from {gains[last_help + 1][0]:.1%} of the "
                   f"frames in the training split on (last gain of {HELP_FADES_BELOW:g} point or more at "
                   f"{gains[last_help][0]:.1%})")
    return f"Combined minus LSTM, segment accuracy points, by share of frames that train: {text}; {verdict}."


def rich_spec_claim(run: Run) -> str | None:
    stats = method_stats(run)
    lines = []
    for method in ("mln", "combined"):
        paper, rich = lookup(stats, dataset="fetch", method=method)[0], lookup(stats, dataset=RICH, method=method)[0]
        if paper is not None and rich is not None:
            lines.append(f"{METHOD_NAMES[method]} {fmt(paper)} -> {fmt(rich)} ({rich - paper:+.1f} points)")
    return "; ".join(lines) if lines else None



def _met(value: float | None, target: float, at_most: bool = False) -> str:
    if value is None:
        return "not run"
    return "met" if (value <= target if at_most else value >= target) else "**missed**"


def _named(candidate: dict) -> str:
    return f"{method_name(candidate['method'])}, {candidate['variant']}"


def deploy_sentence(run: Run, dataset: str) -> str | None:
    """Which decoded method to deploy on ``dataset``, online and offline, as chosen by cross-validation."""
    choices = deploy_choices(run, dataset)
    if "filter" not in choices or "viterbi" not in choices:
        return None
    online, offline = choices["filter"], choices["viterbi"]
    ties = "; ".join(f"the {kind} choice is tied with {', '.join(_named(t) for t in c['ties'])}"
                     for kind, c in (("online", online), ("offline", offline)) if c["ties"])
    return (f"{dataset}: deploy **{_named(online)}** (`{online['folder']}`) where frames must be recognised as they "
            f"arrive, and **{_named(offline)}** (`{offline['folder']}`) where a whole recording is labelled after "
            f"the fact (cross-validated segment accuracy {fmt(*online['cv']['segment_accuracy'])} and "
            f"{fmt(*offline['cv']['segment_accuracy'])}, edit {fmt(*offline['cv']['edit'])}; on test, segment "
            f"accuracy {fmt(*online['segment_accuracy'])} and {fmt(*offline['segment_accuracy'])})"
            + (f"; {ties}." if ties else "."))


def target_checks(run: Run) -> list[str]:
    """The targets on this run, stream mode, test split: the online and offline methods chosen by cross-validation
    and the stream LSTM; beside them, marked optimistic, each metric's best decoded method on test."""
    from mlnseq.reporting.tables import sequence_stats

    stats = sequence_stats(run)
    lines = []
    for dataset, targets in SEQUENCE_TARGETS.items():
        choices = deploy_choices(run, dataset)
        if "filter" not in choices or "viterbi" not in choices:
            continue
        for use, decode in (("online", "filter"), ("offline", "viterbi")):
            chosen = choices[decode]
            checks = ", ".join(f"{METRIC_NAMES[m]} {fmt(*chosen[m])} (target ≥ {t:g}: {_met(chosen[m][0], t)})"
                               for m, t in targets[use].items())
            lines.append(f"{dataset}, {use} choice ({_named(chosen)}, by cross-validation): {checks}.")
        for m, t in targets.get("lstm", {}).items():
            value = lookup(stats[m], dataset=dataset, method="lstm")
            lines.append(f"{dataset}, the stream LSTM (refit on the whole training split): {METRIC_NAMES[m]} "
                         f"{fmt(*value)} (target ≥ {t:g}: {_met(value[0], t)}).")
        optimistic = "; ".join(
            f"{METRIC_NAMES[m]} {fmt(*best[m])} ({_named(best)})"
            for m in SEQUENCE_METRICS_SHOWN for best in [choices["best_on_test"][m]])
        lines.append(f"{dataset}, best on test (**optimistic**: each metric's best decoded method, chosen on the test "
                     f"split itself, for comparison only): {optimistic}.")
    return lines


SEQUENCE_METRICS_SHOWN = ("segment_accuracy", "frame_accuracy", "edit")
