"""report: the paper's tables and figures from a `make reproduce` run, beside the published numbers.

The run folder is laid out by the Makefile: ``RUNS/DATASET/`` holds a dataset's frames, predicates and
MLN weights, ``RUNS/DATASET/MODE/seed-N/`` one training seed's models (with their per-epoch logs),
predictions and metrics, and ``RUNS/timings.tsv`` one row per stage run (scripts/timed_stage.sh).
Datasets: ``fetch`` and ``desk`` (the paper's splits), ``fetch-rich`` (the richer predicate spec) and
``fetch-fraction-F`` (the first F of the Fetch episodes train: the data-efficiency curve).

The cores below are pure: they turn the loaded run (:class:`Run`) into tables, statements, figures and
Markdown; :func:`run` reads the folder and writes ``REPORT.md`` and the PNGs beside it.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from stages import artifacts
from stages.errors import BadInput
from stages.learn_weights import strongest
from stages.recognizer import METHODS, NETWORKS

# Table III of the paper: segment accuracy (%) at half of each segment.
PAPER_TABLE_III = {
    "fetch": {"lstm": 71, "mln": 50, "priorlayer": 83, "conflation": 77, "combined": 84},
    "desk": {"lstm": 68, "mln": 49, "priorlayer": 71, "conflation": 69, "combined": 72},
}
METHOD_NAMES = {"lstm": "LSTM", "mln": "MLN", "priorlayer": "LSTM + PriorLayer",
                "conflation": "LSTM + Conflation", "combined": "PriorLayer + Conflation (combined)"}
PAPER_DATASETS = ("fetch", "desk")
RICH, FRACTION_PREFIX = "fetch-rich", "fetch-fraction-"
TIMINGS = "timings.tsv"  # written by scripts/timed_stage.sh: started, seconds, stage, arguments
STAGE_ORDER = ("collect", "binarize", "formulas", "learn-weights", "train", "conflate", "eval", "report")
SEED_DIR = re.compile(r"seed-(\d+)")
HELP_FADES_BELOW = 1.0  # points of segment accuracy: a smaller gain of combined over LSTM counts as none
FIGURES = {
    "fig7": "fig7_test_accuracy.png",
    "fig8": "fig8_train_vs_test.png",
    "confusion": "confusion_{dataset}.png",
    "efficiency": "data_efficiency.png",
}


@dataclass(frozen=True)
class ReportOptions:
    """Options of `mlnseq report`."""

    runs: Path = Path("runs")
    out: Path = Path("reports")

    def validate(self) -> None:
        if not Path(self.runs).is_dir():
            raise BadInput(f"--runs {self.runs} is not a folder: run `make reproduce` first "
                           "(or point --runs at its RUNS)")


@dataclass
class Run:
    """Everything the report reads from a run folder, as tables."""

    metrics: pl.DataFrame  # dataset, mode, seed, method, metric, item, value
    logs: pl.DataFrame  # dataset, mode, seed, method, epoch, split, accuracy, loss
    datasets: dict[str, dict[str, Any]]  # name -> frames metadata + n_frames, n_train, spec, classes
    weights: dict[str, pl.DataFrame]  # dataset -> weights.parquet
    settings: dict[str, dict[str, Any]]  # stage -> option -> sorted distinct values used
    timings: pl.DataFrame  # started, seconds, stage, arguments (latest run of each command)
    machine: dict[str, str] = field(default_factory=dict)


# --- numbers ------------------------------------------------------------------------------------------


def seed_stats(metrics: pl.DataFrame, metric: str, by: list[str]) -> pl.DataFrame:
    """Mean, std and count over seeds of one metric (as %, or as is for edit and F1@k), grouped by ``by``."""
    scale = 1.0 if metric in ("edit", "f1@10", "f1@25", "f1@50") else 100.0
    return (
        metrics.filter(pl.col("metric") == metric)
        .group_by(by, maintain_order=True)
        .agg((pl.col("value") * scale).mean().alias("mean"), (pl.col("value") * scale).std().alias("std"),
             pl.col("seed").n_unique().alias("seeds"))
    )


def method_stats(run: Run, metric: str = "segment_accuracy", mode: str = "segment") -> pl.DataFrame:
    """:func:`seed_stats` of one metric in one training mode, per dataset and method."""
    return seed_stats(run.metrics.filter(pl.col("mode") == mode), metric, ["dataset", "method"])


def fmt(mean: float | None, std: float | None = None) -> str:
    """'66.5 ± 1.2' (std absent with one seed)."""
    if mean is None or (isinstance(mean, float) and np.isnan(mean)):
        return "–"
    if std is None or np.isnan(std):
        return f"{mean:.1f}"
    return f"{mean:.1f} ± {std:.1f}"


def lookup(stats: pl.DataFrame, **keys: Any) -> tuple[float | None, float | None]:
    row = stats.filter(pl.all_horizontal(pl.col(k) == v for k, v in keys.items()))
    return (row["mean"][0], row["std"][0]) if row.height else (None, None)


def log_epoch_stats(logs: pl.DataFrame) -> pl.DataFrame:
    """Per dataset, mode, method, split and epoch: accuracy (%) mean and std over seeds."""
    return (
        logs.group_by(["dataset", "mode", "method", "split", "epoch"])
        .agg((pl.col("accuracy") * 100).mean().alias("mean"), (pl.col("accuracy") * 100).std().alias("std"))
        .sort(["dataset", "mode", "method", "split", "epoch"])
    )


def best_test_epoch(logs: pl.DataFrame) -> pl.DataFrame:
    """Per network: test frame accuracy (%) of each seed's best test epoch, mean and std, and the median epoch."""
    per_seed = logs.filter(pl.col("split") == "test").group_by(["dataset", "mode", "method", "seed"]).agg(
        (pl.col("accuracy").max() * 100).alias("best"), pl.col("epoch").sort_by("accuracy").last().alias("epoch"))
    return per_seed.group_by(["dataset", "mode", "method"]).agg(
        pl.col("best").mean().alias("mean"), pl.col("best").std().alias("std"), pl.col("epoch").median())


def table_iii(run: Run) -> list[list[str]]:
    """Paper vs mlnseq, segment mode: segment accuracy at half a segment, last epoch, mean ± std over seeds."""
    stats = method_stats(run)
    frame_stats = method_stats(run, "frame_accuracy")
    best = best_test_epoch(run.logs.filter(pl.col("mode") == "segment"))
    rows = []
    for dataset in _present(run, PAPER_DATASETS):
        for method in METHODS:
            this = (pl.col("dataset") == dataset) & (pl.col("method") == method)
            seeds, best_epoch = stats.filter(this)["seeds"], best.filter(this)["epoch"]
            rows.append([
                dataset, METHOD_NAMES[method], str(PAPER_TABLE_III[dataset][method]),
                fmt(*lookup(stats, dataset=dataset, method=method)), str(seeds[0]) if seeds.len() else "0",
                fmt(*lookup(frame_stats, dataset=dataset, method=method)),
                f"{fmt(*lookup(best, dataset=dataset, method=method))} (epoch ~{best_epoch[0]:.0f})"
                if best_epoch.len() else "–",
            ])
    return rows


def per_class_table(run: Run, dataset: str, methods: tuple[str, ...] = ("lstm", "mln", "combined")) -> list[list[str]]:
    """Table IV: segment accuracy per true class (%), mean ± std over seeds, segment mode."""
    stats = seed_stats(run.metrics.filter((pl.col("mode") == "segment") & (pl.col("dataset") == dataset)),
                       "class_accuracy", ["method", "item"])
    return [[name, *(fmt(*lookup(stats, method=m, item=name)) for m in methods)]
            for name in run.datasets[dataset]["classes"]]


def confusion_matrix(run: Run, dataset: str, method: str) -> np.ndarray:
    """Segment confusion counts (true rows, predicted columns), summed over seeds, segment mode."""
    classes = run.datasets[dataset]["classes"]
    counts = run.metrics.filter((pl.col("dataset") == dataset) & (pl.col("mode") == "segment")
                                & (pl.col("method") == method) & (pl.col("metric") == "confusion"))
    matrix = np.zeros((len(classes), len(classes)))
    for item, value in counts.select("item", "value").iter_rows():
        true, predicted = item.split(" -> ")
        matrix[classes.index(true), classes.index(predicted)] += value
    return matrix


def stream_table(run: Run) -> list[list[str]]:
    """Stream mode (no segment boundaries at test): segment accuracy, edit and F1@k, mean ± std."""
    columns = ("segment_accuracy", "frame_accuracy", "edit", "f1@10", "f1@25", "f1@50")
    stats = {c: method_stats(run, c, mode="stream") for c in columns}
    return [[dataset, METHOD_NAMES[method], *(fmt(*lookup(stats[c], dataset=dataset, method=method)) for c in columns)]
            for dataset in _present(run, PAPER_DATASETS) for method in METHODS
            if lookup(stats["segment_accuracy"], dataset=dataset, method=method)[0] is not None]


def rich_spec_table(run: Run) -> list[list[str]]:
    """Fetch, segment mode: the paper's predicate spec against the richer one, per method."""
    stats = method_stats(run)
    return [[METHOD_NAMES[m], *(fmt(*lookup(stats, dataset=d, method=m)) for d in ("fetch", RICH))] for m in METHODS]


def efficiency_points(run: Run) -> pl.DataFrame:
    """Per training size (share of the Fetch frames that train) and method: segment accuracy mean, std."""
    names = [d for d in run.datasets if d.startswith(FRACTION_PREFIX)] + _present(run, ("fetch",))
    shares = pl.DataFrame({"dataset": names,
                           "train_share": [run.datasets[d]["n_train"] / run.datasets[d]["n_frames"] for d in names],
                           "train_frames": [run.datasets[d]["n_train"] for d in names]},
                          schema={"dataset": pl.String, "train_share": pl.Float64, "train_frames": pl.Int64})
    return method_stats(run).join(shares, on="dataset").sort(["method", "train_share"])


def efficiency_table(points: pl.DataFrame) -> list[list[str]]:
    """One row per training size: LSTM, MLN and combined segment accuracy and the combined model's gain."""
    rows = []
    for (share, frames), group in points.sort("train_share").group_by(["train_share", "train_frames"],
                                                                       maintain_order=True):
        by = {r["method"]: r for r in group.iter_rows(named=True)}
        gain = _gain(by)
        rows.append([f"{share:.1%}", f"{frames:,}",
                     *(fmt(by[m]["mean"], by[m]["std"]) if m in by else "–" for m in ("lstm", "mln", "combined")),
                     "–" if gain is None else f"{gain:+.1f}"])
    return rows


def _gain(by_method: dict[str, dict[str, Any]]) -> float | None:
    if "lstm" in by_method and "combined" in by_method:
        return by_method["combined"]["mean"] - by_method["lstm"]["mean"]
    return None


def weights_table(run: Run, dataset: str, per_class: int = 3) -> list[list[str]]:
    """Table II style: the strongest learned formulas of each class."""
    classes = run.datasets[dataset]["classes"]
    rows = []
    for row in strongest(run.weights[dataset], per_class).iter_rows(named=True):
        name = classes[int(row["class"][1:])] if re.fullmatch(r"C\d+", row["class"] or "") else row["class"]
        weight = "hard" if row["hard"] else f"{row['weight']:.3f}"
        rows.append([name, weight, f"`{row['formula']}`"])
    return rows


def datasets_table(run: Run) -> list[list[str]]:
    """What each dataset folder holds: source, frames, training frames, features, predicate spec, epochs."""
    rows = []
    for name, d in sorted(run.datasets.items()):
        options = d.get("options", {})
        source = d.get("source", "?") + (f", {options['episodes']} episodes, seed {options['seed']}"
                                         if d.get("source") == "fetch" else "")
        epochs = run.logs.filter(pl.col("dataset") == name)["epoch"].max()
        rows.append([name, source, f"{d['n_frames']:,}", f"{d['n_train']:,}", str(len(d["features"])), d["spec"],
                     "–" if epochs is None else str(epochs)])
    return rows


def timings_table(timings: pl.DataFrame) -> list[list[str]]:
    """Per stage: runs, total, mean and longest seconds (latest run of each command)."""
    if timings.height == 0:
        return []
    per_stage = timings.group_by("stage").agg(
        pl.len().alias("runs"), pl.col("seconds").sum().alias("total"), pl.col("seconds").mean().alias("mean"),
        pl.col("seconds").max().alias("longest"))
    order = {stage: i for i, stage in enumerate(STAGE_ORDER)}
    rows = sorted(per_stage.iter_rows(named=True), key=lambda r: order.get(r["stage"], len(order)))
    return [[r["stage"], str(r["runs"]), f"{r['total']:.0f}", f"{r['mean']:.1f}", f"{r['longest']:.1f}"] for r in rows]


def wall_seconds(timings: pl.DataFrame) -> float | None:
    """From the first stage's start to the last stage's end."""
    if timings.height == 0:
        return None
    started = timings["started"].str.to_datetime("%Y-%m-%dT%H:%M:%S").dt.epoch("s").to_numpy()
    return float((started + timings["seconds"].to_numpy()).max() - started.min())


# --- what the paper claims, checked on this run --------------------------------------------------------


def claims(run: Run) -> list[str]:
    """Plain statements, computed from the run, on whether each claim of the paper holds here."""
    stats = method_stats(run)
    lines = []
    for dataset in _present(run, PAPER_DATASETS):
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
        lines.append(f"{dataset}: the MLN alone is the weakest: {verdict} ({fmt(mean['mln'])}).")
    lines += regularisation_claims(run)
    return lines


def regularisation_claims(run: Run) -> list[str]:
    """Fig. 8's claim: PriorLayer regularises (a smaller train - test gap than the LSTM at the last epoch)."""
    last = (run.logs.filter(pl.col("mode") == "segment")
            .filter(pl.col("epoch") == pl.col("epoch").max().over(["dataset", "seed", "method"]))
            .group_by(["dataset", "method", "split"])
            .agg((pl.col("accuracy") * 100).mean().alias("mean"), (pl.col("accuracy") * 100).std().alias("std")))
    lines = []
    for dataset in _present(run, PAPER_DATASETS):
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
        gain = _gain({r["method"]: r for r in group.iter_rows(named=True)})
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


def _present(run: Run, names: tuple[str, ...]) -> list[str]:
    have = set(run.metrics["dataset"].unique().to_list())
    return [n for n in names if n in have]


# --- figures ------------------------------------------------------------------------------------------


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _curve(dataset: str, method: str, split: str) -> pl.Expr:
    return (pl.col("dataset") == dataset) & (pl.col("method") == method) & (pl.col("split") == split)


COLOURS = {"lstm": "tab:blue", "mln": "tab:gray", "priorlayer": "tab:orange", "conflation": "tab:green",
           "combined": "tab:red"}


def figure_test_curves(run: Run):
    """Fig. 7: test frame accuracy per epoch (networks), mln flat, conflation/combined at the last epoch."""
    plt = _pyplot()
    datasets = _present(run, PAPER_DATASETS)
    curves = log_epoch_stats(run.logs.filter(pl.col("mode") == "segment"))
    frame = method_stats(run, "frame_accuracy")
    fig, axes = plt.subplots(1, max(len(datasets), 1), figsize=(6 * max(len(datasets), 1), 4.2), squeeze=False)
    for ax, dataset in zip(axes[0], datasets):
        last_epoch = 1
        for method in NETWORKS:
            c = curves.filter(_curve(dataset, method, "test"))
            if c.height:
                x, y, s = c["epoch"].to_numpy(), c["mean"].to_numpy(), np.nan_to_num(c["std"].to_numpy())
                ax.plot(x, y, color=COLOURS[method], label=METHOD_NAMES[method])
                ax.fill_between(x, y - s, y + s, color=COLOURS[method], alpha=0.2)
                last_epoch = int(x.max())
        mean, _ = lookup(frame, dataset=dataset, method="mln")
        if mean is not None:
            ax.axhline(mean, color=COLOURS["mln"], linestyle="--", label="MLN (no training epochs)")
        for method in ("conflation", "combined"):
            mean, std = lookup(frame, dataset=dataset, method=method)
            if mean is not None:
                ax.errorbar([last_epoch], [mean], yerr=[0 if std is None or np.isnan(std) else std], fmt="o",
                            color=COLOURS[method], capsize=4, label=f"{METHOD_NAMES[method]} (last epoch)")
        ax.set(title=f"{dataset}: test accuracy per epoch", xlabel="epoch", ylabel="test frame accuracy (%)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return fig


def figure_train_vs_test(run: Run):
    """Fig. 8: train and test frame accuracy per epoch of the LSTM and PriorLayer (mean over seeds)."""
    plt = _pyplot()
    datasets = _present(run, PAPER_DATASETS)
    curves = log_epoch_stats(run.logs.filter(pl.col("mode") == "segment"))
    fig, axes = plt.subplots(1, max(len(datasets), 1), figsize=(6 * max(len(datasets), 1), 4.2), squeeze=False)
    for ax, dataset in zip(axes[0], datasets):
        for method in NETWORKS:
            for split, style in (("train", "-"), ("test", "--")):
                c = curves.filter(_curve(dataset, method, split))
                if c.height:
                    ax.plot(c["epoch"], c["mean"], style, color=COLOURS[method],
                            label=f"{METHOD_NAMES[method]}, {split}")
        ax.set(title=f"{dataset}: train vs test", xlabel="epoch", ylabel="frame accuracy (%)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


def figure_confusion(run: Run, dataset: str, methods: tuple[str, ...] = ("lstm", "combined")):
    """Row-normalised segment confusion matrices, summed over seeds."""
    plt = _pyplot()
    classes = run.datasets[dataset]["classes"]
    size = 2.5 + 0.7 * len(classes)
    fig, axes = plt.subplots(1, len(methods), figsize=(size * len(methods), size), squeeze=False)
    for ax, method in zip(axes[0], methods):
        counts = confusion_matrix(run, dataset, method)
        rates = counts / np.maximum(counts.sum(1, keepdims=True), 1)
        ax.imshow(rates, cmap="Blues", vmin=0, vmax=1)
        for i in range(len(classes)):
            for j in range(len(classes)):
                ax.text(j, i, f"{rates[i, j]:.0%}", ha="center", va="center", fontsize=7,
                        color="white" if rates[i, j] > 0.5 else "black")
        short = [c.split(" ")[0] if dataset == "desk" else c for c in classes]
        ax.set_xticks(range(len(classes)), short, rotation=45, ha="right")
        ax.set_yticks(range(len(classes)), short)
        ax.set(title=f"{dataset}: {METHOD_NAMES[method]}", xlabel="predicted", ylabel="true")
    fig.tight_layout()
    return fig


def figure_efficiency(points: pl.DataFrame):
    """Segment accuracy of the LSTM, MLN and combined model as the Fetch training split grows."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for method in ("lstm", "mln", "combined"):
        p = points.filter(pl.col("method") == method)
        if p.height:
            ax.errorbar(p["train_share"] * 100, p["mean"], yerr=np.nan_to_num(p["std"].to_numpy()), marker="o",
                        capsize=3, color=COLOURS[method], label=METHOD_NAMES[method],
                        linestyle="--" if method == "mln" else "-")
    ax.set_xscale("log")
    ax.set(title="Fetch: accuracy as the training split grows",
           xlabel="frames in the training split (% of all, log scale)",
           ylabel="test segment accuracy (%)")
    ax.grid(alpha=0.3, which="both")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no data-efficiency runs in this run folder", transform=ax.transAxes, ha="center")
    fig.tight_layout()
    return fig


# --- Markdown -----------------------------------------------------------------------------------------


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    if not rows:
        return "_nothing to show: this run has no such results._\n"
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def render(run: Run, figures: dict[str, str]) -> str:
    """REPORT.md: every section, its numbers from ``run``; ``figures`` maps a figure key to its file name."""
    points = efficiency_points(run)
    datasets = _present(run, PAPER_DATASETS)
    missing = [d for d in PAPER_DATASETS if d not in datasets]
    wall = wall_seconds(run.timings)
    out = ["# mlnseq: reproduction of Rahman et al., RO-MAN 2021\n",
           "Every number below is read from the artifacts of this run "
           f"({', '.join(sorted(run.datasets))}); nothing is copied from the paper except its own columns.\n"]
    if missing:
        out.append(f"**Not run:** {', '.join(missing)} (its data was not found when `make reproduce` ran).\n")

    out.append("## Table III: segment accuracy, paper vs mlnseq\n")
    out.append("Segment recognised at half of its frames (the paper's metric), `segment` mode, **last epoch, "
               "mean ± std over seeds** (%). The last column is the best test epoch's frame accuracy per seed, "
               "**optimistic**: it selects on the test split, as the published numbers do.\n")
    out.append(markdown_table(["dataset", "method", "paper", "mlnseq (last epoch)", "seeds",
                               "frame accuracy (last epoch)", "best test epoch, as in the paper (optimistic)"],
                              table_iii(run)))
    out.append("### Do the paper's claims hold here?\n")
    out.append("\n".join(f"- {line}" for line in claims(run)) + "\n")

    out.append("## Table IV: per-class segment accuracy\n")
    for dataset in datasets:
        out.append(f"**{dataset}** (%, mean ± std over seeds)\n")
        out.append(markdown_table(["class", "LSTM", "MLN", "combined"], per_class_table(run, dataset)))

    out.append("## Fig. 7: test accuracy per epoch\n")
    out.append(f"![Fig. 7]({figures['fig7']})\n")
    out.append("Drawn: the LSTM's and PriorLayer's test **frame** accuracy after every epoch (mean, band ± std over "
               "seeds), from the training logs. The MLN has no epochs (flat line). Conflation and the combined "
               "model are computed from the final networks only, so they appear as one point at the last epoch; "
               "their per-epoch curves would need every epoch's network, which is not kept.\n")
    out.append("## Fig. 8: train vs test accuracy per epoch\n")
    out.append(f"![Fig. 8]({figures['fig8']})\n")
    out.append("PriorLayer's regularisation claim, checked on these curves, is listed under Table III.\n")

    out.append("## Confusion matrices (LSTM and combined)\n")
    for dataset in datasets:
        out.append(f"![confusion {dataset}]({figures['confusion'].format(dataset=dataset)})\n")
    out.append("Segments of the test split, counts summed over seeds, each row normalised to its true class.\n")

    out.append("## Data efficiency: where do the logic constraints stop helping?\n")
    out.append(f"![data efficiency]({figures['efficiency']})\n")
    out.append("The same Fetch episodes (collection seed fixed); the first share of them trains, the MLN learns its "
               "weights on that part only, the rest is the test split"
               + (f"; the smallest point is the paper's split ({run.datasets['fetch']['n_train']:,} frames, "
                  "folder `fetch`)" if "fetch" in run.datasets else "")
               + ". Segment accuracy (%), mean ± std over training seeds.\n")
    out.append(markdown_table(["training share", "training frames", "LSTM", "MLN", "combined", "combined − LSTM"],
                              efficiency_table(points)))
    out.append(efficiency_claim(points) + "\n")

    out.append("## Learned weights: strongest formulas per class (Table II style)\n")
    for dataset in datasets:
        out.append(f"**{dataset}** ({run.datasets[dataset]['spec']})\n")
        out.append(markdown_table(["class", "weight", "formula"], weights_table(run, dataset)))

    out.append("## Fetch: richer predicate spec vs the paper's\n")
    rich = run.datasets.get(RICH)
    spec = f" (`{rich['spec']}`)" if rich else ""
    out.append(f"Segment mode, segment accuracy (%), mean ± std over seeds. The rich spec{spec} needs the goal "
               "position, so its frames carry the 6 goal values too: its LSTM row also sees them; the MLN row "
               "isolates what the knowledge itself buys.\n")
    out.append(markdown_table(["method", "paper spec", "rich spec"], rich_spec_table(run) if rich else []))
    verdict = rich_spec_claim(run)
    if verdict:
        out.append(f"Rich minus paper spec: {verdict}.\n")

    out.append("## Stream mode: no segment boundaries at test\n")
    out.append("Networks trained on fixed windows and run over whole episodes (`--mode stream`); segment "
               "accuracy (%), frame accuracy (%), segmental edit score and F1@{10,25,50} (Lea et al.), mean ± std.\n")
    out.append(markdown_table(["dataset", "method", "segment acc.", "frame acc.", "edit", "F1@10", "F1@25", "F1@50"],
                              stream_table(run)))

    out.append("## Timings and machine\n")
    total = f"{wall:.0f} s from the first stage's start to the last stage's end" if wall is not None else "not recorded"
    out.append(f"Stage time (seconds, the latest run of each command; two jobs at a time): {total}.\n")
    out.append(markdown_table(["stage", "runs", "total s", "mean s", "longest s"], timings_table(run.timings)))
    out.append(markdown_table(["", ""], [[k, v] for k, v in run.machine.items()]))

    out.append("## Hyper-parameters used\n")
    out.append("Read from the artifacts' metadata: each dataset folder, then every stage's options (several values "
               "where runs differ).\n")
    out.append(markdown_table(["dataset folder", "source", "frames", "training frames", "features", "predicate spec",
                               "epochs"],
                              datasets_table(run)))
    out.append(markdown_table(["stage", "option", "values"],
                              [[stage, name, ", ".join(map(str, values))]
                               for stage, options in run.settings.items() for name, values in options.items()]
                              + [["train", "seeds", ", ".join(map(str, sorted(run.metrics["seed"].unique())))]]))

    out.append("## Differences from the paper\n")
    out.append("\n".join(f"- {line}" for line in differences(run)) + "\n")
    return "\n".join(out)


def differences(run: Run) -> list[str]:
    lines = [
        "Fetch data come from our own scripted controller on Gymnasium-Robotics v4 (FetchPickAndPlace-v4, "
        "MuJoCo), not from the authors' Gym v1 demonstrations, whose test kinematics were not released; the "
        "split is the paper's (first 126 frames train).",
        "DESK test frames carry only the arm distance and the two gripper openings, so on DESK the recurrent "
        "models see those three channels, not the 14 kinematics of the training file.",
        "Headline numbers are the last epoch's, mean ± std over training seeds; no epoch is chosen on the test "
        "split. The published Table III numbers match single best epochs of the authors' test curves (there "
        "was no validation split); the optimistic column above shows what that selection does here.",
        "The figures' per-epoch curves are frame accuracy; Table III is segment accuracy at half a segment.",
    ]
    fetch = run.datasets.get("fetch")
    if fetch is not None:
        lines.append(f"Fetch: {fetch['n_frames']:,} frames ({fetch['n_train']:,} train) from "
                     f"{fetch.get('env_id', 'the simulator')}; episodes that succeeded: "
                     f"{np.mean(fetch.get('episode_success', [np.nan])):.1%}.")
    return lines


# --- the stage ----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReportResult:
    path: Path
    figures: list[Path]
    datasets: list[str]
    n_seed_runs: int


def load_run(runs: Path) -> Run:
    """Read every dataset folder and seed workdir of a run (see the module docstring)."""
    metrics, logs, settings = [], [], {}
    datasets, weights = {}, {}
    for frames_path in sorted(runs.glob(f"*/{artifacts.FRAMES}")):
        folder = frames_path.parent
        _, meta = artifacts.read_table(frames_path, "frames")
        frames = pl.read_parquet(frames_path, columns=["split"])
        predicates = folder / artifacts.PREDICATES
        predicates_meta = artifacts.read_metadata(predicates) if predicates.exists() else {}
        datasets[folder.name] = {**meta, "n_frames": frames.height,
                                 "n_train": int((frames["split"] == "train").sum()),
                                 "spec": predicates_meta.get("options", {}).get("spec", "–")}
        _note(settings, "binarize", predicates_meta.get("options", {}))
        if (folder / artifacts.WEIGHTS).exists():
            weights[folder.name], weights_meta = artifacts.read_table(folder / artifacts.WEIGHTS, "weights")
            _note(settings, "learn-weights", {"engine": weights_meta.get("engine")})
        for metrics_path in sorted(folder.glob(f"*/seed-*/{artifacts.METRICS}")):
            workdir = metrics_path.parent
            keys = {"dataset": folder.name, "mode": workdir.parent.name,
                    "seed": int(SEED_DIR.fullmatch(workdir.name).group(1))}
            table, metrics_meta = artifacts.read_table(metrics_path, "metrics")
            metrics.append(table.with_columns(**{k: pl.lit(v) for k, v in keys.items()}))
            _note(settings, "eval", metrics_meta.get("options", {}))
            predictions_meta = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")
            _note(settings, "conflate", {"mln_mode": predictions_meta.get("mln_mode")})
            for method in NETWORKS:
                log_path = artifacts.train_log_path(workdir, method)
                if log_path.exists():
                    log, log_meta = artifacts.read_table(log_path, "train_log")
                    logs.append(log.with_columns(method=pl.lit(method), **{k: pl.lit(v) for k, v in keys.items()}))
                    _note(settings, "train", {**log_meta.get("options", {}), "kept_epoch": log_meta.get("kept_epoch")},
                          skip=("seed", "method"))
    if not metrics:
        raise BadInput(f"no results in {runs}: expected {runs}/DATASET/MODE/seed-N/{artifacts.METRICS}; "
                       "run `make reproduce` first")
    return Run(
        metrics=pl.concat(metrics, how="diagonal_relaxed"),
        logs=pl.concat(logs, how="diagonal_relaxed") if logs else pl.DataFrame(
            schema={"epoch": pl.Int32, "split": pl.String, "accuracy": pl.Float64, "loss": pl.Float64,
                    "method": pl.String, "dataset": pl.String, "mode": pl.String, "seed": pl.Int64}),
        datasets=datasets, weights=weights,
        settings={stage: {k: sorted(v, key=str) for k, v in options.items()} for stage, options in settings.items()},
        timings=read_timings(runs / TIMINGS), machine=machine(),
    )


def _note(settings: dict[str, dict[str, set]], stage: str, options: dict[str, Any], skip: tuple[str, ...] = ()) -> None:
    for name, value in options.items():
        if name not in skip and value is not None:
            settings.setdefault(stage, {}).setdefault(name, set()).add(value if np.isscalar(value) else str(value))


def read_timings(path: Path) -> pl.DataFrame:
    """timings.tsv, keeping each command's latest run."""
    schema = {"started": pl.String, "seconds": pl.Float64, "stage": pl.String, "arguments": pl.String}
    if not path.exists():
        return pl.DataFrame(schema=schema)
    table = pl.read_csv(path, separator="\t", has_header=False, new_columns=list(schema), schema_overrides=schema,
                        quote_char=None)
    return table.group_by(["stage", "arguments"], maintain_order=True).last().select(list(schema))


def machine() -> dict[str, str]:
    """The machine this report runs on (the run's own, as `make reproduce` writes it last)."""
    cpu = platform.processor() or ""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        found = re.search(r"^model name\s*:\s*(.+)$", cpuinfo.read_text(), re.MULTILINE)
        cpu = found.group(1) if found else cpu
    versions = {}
    for package in ("torch", "numpy", "polars", "mujoco", "gymnasium-robotics", "mlnseq"):
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = "not installed"
    return {"CPU": cpu or "unknown", "cores": str(os.cpu_count()), "OS": platform.platform(),
            "Python": platform.python_version(), **versions}


def run(options: ReportOptions) -> ReportResult:
    """Read the run folder ``options.runs``; write ``options.out/REPORT.md`` and its PNG figures."""
    options.validate()
    loaded = load_run(Path(options.runs))
    out = Path(options.out)
    drawn = {FIGURES["fig7"]: figure_test_curves(loaded), FIGURES["fig8"]: figure_train_vs_test(loaded),
             FIGURES["efficiency"]: figure_efficiency(efficiency_points(loaded))}
    for dataset in _present(loaded, PAPER_DATASETS):
        drawn[FIGURES["confusion"].format(dataset=dataset)] = figure_confusion(loaded, dataset)
    written = []
    plt = _pyplot()
    for name, figure in drawn.items():
        with artifacts.atomic_path(out / name) as tmp:
            figure.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
        plt.close(figure)
        written.append(out / name)
    path = artifacts.write_text(out / "REPORT.md", render(loaded, FIGURES))
    n_seed_runs = loaded.metrics.select("dataset", "mode", "seed").unique().height
    return ReportResult(path, written, sorted(loaded.datasets), n_seed_runs)
