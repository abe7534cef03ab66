"""docs/recordings.md's worked example, as the docs test ran it (its script saved as the page says, then its
commands, in the page's own folder): what it wrote is what the page says."""

from __future__ import annotations

import polars as pl
import pytest

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")

pytestmark = pytest.mark.slow


def test_the_worked_example_wrote_what_the_page_says(doc_runs):
    run = doc_runs.run_to("docs/recordings.md")
    folder = run.folder
    printed = " ".join(" ".join(p.text.split()) for p in run.printed)
    assert "labelled recordings" in printed  # the model's label topic, found in the new bag
    predictions = pl.read_parquet(folder / "new_trial.predictions.parquet")
    assert predictions["episode"].unique().to_list() == ["new_trial"]
    segments = pl.read_csv(folder / "new_trial.csv")
    assert segments.columns == ["episode", "start", "end", "label"] and (folder / "new_trial.rrd").stat().st_size > 0
    relabelled = pl.read_parquet(folder / "relabelled" / "frames.parquet")
    assert relabelled.height == predictions.height
