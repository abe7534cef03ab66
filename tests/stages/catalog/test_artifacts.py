"""artifacts: atomic writes clean up after writers that were killed, never after one still writing."""

from __future__ import annotations

import os
import subprocess
import sys

import polars as pl

from mlnseq.catalog import artifacts


def finished_pid() -> int:
    """The id of a process that has ended (its temporary files are leftovers)."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


def test_a_write_removes_the_leftovers_of_killed_writers_of_that_artifact(tmp_path):
    dead = finished_pid()
    gone = [tmp_path / f".frames.parquet.{dead}.k3j9x_2a.tmp", tmp_path / ".frames.parquet.qz81mw0c.tmp",
            tmp_path / f"..frames.parquet.{dead}.a.tmp.{dead}.b.tmp"]  # a temp's own temp; an older name
    kept = [tmp_path / ".predicates.parquet.1.a.tmp", tmp_path / "notes.tmp", tmp_path / ".frames.parquet"]
    for path in gone + kept:
        path.write_bytes(b"half a file")
    artifacts.write_table(pl.DataFrame({"a": [1]}), tmp_path / "frames.parquet", "frames", {})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in [*kept, tmp_path / "frames.parquet"])


def test_a_write_in_progress_keeps_its_temporary_file(tmp_path):
    with subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) as writer:
        try:
            busy = tmp_path / f".REPORT.md.{writer.pid}.x81kq0zz.tmp"
            busy.write_text("still being written")
            artifacts.write_text(tmp_path / "REPORT.md", "# report\n")
            assert busy.exists() and (tmp_path / "REPORT.md").read_text() == "# report\n"
        finally:
            writer.kill()
    assert artifacts.remove_leftovers(tmp_path / "REPORT.md") == [busy]


def test_the_temporary_file_is_named_after_the_artifact_and_the_writer(tmp_path):
    with artifacts.atomic_path(tmp_path / "weights.parquet") as tmp:
        assert tmp.parent == tmp_path and tmp.name.startswith(f".weights.parquet.{os.getpid()}.")
        assert tmp.name.endswith(".tmp")
        tmp.write_text("x")
    assert [p.name for p in tmp_path.iterdir()] == ["weights.parquet"]


def test_own_metadata_drops_exactly_the_envelope_a_write_adds(tmp_path):
    path = artifacts.write_table(pl.DataFrame({"a": [1]}), tmp_path / "t.parquet", "frames", {"classes": ["x"]})
    meta = artifacts.read_metadata(path, "frames")
    assert set(meta) == {*artifacts.ENVELOPE, "classes"}
    assert artifacts.own_metadata(meta) == {"classes": ["x"]}


def test_a_file_changed_in_place_is_digested_anew(tmp_path, shared_data):
    """The digests a process keeps serve a file only while it is the same file: rewritten in place with the same
    size (a new modification time) or replaced by another file (a new inode), its digest is read again."""
    path = tmp_path / "motion.txt"
    original = (shared_data / "desk-taurus" / "taurus_motion_train.txt").read_bytes()
    path.write_bytes(original)
    first = artifacts.file_digest(path)
    assert artifacts.file_digest(path) == first
    changed = bytes([original[0] ^ 1]) + original[1:]
    with open(path, "r+b") as handle:
        handle.write(changed[:1])
    status = os.stat(path)
    os.utime(path, ns=(status.st_atime_ns, status.st_mtime_ns + 1_000_000))
    second = artifacts.file_digest(path)
    assert second != first
    replacement = tmp_path / "replacement.txt"
    replacement.write_bytes(original)
    os.replace(replacement, path)
    assert artifacts.file_digest(path) == first
