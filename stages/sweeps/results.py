"""The sweep's results: per config, the cross-validated figures of the method it deploys (means and spreads over
seeds), the test figures beside them for display only, and the best config by cross-validation.

Everything is read from the artifacts: ``predictions.parquet``'s metadata (the figures conflate recorded on the
training split's folds) and ``metrics.parquet`` (eval's test figures)."""

from __future__ import annotations

import shlex
import statistics
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.methods import decoded_name
from mlnseq.recognition.cross_validation import choice_score
from mlnseq.sweeps.grid import Config, Sweep, flags
from mlnseq.sweeps.workflow import run_dir

RESULTS = "results.parquet"
FIGURES = ("segment_accuracy", "frame_accuracy", "edit")  # accuracies in %
TEST_METRICS = {"segment_accuracy": ("segment_accuracy", 100.0), "frame_accuracy": ("frame_accuracy", 100.0),
                "edit": ("edit", 1.0)}


@dataclass(frozen=True)
class SeedResult:
    seed: int
    method: str  # the decoded method name the config deploys on this seed
    cv: dict[str, float]
    test: dict[str, float]


def deployed_method(config: Config, figures: dict[str, dict[str, float]], where: Path) -> str:
    """The method the config's export options deploy: named, or (``auto``) the best cross-validated one."""
    options = config.options["export"]
    if options.method == "auto":
        candidates = {n: f for n, f in figures.items() if n.endswith(f"+{options.decode}")}
        if not candidates:
            raise BadInput(f"{where} holds no cross-validated {options.decode} figures: were its networks trained "
                           "with folds (the dataset's `mlnseq learn-weights --folds K`)?")
        return max(candidates, key=lambda name: choice_score(candidates[name], options.decode))
    name = decoded_name(options.method, options.decode)
    if name not in figures:
        raise BadInput(f"{where} holds no cross-validated figures for {name} (it has {', '.join(sorted(figures))})")
    return name


def seed_result(config: Config, seed: int, workdir: Path) -> SeedResult:
    meta = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")
    figures = (meta.get("cross_validation") or {}).get("figures") or {}
    method = deployed_method(config, figures, workdir / artifacts.PREDICTIONS)
    metrics, _ = artifacts.read_table(workdir / artifacts.METRICS, "metrics")
    test = {}
    for figure, (metric, scale) in TEST_METRICS.items():
        values = metrics.filter((pl.col("method") == method) & (pl.col("metric") == metric))["value"]
        test[figure] = scale * values[0] if len(values) else float("nan")
    return SeedResult(seed, method, {f: figures[method][f] for f in FIGURES}, test)


def spread(values: list[float]) -> float:
    """The standard deviation over seeds (n - 1 in the denominator; 0 for one seed)."""
    return statistics.stdev(values) if len(values) > 1 else 0.0


def deploy_command(config: Config, result: SeedResult, workdir: Path) -> str:
    """The `mlnseq export` command that writes the model file of ``result``'s method from ``workdir``: its method
    and decoding written out, then the config's other export options."""
    method, _, decode = result.method.partition("+")
    options = config.options["export"]
    defaults = type(options)()
    others = flags("export", replace(options, method=defaults.method, decode=defaults.decode))
    return shlex.join(["mlnseq", "export", "--method", method, "--decode", decode or "none", *others,
                       "--workdir", str(workdir)])


def config_row(sweep: Sweep, config: Config, out: Path) -> dict[str, Any]:
    results = [seed_result(config, seed, run_dir(out, config.name, seed)) for seed in sweep.seeds]
    decode = config.options["export"].decode
    best = max(results, key=lambda r: choice_score(r.cv, decode))
    row: dict[str, Any] = {"config": config.name, **{key: config.values[key] for key in sweep.keys},
                           "method": ", ".join(sorted({r.method for r in results})), "seeds": len(results)}
    for figure in FIGURES:
        values = [r.cv[figure] for r in results]
        row[f"cv_{figure}"] = statistics.fmean(values)
        row[f"cv_{figure}_std"] = spread(values)
    row["cv_score"] = choice_score({f: row[f"cv_{f}"] for f in FIGURES}, decode)
    for figure in FIGURES:
        row[f"test_{figure}"] = statistics.fmean(r.test[figure] for r in results)
    row["best_seed"] = best.seed
    row["deploy"] = deploy_command(config, best, run_dir(out, config.name, best.seed))
    return row


def gather(sweep: Sweep, out: Path) -> pl.DataFrame:
    """One row per config, in the grid's order; a grid key whose values mix types is a text column."""
    rows = [config_row(sweep, config, out) for config in sweep.configs]
    for key in sweep.keys:
        if len({type(row[key]) for row in rows}) > 1:
            for row in rows:
                row[key] = str(row[key])
    return pl.DataFrame(rows)


def best(table: pl.DataFrame) -> dict[str, Any]:
    """The config with the highest cross-validated score (the first in the grid's order among equals)."""
    index = max(range(table.height), key=lambda i: (table["cv_score"][i], -i))
    return table.row(index, named=True)


def write(table: pl.DataFrame, sweep: Sweep, out: Path) -> Path:
    meta = {"sweep_file": str(sweep.path.resolve()), "workdir": str(sweep.workdir.resolve()),
            "seeds": list(sweep.seeds), "grid": list(sweep.keys)}
    return artifacts.write_table(table, out / RESULTS, "sweep-results", meta)
