"""Fixtures of the sweep tests: a tiny DESK dataset workdir with fold weights, and sweep files over it."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
TEST_FRAMES = 1500  # the DESK test split's first frames kept (all 1,405 training frames are)


@pytest.fixture(scope="session")
def tiny_desk_workdir(tmp_path_factory, desk_frames_workdir) -> Path:
    """DESK's training recording and the first 1,500 test frames, their predicates, examples/temporal.mln and its
    weights learned with 3 folds (`learn-weights --folds 3`): a dataset workdir a sweep runs on; read-only."""
    import polars as pl

    from mlnseq import binarize, formulas, learn_weights
    from mlnseq.catalog import artifacts

    workdir = tmp_path_factory.mktemp("tiny-desk")
    frames, meta = artifacts.read_table(desk_frames_workdir / artifacts.FRAMES, "frames")
    test_rows = frames.filter(pl.col("split") == "test").head(TEST_FRAMES)
    tiny = pl.concat([frames.filter(pl.col("split") == "train"), test_rows])
    kept = {k: v for k, v in meta.items() if k not in ("schema_version", "kind", "mlnseq_version", "created", "inputs")}
    artifacts.write_table(tiny, workdir / artifacts.FRAMES, "frames", kept)
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=REPO / "examples" / "temporal.mln"))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions(folds=3))
    return workdir
