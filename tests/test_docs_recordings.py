"""docs/recordings.md's worked example runs as written: its script, then its commands, in a fresh folder."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "recordings.md"

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")


@pytest.mark.slow
def test_the_worked_example_runs_as_documented(tmp_path: Path) -> None:
    text = DOC.read_text()
    (tmp_path / "make_bags.py").write_text(re.search(r"```python\n(.*?)```", text, re.S).group(1))
    block = re.search(r"```bash\n(.*?)```", text, re.S).group(1)
    commands = [line.split("  #", 1)[0].strip() for line in block.splitlines() if line.strip()]
    assert len(commands) == 6
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    outputs = []
    for command in commands:
        done = subprocess.run(command, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True)
        assert done.returncode == 0, f"{command}: {done.stderr}"
        outputs.append(" ".join(done.stdout.split()))
    assert "4 episodes" in outputs[1] and "6 features" in outputs[1]
    assert "labelled recordings" in outputs[4]  # the model's label topic, found in the new bag
    predictions = pl.read_parquet(tmp_path / "new_trial.predictions.parquet")
    assert predictions["episode"].unique().to_list() == ["new_trial"]
    segments = pl.read_csv(tmp_path / "new_trial.csv")
    assert segments.columns == ["episode", "start", "end", "label"] and (tmp_path / "new_trial.rrd").stat().st_size > 0
    relabelled = pl.read_parquet(tmp_path / "relabelled" / "frames.parquet")
    assert relabelled.height == predictions.height
