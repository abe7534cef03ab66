"""The report's numbers: statistics over seeds and the rows of every table (pure functions of a :class:`Run`)."""

from __future__ import annotations

import re
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog.methods import DECODES, METHODS, decoded_name
from mlnseq.reporting.loading import FRACTION_PREFIX, PAPER_DATASETS, RICH, TCN, TEMPORAL, VARIANTS, Run, present

# Table III of the paper: segment accuracy (%) at half of each segment.
PAPER_TABLE_III = {
    "fetch": {"lstm": 71, "mln": 50, "priorlayer": 83, "conflation": 77, "combined": 84},
    "desk": {"lstm": 68, "mln": 49, "priorlayer": 71, "conflation": 69, "combined": 72},
}


def method_names(network: str = "LSTM") -> dict[str, str]:
    """Each method's name in the report, its network named ``network`` (the paper's: LSTM)."""
    return {"lstm": network, "mln": "MLN", "priorlayer": f"{network} + PriorLayer",
            "conflation": f"{network} + Conflation", "combined": "PriorLayer + Conflation (combined)"}


METHOD_NAMES = method_names()  # the paper's networks: LSTMs


def network_label(folder: str) -> str:
    """The network type of a dataset folder's methods: TCN in a D-tcn folder (`train --cell tcn`), else LSTM."""
    return "TCN" if folder.endswith(TCN) else "LSTM"

DECODE_NAMES = {"none": "", "filter": " + filter (online)", "viterbi": " + Viterbi (offline)"}
SEQUENCE_METRICS = ("segment_accuracy", "frame_accuracy", "edit", "f1@50")
ABLATION_METHODS = ("lstm", "mln", "conflation")  # no retraining: every variant has them
DEPLOY_VARIANTS = ("", TEMPORAL, "-order", "-conjunctive")  # what a user may deploy (fixed-weight: an ablation)
CV_METRICS = {"segment_accuracy": "segment_accuracy", "frame_accuracy": "frame_accuracy", "edit": "edit",
              "f1@50": "f1_50"}  # SEQUENCE_METRICS -> the cross-validated figures' names
STAGE_ORDER = ("collect", "binarize", "formulas", "learn-weights", "train", "conflate", "eval", "report")


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


ABSENT = (None, None)  # lookup's answer, and by_pair's, where there are no figures


def lookup(stats: pl.DataFrame, **keys: Any) -> tuple[float | None, float | None]:
    row = stats.filter(pl.all_horizontal(pl.col(k) == v for k, v in keys.items()))
    return (row["mean"][0], row["std"][0]) if row.height else ABSENT


def by_pair(stats: pl.DataFrame) -> dict[tuple[str, str], tuple[float | None, float | None]]:
    """:func:`lookup`'s answer for every (dataset, method) of ``stats`` at once: the first row's mean and std."""
    out: dict[tuple[str, str], tuple[float | None, float | None]] = {}
    for dataset, method, mean, std in zip(stats["dataset"].to_list(), stats["method"].to_list(),
                                          stats["mean"].to_list(), stats["std"].to_list()):
        out.setdefault((dataset, method), (mean, std))
    return out


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
    for dataset in present(run, PAPER_DATASETS):
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


def method_name(name: str, folder: str = "") -> str:
    """'LSTM + Conflation + Viterbi (offline)' for 'conflation+viterbi' (TCN for a D-tcn ``folder``'s)."""
    method, _, decode = name.partition("+")
    return method_names(network_label(folder))[method] + DECODE_NAMES[decode or "none"]


def sequence_stats(run: Run, mode: str = "stream") -> dict[str, pl.DataFrame]:
    """Per metric of SEQUENCE_METRICS: mean and std over seeds per dataset folder and method, in one mode."""
    return {m: method_stats(run, m, mode=mode) for m in SEQUENCE_METRICS}


def cv_stats(run: Run, mode: str = "stream") -> dict[str, pl.DataFrame]:
    """Per metric of SEQUENCE_METRICS: the cross-validated figure on the training split, mean and std over seeds,
    per dataset folder and method."""
    return {m: run.cv.filter((pl.col("mode") == mode) & (pl.col("metric") == CV_METRICS[m]))
            .group_by(["dataset", "method"], maintain_order=True)
            .agg(pl.col("value").mean().alias("mean"), pl.col("value").std().alias("std"),
                 pl.col("seed").n_unique().alias("seeds")) for m in SEQUENCE_METRICS}


def weight_cell(run: Run, folder: str, mode: str, method: str) -> str:
    """The network factor's weight of a decoded method: its values over seeds ('0.25, 0.5'), or '–'."""
    if folder.endswith("-fixed-weight") and not method.startswith("mln"):
        return "1 (fixed)"
    chosen = run.network_weights.filter((pl.col("dataset") == folder) & (pl.col("mode") == mode)
                                        & (pl.col("method") == method))["value"]
    return ", ".join(f"{w:.3g}" for w in sorted(chosen.unique())) if chosen.len() else "–"


def decoded_cells(run: Run, stats: dict[str, pl.DataFrame], cv: dict[str, pl.DataFrame], folder: str, mode: str,
                  method: str) -> list[str]:
    """A decoded-method row's figures: SEQUENCE_METRICS on test, the network factor's weight, the cross-validated
    segment accuracy and edit on the training split."""
    return [*(fmt(*lookup(stats[m], dataset=folder, method=method)) for m in SEQUENCE_METRICS),
            weight_cell(run, folder, mode, method),
            *(fmt(*lookup(cv[m], dataset=folder, method=method)) for m in ("segment_accuracy", "edit"))]


def decoded_table(run: Run) -> list[list[str]]:
    """The decoded rows: per paper dataset and mode, every method of DATASET-temporal undecoded and decoded."""
    rows = []
    for mode in ("segment", "stream"):
        stats, cv = sequence_stats(run, mode), cv_stats(run, mode)
        for dataset in PAPER_DATASETS:
            folder = dataset + TEMPORAL
            for decode in DECODES:
                for method in METHODS:
                    name = decoded_name(method, decode)
                    if lookup(stats["segment_accuracy"], dataset=folder, method=name)[0] is None:
                        continue
                    rows.append([dataset, mode, method_name(name, folder),
                                 *decoded_cells(run, stats, cv, folder, mode, name)])
    return rows


def ablation_table(run: Run, dataset: str) -> list[list[str]]:
    """Stream mode, per decoded method of ABLATION_METHODS: each variant of VARIANTS that has it."""
    stats, cv = sequence_stats(run), cv_stats(run)
    rows = []
    for method in ABLATION_METHODS:
        for decode in DECODES[1:]:
            name = decoded_name(method, decode)
            for suffix, variant in VARIANTS.items():
                folder = dataset + suffix
                if lookup(stats["segment_accuracy"], dataset=folder, method=name)[0] is None:
                    continue
                if method == "mln" and suffix == "-fixed-weight":
                    continue  # the MLN alone has no network factor
                rows.append([method_name(name, folder), variant,
                             *decoded_cells(run, stats, cv, folder, "stream", name)])
    return rows


def fold_frames_of(run: Run, folder: str, names: list[str], mode: str = "stream") -> dict[str, list[float]]:
    """The cross-validated frame accuracy per fold (mean over seeds) of the methods ``names`` of a folder."""
    return {name: run.fold_frames[folder, mode, name] for name in names if (folder, mode, name) in run.fold_frames}


def deploy_choices(run: Run, dataset: str) -> dict[str, Any]:
    """Per decoding (filter, viterbi), every decoded method of a DEPLOY_VARIANTS folder (stream mode) with its
    cross-validated and test figures (mean, std over seeds), and the one export --method auto's choice takes
    (``recognition.latency.best`` on the means: the frames first, then the mean of segment accuracy, frame accuracy
    and edit; ties: the first in that order and METHODS order, the others near the best frames of the same
    criterion listed under ``ties``); the test split is never looked at for the choice. ``best_on_test`` per metric
    is shown beside it, marked optimistic."""
    from mlnseq.choosing import latency

    stats = {m: by_pair(table) for m, table in sequence_stats(run).items()}
    cv = {m: by_pair(table) for m, table in cv_stats(run).items()}
    candidates = []
    for suffix in DEPLOY_VARIANTS:
        for decode in DECODES[1:]:
            for method in METHODS:
                pair = (dataset + suffix, decoded_name(method, decode))
                figures = {m: cv[m].get(pair, ABSENT) for m in SEQUENCE_METRICS}
                if figures["segment_accuracy"][0] is None or stats["segment_accuracy"].get(pair, ABSENT)[0] is None:
                    continue
                means = {CV_METRICS[m]: np.nan if v[0] is None else v[0] for m, v in figures.items()}
                (scored,) = latency.candidates({pair[1]: means}, fold_frames_of(run, pair[0], [pair[1]]))
                candidates.append({"folder": pair[0], "variant": VARIANTS[suffix], "method": pair[1], "decode": decode,
                                   "score": scored.score[0], "cv": figures, "candidate": scored,
                                   **{m: stats[m].get(pair, ABSENT) for m in SEQUENCE_METRICS}})
    choices: dict[str, Any] = {"candidates": candidates}
    for decode in DECODES[1:]:
        kind = [c for c in candidates if c["decode"] == decode]
        if kind:
            chosen = latency.best([c["candidate"] for c in kind])  # max keeps the first of equals
            best = next(c for c in kind if c["candidate"] is chosen)
            near = {id(n) for n in latency.near_best([c["candidate"] for c in kind])}  # no network alone: no floor
            ties = [c for c in kind if c is not best and id(c["candidate"]) in near
                    and np.isclose(c["score"], best["score"], atol=1e-9)]
            choices[decode] = {**best, "ties": ties}
    if candidates:
        choices["best_on_test"] = {m: max(candidates, key=lambda c: c[m][0] if c[m][0] is not None else -np.inf)
                                   for m in SEQUENCE_METRICS}
    return choices


def _number(value: float | None) -> float | None:
    """A figure for JSON: None where it is absent or not a number."""
    return None if value is None or np.isnan(value) else float(value)


def deploy_table(run: Run) -> list[list[str]]:
    """Per paper dataset and use (online: filter, offline: Viterbi), stream mode: every candidate with its
    cross-validated figures (training split) and its test figures side by side; the choice marked."""
    rows = []
    for dataset in PAPER_DATASETS:
        choices = deploy_choices(run, dataset)
        for decode, kind in (("filter", "online"), ("viterbi", "offline")):
            for c in choices["candidates"]:
                if c["decode"] != decode:
                    continue
                chosen = decode in choices and c["folder"] == choices[decode]["folder"] \
                    and c["method"] == choices[decode]["method"]
                rows.append([dataset, kind, ("**chosen** " if chosen else "") + method_name(c["method"], c["folder"]),
                             f"{c['variant']} (`{c['folder']}`)",
                             *(fmt(*c["cv"][m]) for m in SEQUENCE_METRICS), *(fmt(*c[m]) for m in SEQUENCE_METRICS)])
    return rows


def summary(run: Run) -> dict[str, Any]:
    """reports/summary.json: per paper dataset and use, the chosen method with its cross-validated and test figures
    (segment_accuracy, frame_accuracy in %, edit, f1_50; means over seeds), and the stream LSTM's test figures."""
    out: dict[str, Any] = {}
    stats = sequence_stats(run)
    for dataset in present(run, PAPER_DATASETS):
        choices = deploy_choices(run, dataset)
        entry: dict[str, Any] = {}
        for decode, use in (("filter", "online"), ("viterbi", "offline")):
            if decode in choices:
                c = choices[decode]
                entry[use] = {"method": c["method"], "folder": c["folder"], "variant": c["variant"],
                              "cv": {CV_METRICS[m]: _number(c["cv"][m][0]) for m in SEQUENCE_METRICS},
                              "test": {CV_METRICS[m]: _number(c[m][0]) for m in SEQUENCE_METRICS}}
        entry["lstm"] = {"test": {CV_METRICS[m]: _number(lookup(stats[m], dataset=dataset, method="lstm")[0])
                                  for m in SEQUENCE_METRICS}}
        out[dataset] = entry
    return out


def stream_table(run: Run) -> list[list[str]]:
    """Stream mode (no segment boundaries at test): segment accuracy, edit and F1@k, mean ± std."""
    columns = ("segment_accuracy", "frame_accuracy", "edit", "f1@10", "f1@25", "f1@50")
    stats = {c: method_stats(run, c, mode="stream") for c in columns}
    return [[dataset, method_name(method, dataset),
             *(fmt(*lookup(stats[c], dataset=dataset, method=method)) for c in columns)]
            for dataset in present(run, (*PAPER_DATASETS, *(d + TCN for d in PAPER_DATASETS))) for method in METHODS
            if lookup(stats["segment_accuracy"], dataset=dataset, method=method)[0] is not None]


def rich_spec_table(run: Run) -> list[list[str]]:
    """Fetch, segment mode: the paper's predicate spec against the richer one, per method."""
    stats = method_stats(run)
    return [[METHOD_NAMES[m], *(fmt(*lookup(stats, dataset=d, method=m)) for d in ("fetch", RICH))] for m in METHODS]


def efficiency_points(run: Run) -> pl.DataFrame:
    """Per training size (share of the Fetch frames that train) and method: segment accuracy mean, std."""
    names = [d for d in run.datasets if d.startswith(FRACTION_PREFIX)] + present(run, ("fetch",))
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
        gain = combined_gain(by)
        rows.append([f"{share:.1%}", f"{frames:,}",
                     *(fmt(by[m]["mean"], by[m]["std"]) if m in by else "–" for m in ("lstm", "mln", "combined")),
                     "–" if gain is None else f"{gain:+.1f}"])
    return rows


def combined_gain(by_method: dict[str, dict[str, Any]]) -> float | None:
    """The combined model's segment accuracy minus the LSTM's, where both were run."""
    if "lstm" in by_method and "combined" in by_method:
        return by_method["combined"]["mean"] - by_method["lstm"]["mean"]
    return None


def weights_table(run: Run, dataset: str, per_class: int = 3) -> list[list[str]]:
    """Table II style: the strongest learned formulas of each class."""
    from mlnseq.mln.weights_table import strongest

    classes = run.datasets[dataset]["classes"]
    rows = []
    for row in strongest(run.weights[dataset], per_class).iter_rows(named=True):
        name = classes[int(row["class"][1:])] if re.fullmatch(r"C\d+", row["class"] or "") else row["class"]
        weight = "hard" if row["hard"] else f"{row['weight']:.3f}"
        rows.append([name, weight, f"`{row['formula']}`"])
    return rows


def datasets_table(run: Run) -> list[list[str]]:
    """What each dataset folder holds: source, frames, training frames, features, predicate spec, formulas
    (the spec and the weights' objective), epochs."""
    rows = []
    for name, d in sorted(run.datasets.items()):
        options = d.get("options", {})
        source = d.get("source", "?") + (f", {options['episodes']} episodes, seed {options['seed']}"
                                         if d.get("source") == "fetch" else "")
        epochs = run.logs.filter(pl.col("dataset") == name)["epoch"].max()
        formulas = d.get("formulas", "–") + (f" ({d['objective']})" if "objective" in d else "")
        rows.append([name, source, f"{d['n_frames']:,}", f"{d['n_train']:,}", str(len(d["features"])), d["spec"],
                     formulas, "–" if epochs is None else str(epochs)])
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

