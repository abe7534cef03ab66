"""`mlnseq sweep`: a grid of stage options times seeds, run as a Snakemake workflow, locally or on SLURM."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from mlnseq_cli.console import console, reported_errors
from mlnseq.catalog.errors import BadInput
from mlnseq.pipeline import sweep as stage


def sweep(
    sweep_file: Annotated[Path, typer.Argument(help="The sweep file (TOML): [sweep] workdir and seeds, [grid] option = [values].", dir_okay=False)],
    cores: Annotated[Optional[int], typer.Option(help="Locally: cores to use \\[default: all]. With --executor slurm: jobs at once \\[default: the profile's].", show_default=False)] = None,
    executor: Annotated[str, typer.Option(help="local (this machine) or slurm (one cluster job per rule, needs --profile).")] = stage.Executor.LOCAL.value,
    profile: Annotated[Optional[Path], typer.Option(help="A Snakemake profile folder (config.yaml): the cluster's partition, resources per rule, status command.", file_okay=False)] = None,
    out: Annotated[Optional[Path], typer.Option(help="Where the workflow, the runs and results.parquet go \\[default: sweep/ beside the sweep file].", file_okay=False)] = None,
    yes: Annotated[bool, typer.Option("--yes", help="Run a grid of more than 1,000 configs.")] = False,
) -> None:
    """Read SWEEP_FILE and its dataset workdir (frames, predicates, weights and fold weights); write OUT/Snakefile, OUT/sweep.json, per config and seed OUT/runs/CONFIG/seed-N (train, conflate --decode all, eval, the inputs linked), with a grid key formulas OUT/formulas/STEM (formulas, learn-weights --folds K) and OUT/results.parquet: per config its cross-validated segment and frame accuracy and edit (means over seeds, with spreads), the test figures for display only, and the `mlnseq export` command that deploys it. A rerun does only what is missing or stale. The last line names the best config by cross-validation."""
    with reported_errors():
        try:
            chosen = stage.Executor(executor)
        except ValueError:
            raise BadInput(f"unknown --executor {executor!r}: choose one of "
                           f"{', '.join(e.value for e in stage.Executor)}") from None
        options = stage.SweepOptions(cores=cores, executor=chosen, profile=profile, out=out,
                                     limit=None if yes else stage.grid.MAX_CONFIGS)
        swept = stage.sweep(sweep_file, options, say_progress)
    console.print("cross-validated on the training split (mean ± spread over seeds); test only for display:",
                  highlight=False)
    for line in summary_lines(swept):
        console.print(line, highlight=False, markup=False)
    failed = f", {len(swept.failures)} failed" if swept.failures else ""
    if swept.path is not None:
        console.print(f"[green]sweep[/]: wrote {swept.path} ({swept.table.height} configs{failed})")
    best = swept.best
    if best is not None:
        console.print(f"best by cross-validation: {best['config']} ({best['method']}): segment accuracy "
                      f"{best['cv_segment_accuracy']:.1f} ± {best['cv_segment_accuracy_std']:.1f} %, frame accuracy "
                      f"{best['cv_frame_accuracy']:.1f} ± {best['cv_frame_accuracy_std']:.1f} %, edit "
                      f"{best['cv_edit']:.1f} ± {best['cv_edit_std']:.1f}; deploy it: {best['deploy']}",
                      highlight=False, markup=False)
    if swept.log_error:
        print(f"warning: {swept.log_error}: Snakemake's output was not all kept", file=sys.stderr)
    for failure in swept.failures:
        print(f"error: {failure.line()}", file=sys.stderr)
        for line in failure.tail:
            print(f"    | {line}", file=sys.stderr)
    if swept.write_error:
        print(f"error: {swept.write_error}", file=sys.stderr)
    if swept.failures or swept.write_error:
        print("error: rerun `mlnseq sweep` to redo only what is missing (free space first if the disk is full)",
              file=sys.stderr)
        raise typer.Exit(1)


def say_progress(progress: stage.Progress) -> None:
    """One line on stderr each time a config finishes or fails (Snakemake's own output goes to the sweep's log)."""
    if progress.starting:
        already = f" ({progress.done} done already)" if progress.done else ""
        print(f"sweep: {progress.total} configs{already}; Snakemake's output goes to {progress.log}", file=sys.stderr,
              flush=True)
        return
    failed = f", {progress.failed} failed" if progress.failed else ""
    jobs = f" ({progress.jobs[0]} of {progress.jobs[1]} jobs)" if progress.jobs[1] else ""
    print(f"sweep: {progress.done} of {progress.total} configs done{failed}{jobs}", file=sys.stderr, flush=True)


def summary_lines(swept: stage.Swept) -> list[str]:
    """The configs as aligned plain lines, best cross-validated score first (the score shown: the mean of the three
    cross-validated figures, with the decimals that tell them apart); test figures are shown, never ranked on."""
    header = ("config", "method", "cv score", "cv seg. %", "cv frame %", "cv edit", "test seg. %", "test frame %",
              "test edit")
    rows = [header]
    places = _places([v for v in swept.table["cv_score"].to_list() if v is not None])
    for row in swept.table.sort("cv_score", descending=True, nulls_last=True, maintain_order=True).iter_rows(
            named=True):
        if row["status"] != stage.results.DONE:
            rows.append((row["config"], "failed", *("–" for _ in range(7))))
            continue
        rows.append((row["config"], row["method"], f"{row['cv_score']:.{places}f}",
                     *(f"{row[f'cv_{f}']:.1f} ± {row[f'cv_{f}_std']:.1f}" for f in stage.results.FIGURES),
                     *(f"{row[f'test_{f}']:.1f}" for f in stage.results.FIGURES)))
    widths = [max(len(r[i]) for r in rows) for i in range(len(header))]
    return ["  ".join(cell.ljust(w) for cell, w in zip(r, widths)).rstrip() for r in rows]


def _places(scores: list[float]) -> int:
    """The decimals (1 to 4) at which scores that differ are shown different: the rank they give, readable."""
    for places in range(1, 5):
        if len({round(v, places) for v in scores}) == len(set(scores)):
            return places
    return 4
