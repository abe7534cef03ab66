"""A full disk under a sweep: the tiny sweep's finished folder on a real small filesystem (a tmpfs mounted here as
root), one config's eval to redo, and the disk filled (and kept full) once that eval runs. The sweep ends in error
lines naming the config, the full folder and results.parquet, with nothing half-written; freed, the next run redoes
the eval alone and gives the table of the sweep that never ran out of space. Without root or mount it skips saying
why, except under CI (CI=true), where it fails."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import threading
import time
from pathlib import Path

import polars as pl
import pytest

from sweep_files import mlnseq


@contextlib.contextmanager
def small_disk(folder: Path, megabytes: int):
    folder.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={megabytes}m", "tmpfs", str(folder)],
                          capture_output=True, text=True)
    if done.returncode:
        why = f"cannot mount a tmpfs here ({done.stderr.strip() or 'mount failed'}): run the test as root"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(why)
        pytest.skip(why)
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


class Filler(threading.Thread):
    """Once `mlnseq eval` runs in ``out`` (Snakemake's folder), fill its disk and keep it full (space freed by a
    failed write is taken again) until ``stop``."""

    def __init__(self, out: Path):
        super().__init__(daemon=True)
        self.out, self.stop, self.full = out, threading.Event(), threading.Event()

    def run(self) -> None:
        while not self.stop.is_set() and not eval_runs_in(self.out):
            time.sleep(0.01)
        with open(self.out.parent / "filler", "wb", buffering=0) as filler:
            while not self.stop.is_set():
                for size in (1 << 20, 4096, 1):
                    with contextlib.suppress(OSError):
                        while True:
                            filler.write(b"\0" * size)
                self.full.set()
                time.sleep(0.005)


def eval_runs_in(folder: Path) -> bool:
    for pid in filter(str.isdigit, os.listdir("/proc")):
        with contextlib.suppress(OSError):
            words = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            if any(w.endswith(b"mlnseq") for w in words[:2]) and b"eval" in words[1:3] \
                    and Path(f"/proc/{pid}/cwd").resolve() == folder.resolve():
                return True
    return False


def test_a_full_disk_fails_the_sweep_naming_the_files_and_nothing_is_half_written(local_sweep, tmp_path):
    source = local_sweep["out"]
    size = sum(p.stat().st_size for p in source.rglob("*") if p.is_file() and not p.is_symlink())
    with small_disk(tmp_path / "disk", size // 2**20 + 8) as disk:
        out = disk / "sweep"
        shutil.copytree(source, out, symlinks=True)
        before = (out / "results.parquet").read_bytes()
        stale = out / "runs" / "cell-tcn" / "seed-1" / "metrics.parquet"
        stale.unlink()
        filler = Filler(out)
        filler.start()
        try:
            full = mlnseq("sweep", str(local_sweep["path"]), "--cores", "2", "--out", str(out), cwd=tmp_path)
        finally:
            filler.stop.set()
            filler.join()
        assert filler.full.is_set()
        (disk / "filler").unlink()
        assert full.returncode == 1, full.stderr[-3000:]
        errors = [line for line in full.stderr.splitlines() if line.startswith("error:")]
        assert errors[0] == (f"error: config cell-tcn failed: eval of seed 1 failed (exit 1) and its log is empty: No "
                             f"space left on device in {stale.parent / 'logs'}; its log: {stale.parent}/logs/eval.log")
        assert errors[1].startswith(f"error: cannot write {out / 'results.parquet'}: ")  # pyarrow's words, then
        assert errors[1].endswith("No space left on device: nothing of it was written")
        assert (out / "results.parquet").read_bytes() == before and not stale.exists()  # nothing half-written
        assert not [p for p in out.rglob("*.tmp")]
        for path in out.rglob("*.parquet"):
            pl.read_parquet(path)
        again = mlnseq("sweep", str(local_sweep["path"]), "--cores", "2", "--out", str(out), cwd=tmp_path)
        assert again.returncode == 0, again.stderr[-3000:]
        log = (out / "sweep.log").read_text()
        assert "rule eval:" in log and "rule train:" not in log and "rule conflate:" not in log
        table = pl.read_parquet(out / "results.parquet")
        assert table.drop("deploy").equals(pl.read_parquet(source / "results.parquet").drop("deploy"))
