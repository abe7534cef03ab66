"""Snakemake run as a process for a sweep: its own output goes to the sweep's log (OUT/sweep.log), and is read as it
comes for the progress (a callback hears the configs done, failed and the jobs done each time they change) and for
the jobs that failed (each Error block: its rule, the logs it names, the exit status or the cluster's message).

A log that cannot be written (a full disk) does not stop the sweep: the run goes on, its last lines are kept here,
and the error is reported with the rest.
"""

from __future__ import annotations

import collections
import re
import subprocess
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

LOG = "sweep.log"
TAIL_LINES = 40  # of Snakemake's output, kept for a failure that names no job
STEPS = re.compile(r"^(\d+) of (\d+) steps \(.*\) done")
EXIT_STATUS = re.compile(r"returned non-zero exit status (-?\d+)")
ERROR = re.compile(r"^Error in rule (\w+):")
SLURM_STATUS = re.compile(r"SLURM-job '(\w+)' failed, SLURM status is: '(\w+)'")


@dataclass
class JobError:
    """A job Snakemake reported failed: its rule, the logs its block names, and why (an exit status, or a message)."""

    rule: str
    logs: list[str] = field(default_factory=list)
    status: int | None = None
    message: str | None = None

    def reason(self) -> str:
        """Why, in words: killed by a signal, cancelled on the cluster, or the exit status."""
        slurm = SLURM_STATUS.search(self.message or "")
        if slurm:
            return f"ended on the cluster with status {slurm.group(2)} (SLURM job {slurm.group(1)})"
        if self.status is not None and self.status > 128:
            import signal

            try:
                return f"was killed ({signal.Signals(self.status - 128).name})"
            except ValueError:
                pass
        if self.status is not None:
            return f"failed (exit {self.status})"
        return "failed"


@dataclass
class Run:
    """What one Snakemake run said: its exit code, its jobs' errors, its last lines, and a log write that failed."""

    code: int = 0
    errors: list[JobError] = field(default_factory=list)
    tail: collections.deque = field(default_factory=lambda: collections.deque(maxlen=TAIL_LINES))
    log_error: str | None = None
    jobs: tuple[int, int] = (0, 0)  # done, of

    @property
    def last_line(self) -> str:
        return last_line(self.tail)


def last_line(lines: Iterable[str]) -> str:
    """The last line that is not blank, stripped ('' where there is none)."""
    return next((line.strip() for line in reversed(list(lines)) if line.strip()), "")


class Reader:
    """Snakemake's output line by line: into the log, the tail, the jobs' errors and the progress."""

    def __init__(self, log: Path, progress: Callable[[Run], None]):
        self.run, self.progress = Run(), progress
        self.log_path = log
        self.status: int | None = None  # the exit status a shell command reported, for the Error block after it
        self.block: JobError | None = None
        try:
            self.log = open(log, "w", encoding="utf-8")
        except OSError as error:
            self.log, self.run.log_error = None, f"cannot write {log}: {error.strerror or error}"

    def line(self, text: str) -> None:
        self._write(text)
        stripped = text.rstrip("\n")
        self.run.tail.append(stripped)
        self._parse(stripped)

    def _write(self, text: str) -> None:
        if self.log is None:
            return
        try:
            self.log.write(text)
            self.log.flush()
        except OSError as error:
            self.run.log_error = f"cannot write {self.log_path}: {error.strerror or error}"
            self._close()

    def _parse(self, line: str) -> None:
        if self.block is not None:
            if line.startswith("    "):
                key, _, value = line.strip().partition(": ")
                if key == "log":
                    self.block.logs = [p.strip() for p in value.split(" (check log")[0].split(",") if p.strip()]
                elif key == "message" and value != "None":
                    self.block.message = value
                return
            self.block = None
        error, status, steps = ERROR.match(line), EXIT_STATUS.search(line), STEPS.match(line)
        if status:
            self.status = int(status.group(1))
        elif error:
            self.block = JobError(error.group(1), status=self.status)
            self.run.errors.append(self.block)
            self.status = None
            self.progress(self.run)
        elif steps:  # after each job's `Finished jobid` line: the progress hears the count with the job in it
            self.run.jobs = (int(steps.group(1)), int(steps.group(2)))
            self.progress(self.run)

    def _close(self) -> None:
        if self.log is not None:
            try:
                self.log.close()
            except OSError:
                pass
            self.log = None

    def close(self, code: int) -> Run:
        self._close()
        self.run.code = code
        return self.run


def run_snakemake(command: list[str], log: Path, progress: Callable[[Run], None]) -> Run:
    """Run Snakemake, its output (stdout and stderr) read line by line into ``log``; on Ctrl-C (which reaches it
    too) read on while it stops its jobs and unlocks its folder, so that the next run resumes."""
    reader = Reader(log, progress)
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
                               errors="replace")
    try:
        for text in process.stdout:
            reader.line(text)
    except KeyboardInterrupt:
        for text in process.stdout:
            reader.line(text)
        process.wait()
        reader.close(process.returncode)
        raise
    return reader.close(process.wait())
