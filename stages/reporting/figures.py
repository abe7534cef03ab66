"""The report's figures (matplotlib, imported when the first figure is drawn)."""

from __future__ import annotations

import numpy as np
import polars as pl

from mlnseq.reporting.loading import NETWORKS, PAPER_DATASETS, Run, present
from mlnseq.reporting.tables import METHOD_NAMES, confusion_matrix, log_epoch_stats, lookup, method_stats
from mlnseq.timeline.sequences import run_starts

FIGURES = {  # figure key -> its file name beside REPORT.md
    "fig7": "fig7_test_accuracy.png",
    "fig8": "fig8_train_vs_test.png",
    "confusion": "confusion_{dataset}.png",
    "efficiency": "data_efficiency.png",
    "timeline": "timeline_{dataset}.png",
}


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend."""
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
    plt = pyplot()
    datasets = present(run, PAPER_DATASETS)
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
    plt = pyplot()
    datasets = present(run, PAPER_DATASETS)
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
    plt = pyplot()
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
    plt = pyplot()
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



def figure_timeline(rows: pl.DataFrame, classes: list[str], title: str):
    """One coloured bar per sequence (true labels, then each method's predictions) over the frames of ``rows``
    (a ``frame`` column, then one column of class indices per bar, top to bottom)."""
    plt = pyplot()
    from matplotlib.patches import Patch

    names = [c for c in rows.columns if c != "frame"]
    frames = rows["frame"].to_numpy()
    colours = plt.get_cmap("tab10").colors
    fig, ax = plt.subplots(figsize=(12, 0.65 * len(names) + 1.8))
    for i, name in enumerate(names):
        values = rows[name].to_numpy()
        starts = run_starts(values)
        stops = np.r_[starts[1:], len(values)]
        for start, stop in zip(starts, stops):
            ax.broken_barh([(frames[start], frames[stop - 1] - frames[start] + 1)], (i - 0.4, 0.8),
                           facecolors=colours[int(values[start]) % len(colours)])
    ax.set_yticks(range(len(names)), names)
    ax.invert_yaxis()
    ax.set_xlim(frames[0], frames[-1] + 1)
    ax.set_title(title, fontsize=11)
    ax.set_xlabel("frame of the episode", labelpad=2)
    ax.legend(handles=[Patch(color=colours[k % len(colours)], label=c) for k, c in enumerate(classes)],
              loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=min(len(classes), 4), fontsize=9, frameon=False)
    fig.tight_layout()
    return fig
