"""report: the paper's tables and figures from a `make reproduce` run, beside the published numbers.

The run folder is laid out by the Makefile: ``RUNS/DATASET/`` holds a dataset's frames, predicates and
MLN weights, ``RUNS/DATASET/MODE/seed-N/`` one training seed's models (with their per-epoch logs),
predictions and metrics, and ``RUNS/timings.tsv`` one row per stage run (scripts/timed_stage.sh).
Datasets: ``fetch`` and ``desk`` (the paper's splits), ``fetch-rich`` (the richer predicate spec),
``fetch-fraction-F`` (the first F of the Fetch episodes train: the data-efficiency curve) and, per paper
dataset D, the sequential logic's ``D-temporal``, ``D-order``, ``D-conjunctive`` and ``D-fixed-weight``
(``loading.VARIANTS``). Besides ``REPORT.md``: ``summary.json``, the deploy choices and the stream LSTM's figures.

One module per part: ``loading`` reads the folder into a :class:`Run`; the pure ``tables``, ``claims``,
``figures`` and ``rendering`` turn it into rows, statements, figures and Markdown; :func:`run` below writes
``REPORT.md`` and the PNGs beside it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.reporting.figures import (
    FIGURES, figure_confusion, figure_efficiency, figure_test_curves, figure_timeline, figure_train_vs_test, pyplot,
)
from mlnseq.reporting.latency import FIGURE as LATENCY_FIGURE, figure_latency, with_live
from mlnseq.reporting.loading import PAPER_DATASETS, Run, load_run, present, timeline
from mlnseq.reporting.rendering import render
from mlnseq.reporting.tables import deploy_choices, efficiency_points, method_name, summary
from mlnseq.reporting.worked_examples import worked_examples

SUMMARY = "summary.json"


@dataclass(frozen=True)
class ReportOptions:
    """Options of `mlnseq report`."""

    runs: Path = Path("runs")
    out: Path = Path("reports")

    def validate(self) -> None:
        if not Path(self.runs).is_dir():
            raise BadInput(f"--runs {self.runs} is not a folder: run `make reproduce` first "
                           "(or point --runs at its RUNS)")


@dataclass(frozen=True)
class ReportResult:
    path: Path
    figures: list[Path]
    datasets: list[str]
    n_seed_runs: int


def run(options: ReportOptions) -> ReportResult:
    """Read the run folder ``options.runs``; write ``options.out/REPORT.md`` and its PNG figures."""
    options.validate()
    loaded = load_run(Path(options.runs))
    out = Path(options.out)
    drawn = {FIGURES["fig7"]: figure_test_curves(loaded), FIGURES["fig8"]: figure_train_vs_test(loaded),
             FIGURES["efficiency"]: figure_efficiency(efficiency_points(loaded))}
    for dataset in present(loaded, PAPER_DATASETS):
        drawn[FIGURES["confusion"].format(dataset=dataset)] = figure_confusion(loaded, dataset)
    for dataset in PAPER_DATASETS:  # issue 24: accuracy against latency, where conflate scored lagged decoders
        latency = figure_latency(loaded, dataset)
        if latency is not None:
            drawn[LATENCY_FIGURE.format(dataset=dataset)] = latency
    timelines = {}
    for dataset in PAPER_DATASETS:
        drawn_timeline = timeline_of(loaded, dataset)
        if drawn_timeline is not None:
            timelines[dataset], drawn[FIGURES["timeline"].format(dataset=dataset)] = drawn_timeline
    written = []
    plt = pyplot()
    for name, figure in drawn.items():
        with artifacts.atomic_path(out / name) as tmp:
            figure.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
        plt.close(figure)
        written.append(out / name)
    stream = loaded.metrics.filter(pl.col("mode") == "stream").group_by("dataset").agg(pl.col("seed").min())
    examples = worked_examples(Path(options.runs), list(PAPER_DATASETS), dict(stream.iter_rows()))
    path = artifacts.write_text(out / "REPORT.md", render(loaded, FIGURES, timelines, examples))
    artifacts.write_text(out / SUMMARY, json.dumps(with_live(loaded, summary(loaded)), indent=1, sort_keys=True) + "\n")
    n_seed_runs = loaded.metrics.select("dataset", "mode", "seed").unique().height
    return ReportResult(path, written, sorted(loaded.datasets), n_seed_runs)



def timeline_of(run: Run, dataset: str):
    """(what it shows, the figure) of one test episode of ``dataset`` in stream mode, the first seed: true labels,
    the LSTM, and the online and offline methods chosen by cross-validation; None where they were not run."""
    choices = deploy_choices(run, dataset)
    seeds = run.metrics.filter((pl.col("dataset") == dataset) & (pl.col("mode") == "stream"))["seed"]
    if "filter" not in choices or "viterbi" not in choices or seeds.len() == 0:
        return None
    seed = int(seeds.min())
    picks = {"LSTM": (dataset, "lstm")}
    for decode in ("filter", "viterbi"):
        choice = choices[decode]
        picks[f"{method_name(choice['method'])}\n{choice['variant']}"] = (choice["folder"], choice["method"])
    rows, episode = timeline(Path(run.runs), picks, "stream", seed)
    rows = rows.rename({"label": "true labels"}).select("frame", "true labels", *picks)
    what = (f"stream mode, seed {seed}, test episode {episode} (the first wholly in the test split), frames "
            f"{rows['frame'][0]}–{rows['frame'][-1]}")
    return what, figure_timeline(rows, run.datasets[dataset]["classes"], f"{dataset}: {what}")
