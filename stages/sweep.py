"""sweep: a grid of train/conflate/export options times seeds on one dataset, run as a Snakemake workflow.

:func:`plan` reads and checks the sweep file, the dataset's inputs and the cluster profile (nothing runs);
:func:`run` writes OUT/Snakefile and OUT/sweep.json, runs Snakemake (locally, or through its SLURM executor
with a profile) and gathers OUT/results.parquet. Snakemake's bookkeeping makes a rerun do only what is
missing or stale, and an interrupted sweep resume.
"""

from __future__ import annotations

import enum
import importlib.util
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl

from mlnseq.catalog import artifacts, errors
from mlnseq.catalog.errors import BadInput, MlnseqError
from mlnseq.sweeps import grid, results, workflow

PROFILE_FILES = ("config.v9+.yaml", "config.v8+.yaml", "config.yaml")  # the names Snakemake looks for


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
    best: dict[str, Any]


def plan(sweep_file: Path, options: SweepOptions, stages: grid.StageOptions) -> grid.Sweep:
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
               "--directory", str(out.resolve()), "--rerun-incomplete"]
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


def run_snakemake(command: list[str]) -> int:
    """Snakemake as a process, its output on stderr; on Ctrl-C (which reaches it too) wait while it stops its jobs
    and unlocks the folder, so that the next run resumes."""
    process = subprocess.Popen(command, stdout=sys.stderr)
    try:
        return process.wait()
    except KeyboardInterrupt:
        process.wait()
        raise


def run(sweep_file: Path, options: SweepOptions, stages: grid.StageOptions) -> Swept:
    """Run the sweep (only what is missing or stale) and gather OUT/results.parquet."""
    sweep = plan(sweep_file, options, stages)
    if not installed("snakemake"):
        raise BadInput("mlnseq sweep runs on Snakemake, which is not installed: "
                       f"{errors.install_hint('sweep')} (make setup installs it)")
    if options.executor is Executor.SLURM and not installed("snakemake_executor_plugin_slurm"):
        raise BadInput(f"--executor slurm needs Snakemake's SLURM executor: {errors.install_hint('sweep')}")
    out = options.out_dir(sweep)
    snakefile = workflow.write(sweep, out, mlnseq_command())
    code = run_snakemake(snakemake_command(snakefile, out, options))
    if code != 0:
        raise MlnseqError(f"the sweep's workflow failed (snakemake exit {code}): see its output above and "
                          f"the stage logs in {out / workflow.RUNS}/CONFIG/seed-N/logs/; rerun `mlnseq sweep` to "
                          "resume")
    table = results.gather(sweep, out)
    return Swept(results.write(table, sweep, out), table, results.best(table))
