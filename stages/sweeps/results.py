"""The sweep's results: per config, the cross-validated figures of the method it deploys (means and spreads over
seeds), the test figures beside them for display only, and the best config by cross-validation.

Everything is read from the artifacts: ``predictions.parquet``'s metadata (the figures conflate recorded on the
training split's folds) and ``metrics.parquet`` (eval's test figures). A config whose job failed (or never ran) is a
row of its own, ``status`` failed with the ``failure`` in words and no figures, and is never ranked."""

from __future__ import annotations

import os
import shlex
import statistics
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.methods import decoded_name
from mlnseq.choosing import latency
from mlnseq.sweeps.grid import Config, Sweep, flags
from mlnseq.sweeps.running import JobError
from mlnseq.sweeps.workflow import FORMULAS_DIR, run_dir, spec_names

RESULTS = "results.parquet"
DONE, FAILED = "done", "failed"  # a config's status
LAST_LINES = 5  # of a failed job's log, shown under its line
FIGURES = ("segment_accuracy", "frame_accuracy", "edit")  # accuracies in %
TEST_METRICS = {"segment_accuracy": ("segment_accuracy", 100.0), "frame_accuracy": ("frame_accuracy", 100.0),
                "edit": ("edit", 1.0)}


@dataclass(frozen=True)
class SeedResult:
    seed: int
    method: str  # the decoded method name the config deploys on this seed
    cv: dict[str, float]
    test: dict[str, float]


def deployed_method(config: Config, figures: dict[str, dict[str, float]], where: Path,
                    fold_frames: dict[str, list[float]] | None = None) -> str:
    """The method the config's export options deploy: named, or (``auto``) the best cross-validated one (its frame
    accuracy per fold, where recorded, as export --method auto reads it)."""
    options = config.options["export"]
    if options.method == "auto":
        candidates = {n: f for n, f in figures.items() if n.endswith(f"+{options.decode}")}
        if not candidates:
            raise BadInput(f"{where} holds no cross-validated {options.decode} figures: were its networks trained "
                           "with folds (the dataset's `mlnseq learn-weights --folds K`)?")
        return latency.best(latency.candidates(candidates, fold_frames)).name  # export --method auto --decode's
    name = decoded_name(options.method, options.decode)
    if name not in figures:
        raise BadInput(f"{where} holds no cross-validated figures for {name} (it has {', '.join(sorted(figures))})")
    return name


def seed_result(config: Config, seed: int, workdir: Path) -> SeedResult:
    meta = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")
    cross_validation = meta.get("cross_validation") or {}
    figures = cross_validation.get("figures") or {}
    method = deployed_method(config, figures, workdir / artifacts.PREDICTIONS,
                             cross_validation.get("fold_frame_accuracy"))
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


@dataclass(frozen=True)
class Failure:
    """A config that did not finish: the first of its jobs that failed (or did not run), and its log."""

    config: str
    seed: int | None  # None: a job before the seeds (the formulas file's)
    stage: str
    log: Path
    reason: str
    tail: tuple[str, ...] = ()  # the last lines of its log, then of the cluster's
    others: tuple[Path, ...] = ()  # the other logs Snakemake named for it (the cluster job's)

    def line(self) -> str:
        seed = "" if self.seed is None else f" of seed {self.seed}"
        others = f" (the cluster's: {', '.join(map(str, self.others))})" if self.others else ""
        return f"config {self.config} failed: {self.stage}{seed} {self.reason}; its log: {self.log}{others}"


def config_jobs(sweep: Sweep, config: Config, out: Path, seed: int) -> list[tuple[str, Path, Path]]:
    """A config's jobs for one seed, in order: (stage, its output, its log)."""
    jobs = []
    if config.formulas is not None:
        folder = out / FORMULAS_DIR / spec_names(sweep)[config.formulas]
        jobs += [("formulas", folder / artifacts.FORMULAS, folder / "logs" / "formulas.log"),
                 ("learn-weights", folder / artifacts.FOLD_WEIGHTS, folder / "logs" / "learn-weights.log")]
    workdir, network = run_dir(out, config.name, seed), config.options["train"].method
    return jobs + [("train", workdir / "models" / f"{network}.pt", workdir / "logs" / f"train-{network}.log"),
                   ("conflate", workdir / artifacts.PREDICTIONS, workdir / "logs" / "conflate.log"),
                   ("eval", workdir / artifacts.METRICS, workdir / "logs" / "eval.log")]


def failure(sweep: Sweep, config: Config, out: Path, errors: list[JobError]) -> Failure | None:
    """The config's failed job: of each seed's first job whose output is missing, the first Snakemake reported
    failed (else the first), with its reason; None when every output is there."""
    missing = []
    for seed in sweep.seeds:
        first = next(((stage, log) for stage, output, log in config_jobs(sweep, config, out, seed)
                      if not output.exists()), None)
        if first is not None:
            relative = str(first[1].relative_to(out))
            missing.append((seed, *first, next((e for e in errors if relative in e.logs), None)))
    if not missing:
        return None
    seed, stage, log, error = next((m for m in missing if m[3] is not None), missing[0])
    reason = error.reason() if error else "did not run (a job it needs failed, or the sweep stopped)"
    others = [Path(out, p) for p in (error.logs if error else []) if p != str(log.relative_to(out))]
    tail = last_lines(log) + tuple(line for other in others for line in last_lines(other))
    full = None if tail or error is None else disk_full(log.parent)
    if full:
        reason += f" and its log is empty: {full}"
    return Failure(config.name, None if stage in ("formulas", "learn-weights") else seed, stage, log, reason, tail,
                   tuple(others))


def disk_full(folder: Path, size: int = 64 * 1024) -> str | None:
    """Why ``folder`` cannot take ``size`` bytes more (a full disk), or None when it can: a probe file written and
    removed."""
    import tempfile

    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".disk-probe.", suffix=".tmp") as probe:
            probe.write(b"\0" * size)
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as error:
        return f"{error.strerror or error} in {folder}"
    return None


def last_lines(path: Path, count: int = LAST_LINES) -> tuple[str, ...]:
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return ()
    return tuple(line for line in lines if line.strip())[-count:]


def failed_row(sweep: Sweep, config: Config, failed: Failure) -> dict[str, Any]:
    row: dict[str, Any] = {"config": config.name, **{key: config.values[key] for key in sweep.keys},
                           "status": FAILED, "failure": failed.line(), "method": None, "seeds": len(sweep.seeds)}
    for figure in FIGURES:
        row[f"cv_{figure}"] = row[f"cv_{figure}_std"] = None
    row["cv_score"] = None
    for figure in FIGURES:
        row[f"test_{figure}"] = row[f"test_{figure}_std"] = None
    return {**row, "best_seed": None, "deploy": None}


def config_row(sweep: Sweep, config: Config, out: Path) -> dict[str, Any]:
    results = [seed_result(config, seed, run_dir(out, config.name, seed)) for seed in sweep.seeds]
    best = max(results, key=lambda r: latency.criterion(r.cv))
    row: dict[str, Any] = {"config": config.name, **{key: config.values[key] for key in sweep.keys},
                           "status": DONE, "failure": None, "method": ", ".join(sorted({r.method for r in results})),
                           "seeds": len(results)}
    for figure in FIGURES:
        values = [r.cv[figure] for r in results]
        row[f"cv_{figure}"] = statistics.fmean(values)
        row[f"cv_{figure}_std"] = spread(values)
    row["cv_score"] = latency.criterion({f: row[f"cv_{f}"] for f in FIGURES})
    for figure in FIGURES:
        values = [r.test[figure] for r in results]
        row[f"test_{figure}"], row[f"test_{figure}_std"] = statistics.fmean(values), spread(values)
    row["best_seed"] = best.seed
    row["deploy"] = deploy_command(config, best, run_dir(out, config.name, best.seed))
    return row


def gather(sweep: Sweep, out: Path, errors: list[JobError] = ()) -> tuple[pl.DataFrame, list[Failure]]:
    """One row per config, in the grid's order (a failed config marked, without figures), and the failures; a grid
    key whose values mix types is a text column."""
    rows, failures = [], []
    for config in sweep.configs:
        failed = failure(sweep, config, out, list(errors))
        if failed is not None:
            failures.append(failed)
        rows.append(config_row(sweep, config, out) if failed is None else failed_row(sweep, config, failed))
    for key in sweep.keys:
        if len({type(row[key]) for row in rows}) > 1:
            for row in rows:
                row[key] = str(row[key])
    schema = {"status": pl.String, "failure": pl.String, "method": pl.String, "deploy": pl.String,
              "best_seed": pl.Int64, **{c: pl.Float64 for c in rows[0] if c.startswith(("cv_", "test_"))}}
    return pl.DataFrame(rows, schema_overrides=schema), failures


def best(table: pl.DataFrame) -> dict[str, Any] | None:
    """The finished config with the highest cross-validated score (the first in the grid's order among equals)."""
    done = [i for i in range(table.height) if table["status"][i] == DONE]
    if not done:
        return None
    return table.row(max(done, key=lambda i: (table["cv_score"][i], -i)), named=True)


def write(table: pl.DataFrame, sweep: Sweep, out: Path) -> Path:
    meta = {"sweep_file": str(sweep.path.resolve()), "workdir": str(sweep.workdir.resolve()),
            "seeds": list(sweep.seeds), "grid": list(sweep.keys)}
    return artifacts.write_table(table, out / RESULTS, "sweep-results", meta)
