"""Reading a run folder of `make reproduce` into one :class:`Run` of tables (see ``mlnseq.report``)."""

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

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.methods import NETWORKS

PAPER_DATASETS = ("fetch", "desk")
RICH, FRACTION_PREFIX = "fetch-rich", "fetch-fraction-"
# Sequential logic (issue 12): a paper dataset D's folders by suffix, what each decodes with (the Makefile's layout).
VARIANTS = {
    "": "no transitions",  # D: the paper's per-frame formulas, decoded with uniform transitions
    "-temporal": "learned transitions",  # examples/temporal.mln: the decoded rows
    "-order": "plus hard order",  # examples/D.order.mln
    "-conjunctive": "conjunctive transitions",  # examples/conjunctive.mln: temporal.mln's transitions as a conjunction
    "-fixed-weight": "network factor weight fixed at 1",  # D-temporal decoded with --network-weight 1, not learned
}
TEMPORAL = "-temporal"
TCN = "-tcn"  # D-tcn: D's inputs, its networks causal TCNs (--cell tcn), stream mode
TIMINGS = "timings.tsv"  # written by scripts/timed_stage.sh: started, seconds, stage, arguments
SEED_DIR = re.compile(r"seed-(\d+)")


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
    # from predictions.parquet's metadata: frame accuracy on the networks' validation part, per method, and
    # the decoded methods' chosen network factor weight (dataset, mode, seed, method, value)
    validation: pl.DataFrame = field(default_factory=lambda: pl.DataFrame(schema=SEED_VALUE_SCHEMA))
    network_weights: pl.DataFrame = field(default_factory=lambda: pl.DataFrame(schema=SEED_VALUE_SCHEMA))
    notes: dict[tuple[str, str], list[str]] = field(default_factory=dict)  # (dataset, mode) -> conflate's notes
    # cross-validated figures on the training split (conflate with fold networks): dataset, mode, seed, method,
    # metric (segment_accuracy and frame_accuracy in %, edit, f1_50), value
    cv: pl.DataFrame = field(default_factory=lambda: pl.DataFrame(schema=CV_SCHEMA))
    runs: Path | None = None  # the run folder (the timeline figure reads one workdir's predictions)
    # (dataset, mode, method) -> the cross-validated frame accuracy (%) per fold, mean over seeds fold by fold
    # (every seed and folder of a dataset cuts the same folds): what the choices weigh frame differences by
    fold_frames: dict[tuple[str, str, str], list[float]] = field(default_factory=dict)


SEED_VALUE_SCHEMA = {"dataset": pl.String, "mode": pl.String, "seed": pl.Int64, "method": pl.String,
                     "value": pl.Float64}
CV_SCHEMA = {"dataset": pl.String, "mode": pl.String, "seed": pl.Int64, "method": pl.String, "metric": pl.String,
             "value": pl.Float64}


@dataclass
class _Found:
    """What ``load_run`` gathers, folder by folder, before it becomes a ``Run``."""

    metrics: list[pl.DataFrame] = field(default_factory=list)
    logs: list[pl.DataFrame] = field(default_factory=list)
    settings: dict[str, dict[str, set]] = field(default_factory=dict)
    datasets: dict[str, dict[str, Any]] = field(default_factory=dict)
    weights: dict[str, pl.DataFrame] = field(default_factory=dict)
    validation: list[dict[str, Any]] = field(default_factory=list)
    network_weights: list[dict[str, Any]] = field(default_factory=list)
    notes: dict[tuple[str, str], list[str]] = field(default_factory=dict)
    cv: list[dict[str, Any]] = field(default_factory=list)
    fold_frames: dict[tuple[str, str, str], list[list[float]]] = field(default_factory=dict)  # per seed


def load_run(runs: Path) -> Run:
    """Read every dataset folder and seed workdir of a run (see the module docstring)."""
    found = _Found()
    for frames_path in sorted(runs.glob(f"*/{artifacts.FRAMES}")):
        folder = frames_path.parent
        _read_dataset(folder, found)
        for metrics_path in sorted(folder.glob(f"*/seed-*/{artifacts.METRICS}")):
            _read_seed_workdir(metrics_path.parent, folder.name, found)
    if not found.metrics:
        raise BadInput(f"no results in {runs}: expected {runs}/DATASET/MODE/seed-N/{artifacts.METRICS}; "
                       "run `make reproduce` first")
    return Run(
        metrics=pl.concat(found.metrics, how="diagonal_relaxed"),
        logs=pl.concat(found.logs, how="diagonal_relaxed") if found.logs else pl.DataFrame(
            schema={"epoch": pl.Int32, "split": pl.String, "accuracy": pl.Float64, "loss": pl.Float64,
                    "method": pl.String, "dataset": pl.String, "mode": pl.String, "seed": pl.Int64}),
        datasets=found.datasets, weights=found.weights,
        settings={stage: {k: sorted(v, key=str) for k, v in options.items()}
                  for stage, options in found.settings.items()},
        timings=read_timings(runs / TIMINGS), machine=machine(),
        validation=pl.DataFrame(found.validation, schema=SEED_VALUE_SCHEMA),
        network_weights=pl.DataFrame(found.network_weights, schema=SEED_VALUE_SCHEMA), notes=found.notes, runs=runs,
        cv=pl.DataFrame(found.cv, schema=CV_SCHEMA),
        fold_frames={key: np.mean(seeds, axis=0).tolist() for key, seeds in found.fold_frames.items()
                     if len(set(map(len, seeds))) == 1},
    )


def _read_dataset(folder: Path, found: _Found) -> None:
    """A dataset folder's frames, predicates and weights: what they hold and the options that made them."""
    frames_path = folder / artifacts.FRAMES
    _, meta = artifacts.read_table(frames_path, "frames")
    frames = artifacts.labelled(pl.read_parquet(frames_path, columns=["split"]))
    predicates = folder / artifacts.PREDICATES
    predicates_meta = artifacts.read_metadata(predicates) if predicates.exists() else {}
    found.datasets[folder.name] = {**meta, "n_frames": frames.height,
                                   "n_train": int((frames["split"] == "train").sum()),
                                   "spec": predicates_meta.get("options", {}).get("spec", "–"),
                                   "formulas": formulas_source(folder / artifacts.FORMULAS)}
    _note(found.settings, "binarize", predicates_meta.get("options", {}))
    if (folder / artifacts.WEIGHTS).exists():
        found.weights[folder.name], weights_meta = artifacts.read_table(folder / artifacts.WEIGHTS, "weights")
        found.datasets[folder.name]["objective"] = weights_meta.get("objective", "pll")
        _note(found.settings, "learn-weights", {"engine": weights_meta.get("engine"),
                                                "objective": weights_meta.get("objective"),
                                                "l2": weights_meta.get("l2")})


def _read_seed_workdir(workdir: Path, dataset: str, found: _Found) -> None:
    """One seed workdir's metrics, what its predictions' metadata says, and its networks' training logs."""
    keys = {"dataset": dataset, "mode": workdir.parent.name, "seed": int(SEED_DIR.fullmatch(workdir.name).group(1))}
    table, metrics_meta = artifacts.read_table(workdir / artifacts.METRICS, "metrics")
    found.metrics.append(table.with_columns(**{k: pl.lit(v) for k, v in keys.items()}))
    _note(found.settings, "eval", metrics_meta.get("options", {}))
    predictions_meta = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")
    _note(found.settings, "conflate", {"mln_mode": predictions_meta.get("mln_mode"),
                                       "decode": ",".join(predictions_meta.get("decode", ["none"])),
                                       "network_weight": predictions_meta.get("network_weight_option") or "auto"})
    found.validation += [{**keys, "method": m, "value": v}
                         for m, v in predictions_meta.get("validation_frame_accuracy", {}).items()]
    found.network_weights += [{**keys, "method": m, "value": float(c["weight"])}
                              for m, c in predictions_meta.get("network_weights", {}).items()]
    cross_validation = predictions_meta.get("cross_validation") or {}
    for m, figures in (cross_validation.get("figures") or {}).items():
        found.cv += [{**keys, "method": m, "metric": k, "value": float(v)} for k, v in figures.items()]
    for m, per_fold in (cross_validation.get("fold_frame_accuracy") or {}).items():
        found.fold_frames.setdefault((dataset, keys["mode"], m), []).append(per_fold)
    notes = found.notes.setdefault((dataset, keys["mode"]), []) if predictions_meta.get("notes") else []
    for note in predictions_meta.get("notes", []):
        if note not in notes:
            notes.append(note)
    for method in NETWORKS:
        log_path = artifacts.train_log_path(workdir, method)
        if log_path.exists():
            log, log_meta = artifacts.read_table(log_path, "train_log")
            found.logs.append(log.with_columns(method=pl.lit(method), **{k: pl.lit(v) for k, v in keys.items()}))
            _note(found.settings, "train", {**log_meta.get("options", {}), "kept_epoch": log_meta.get("kept_epoch")},
                  skip=("seed", "method"))


def formulas_source(path: Path) -> str:
    """The spec a dataset's formulas.mln was written from (its first line names it), or '–'."""
    if not path.exists():
        return "–"
    found = re.match(r"// mlnseq formulas from (\S+):", path.read_text().split("\n", 1)[0])
    return found.group(1) if found else "–"


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


def present(run: Run, names: tuple[str, ...]) -> list[str]:
    """Those of ``names`` that the run has results for, in that order."""
    have = set(run.metrics["dataset"].unique().to_list())
    return [n for n in names if n in have]


TIMELINE_FRAMES = 600  # at most this many frames from the start of the episode the timeline shows


def timeline(runs: Path, picks: dict[str, tuple[str, str]], mode: str, seed: int) -> tuple[pl.DataFrame, int]:
    """Labels and predictions of the first episode that lies wholly in the test split, its first
    TIMELINE_FRAMES frames: a ``label`` column and one column per pick (row name -> (dataset folder, method)),
    from ``runs/FOLDER/MODE/seed-SEED/predictions.parquet``; and that episode's number."""
    columns, episode = {}, None
    for name, (folder, method) in picks.items():
        path = runs / folder / mode / f"seed-{seed}" / artifacts.PREDICTIONS
        table = pl.read_parquet(path, columns=["episode", "frame", "split", "label", artifacts.pred_column(method)])
        if episode is None:
            mixed = table.filter(pl.col("split") != "test")["episode"].unique()
            episode = table.filter(~pl.col("episode").is_in(mixed.implode()))["episode"][0]
        rows = table.filter(pl.col("episode") == episode).sort("frame").head(TIMELINE_FRAMES)
        columns.setdefault("frame", rows["frame"])
        columns.setdefault("label", rows["label"])
        columns[name] = rows[artifacts.pred_column(method)]
    return pl.DataFrame(columns), int(episode)
