"""A sweep: a grid of train/conflate/export options times seeds on one dataset, run as a Snakemake workflow of the
stage commands, callable from Python (``mlnseq.sweep``) as from the command line.

``SWEPT`` is the stages a grid sets: their options dataclasses and the fields their commands take as options (a
grid key is one of those, since the workflow runs the commands). :func:`plan` reads and checks the sweep file, the
dataset's inputs and the cluster profile (nothing runs);
:func:`run` writes OUT/Snakefile and OUT/sweep.json, runs Snakemake (locally, or through its SLURM executor
with a profile; its own output to OUT/sweep.log, the progress to a callback) and gathers OUT/results.parquet.
Snakemake's bookkeeping makes a rerun do only what is missing or stale, and an interrupted sweep resume. A job that
fails (killed, cancelled on the cluster, out of disk) fails its config alone: the others run on (``--keep-going``),
the table marks it, and the next run redoes what is missing.
"""

from __future__ import annotations

import enum
import importlib.util
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import polars as pl

from mlnseq import conflate, export, train
from mlnseq.catalog import artifacts, errors
from mlnseq.catalog.errors import BadInput, MlnseqError
from mlnseq.sweeps import grid, results, running, workflow

PROFILE_FILES = ("config.v9+.yaml", "config.v8+.yaml", "config.yaml")  # the names Snakemake looks for
OPTIONS = {"train": train.TrainOptions, "conflate": conflate.ConflateOptions, "export": export.ExportOptions}
NOT_COMMAND_OPTIONS = {"train": ("hidden_size", "learning_rate", "val_fraction")}  # fields no command flag sets
SWEPT = grid.StageOptions(OPTIONS, {stage: [f.name for f in fields(options) if f.name not in
                                            NOT_COMMAND_OPTIONS.get(stage, ())] for stage, options in OPTIONS.items()})


class Executor(enum.Enum):
    """Where Snakemake runs the rules."""

    LOCAL = "local"
    SLURM = "slurm"


@dataclass(frozen=True)
class SweepOptions:
    """Options of `mlnseq sweep`."""

    cores: int | None = None  # local: cores Snakemake uses (default: all); slurm: jobs at once (default: profile's)
    executor: Executor = Executor.LOCAL
    profile: Path | None = None  # a Snakemake profile folder (slurm: resources, partition, status command)
    out: Path | None = None  # default: sweep/ beside the sweep file
    limit: int | None = grid.MAX_CONFIGS  # refuse a larger grid; None (--yes): no limit

    def validate(self) -> None:
        if self.cores is not None and self.cores < 1:
            raise BadInput(f"--cores must be at least 1, got {self.cores}")
        if self.executor is Executor.SLURM and self.profile is None:
            raise BadInput("--executor slurm needs --profile DIR, a Snakemake profile for the cluster "
                           "(examples/sweep/slurm-profile is one for a one-node cluster)")

    def out_dir(self, sweep: grid.Sweep) -> Path:
        return Path(self.out) if self.out is not None else sweep.path.parent / "sweep"


@dataclass(frozen=True)
class Swept:
    path: Path  # OUT/results.parquet
    table: pl.DataFrame
    best: dict[str, Any] | None  # None when no config finished
    failures: list[results.Failure] = field(default_factory=list)
    log: Path | None = None  # OUT/sweep.log, Snakemake's own output
    log_error: str | None = None  # the log could not be written (a full disk)
    write_error: str | None = None  # results.parquet could not be written (then ``path`` is None): nothing half-written


@dataclass(frozen=True)
class Progress:
    """How far a sweep is: configs done and failed of all, and Snakemake's jobs done of its plan for this run."""

    done: int
    failed: int
    total: int
    jobs: tuple[int, int]
    log: Path  # where Snakemake's own output goes
    starting: bool = False  # before Snakemake runs: ``done`` are the configs finished by an earlier run


def plan(sweep_file: Path, options: SweepOptions = SweepOptions(), stages: grid.StageOptions = SWEPT) -> grid.Sweep:
    """The sweep file read and checked against the stages' options (``stages``: train, conflate and export's
    dataclasses), with the dataset's inputs and the profile: any error comes before anything runs."""
    options.validate()
    sweep = grid.read(sweep_file, stages)
    if options.limit is not None and len(sweep.configs) > options.limit:
        raise BadInput(f"{sweep_file}: the grid has {len(sweep.configs):,} configs (x {len(sweep.seeds)} seeds), over "
                       f"{options.limit:,}; shrink it or add --yes to run them all")
    for name in workflow.SHARED_INPUTS:
        path = sweep.workdir / name
        if not path.exists():
            raise BadInput(f"{sweep_file}: the dataset workdir's {path} not found; run `mlnseq "
                           f"{artifacts.producer_of(path)} --workdir {sweep.workdir}` first (a sweep's "
                           "cross-validation needs the fold weights of `learn-weights --folds K`)")
    if options.profile is not None:
        check_profile(Path(options.profile))
    return sweep


def check_profile(profile: Path) -> dict[str, Any]:
    """A Snakemake profile folder's settings; a missing folder or file, or YAML that does not parse, is refused."""
    import yaml

    found = [profile / name for name in PROFILE_FILES if (profile / name).is_file()]
    if not profile.is_dir() or not found:
        raise BadInput(f"--profile {profile}: not a Snakemake profile folder (it needs a config.yaml)")
    try:
        settings = yaml.safe_load(found[0].read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
        mark = getattr(error, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        problem = getattr(error, "problem", None) or error
        raise BadInput(f"--profile: {found[0]}{line} does not parse as YAML: {problem}") from None
    if not isinstance(settings, dict):
        raise BadInput(f"--profile: {found[0]} must hold a mapping of Snakemake options (key: value lines)")
    return settings


def mlnseq_command() -> str:
    """This installation's `mlnseq` (the one beside the running Python, else the first on PATH)."""
    beside = Path(sys.executable).with_name("mlnseq")
    if beside.exists():
        return str(beside)
    found = shutil.which("mlnseq")
    if found is None:
        raise MlnseqError("no `mlnseq` command beside this Python or on PATH; run `make setup`")
    return found


def snakemake_command(snakefile: Path, out: Path, options: SweepOptions) -> list[str]:
    command = [sys.executable, "-m", "snakemake", "--snakefile", str(snakefile.resolve()),
               "--directory", str(out.resolve()), "--rerun-incomplete", "--keep-going"]
    if options.executor is Executor.SLURM:
        command += ["--executor", "slurm", "--profile", str(Path(options.profile).resolve())]
        return command + (["--jobs", str(options.cores)] if options.cores else [])
    return command + ["--cores", str(options.cores or os.cpu_count() or 1)]


def installed(module: str) -> bool:
    """Whether ``module`` can be imported here (without importing it)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ValueError, ImportError):  # a module blocked in sys.modules
        return False


def sweep(sweep_file: Path, options: SweepOptions = SweepOptions(),
          progress: Callable[[Progress], None] = lambda _: None, stages: grid.StageOptions = SWEPT) -> Swept:
    """Run the sweep (only what is missing or stale) and gather OUT/results.parquet, the failed configs marked."""
    planned = plan(sweep_file, options, stages)
    if not installed("snakemake"):
        raise BadInput("mlnseq sweep runs on Snakemake, which is not installed: "
                       f"{errors.install_hint('sweep')} (make setup installs it)")
    if options.executor is Executor.SLURM and not installed("snakemake_executor_plugin_slurm"):
        raise BadInput(f"--executor slurm needs Snakemake's SLURM executor: {errors.install_hint('sweep')}")
    out = options.out_dir(planned)
    snakefile = workflow.write(planned, out, mlnseq_command())
    done = Counting(planned, out, progress)
    ran = running.run_snakemake(snakemake_command(snakefile, out, options), out / running.LOG, done.heard)
    done.heard(ran, finished=True)
    if ran.code != 0 and not ran.errors:  # Snakemake itself failed: no job to blame
        raise MlnseqError(f"the sweep's workflow failed (snakemake exit {ran.code}): {ran.last_line or 'no output'}; "
                          f"see {out / running.LOG}"
                          f"{'' if ran.log_error is None else f' ({ran.log_error})'}; rerun `mlnseq sweep` to resume")
    table, failures = results.gather(planned, out, ran.errors)
    path, write_error = None, None
    try:
        path = results.write(table, planned, out)
    except BadInput as error:  # the disk is full (or the folder not writable): nothing half-written
        write_error = str(error).replace("; choose a writable --workdir", ": nothing of it was written")
    return Swept(path, table, results.best(table), failures, out / running.LOG, ran.log_error, write_error)


class Counting:
    """Turns what Snakemake says into `Progress`: configs whose every seed's metrics are written, configs a failed job
    belongs to; the callback hears each change."""

    def __init__(self, sweep: grid.Sweep, out: Path, progress: Callable[[Progress], None]):
        self.sweep, self.out, self.progress = sweep, out, progress
        self.said: tuple[int, int] | None = None
        self.jobs: tuple[int, int] = (0, 0)  # the jobs' count last said
        self.heard(running.Run(), starting=True)

    def heard(self, ran: running.Run, starting: bool = False, finished: bool = False) -> None:
        done = sum(all(workflow.run_dir(self.out, c.name, s).joinpath(artifacts.METRICS).exists()
                       for s in self.sweep.seeds) for c in self.sweep.configs)
        failed_logs = {log for error in ran.errors for log in error.logs}
        failed = sum(any(log.startswith(f"{workflow.RUNS}/{c.name}/") for log in failed_logs)
                     for c in self.sweep.configs)
        if (done, failed) != self.said or (finished and ran.jobs != self.jobs):  # the last line: every job counted
            self.said, self.jobs = (done, failed), ran.jobs
            self.progress(Progress(done, failed, len(self.sweep.configs), ran.jobs, self.out / running.LOG, starting))
