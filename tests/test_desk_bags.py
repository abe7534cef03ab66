"""tests/desk_bags.py as the README and docs/deploy.md run it: a second run in the same folder says the bags
are there (no traceback), and a folder in the way is one line, exit 2, nothing removed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")

SCRIPT = Path(__file__).resolve().parent / "desk_bags.py"


def desk_bags(folder: Path, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(SCRIPT), str(folder)], cwd=cwd, capture_output=True, text=True)


def test_run_twice_the_second_run_says_the_bags_are_there(tmp_path):
    first = desk_bags(tmp_path / "bags", tmp_path)
    assert first.returncode == 0, first.stderr
    written = sorted(p.name for p in (tmp_path / "bags").iterdir())
    assert written == [f"trial_{k}" for k in range(1, 7)] and (tmp_path / "bags-heldout" / "trial_7").is_dir()
    second = desk_bags(tmp_path / "bags", tmp_path)
    assert second.returncode == 0 and second.stderr == ""
    assert "there already: nothing to do" in second.stdout


def test_a_folder_in_the_way_is_one_line_and_kept(tmp_path):
    (tmp_path / "bags").mkdir()
    (tmp_path / "bags" / "mine.txt").write_text("a user's file")
    done = desk_bags(tmp_path / "bags", tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'bags'} exists and is not the bags this script writes: remove it or name another folder"]
    assert (tmp_path / "bags" / "mine.txt").read_text() == "a user's file" and not (tmp_path / "bags-heldout").exists()
