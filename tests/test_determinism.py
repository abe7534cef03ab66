"""Determinism: the same seed and inputs give the same artifacts, run after run.

With ``SOURCE_DATE_EPOCH`` set (the reproducible-builds convention, honoured by artifacts.created_time)
every file of two runs is byte-identical. Without it the files differ only in the creation time of
their metadata: the data and the rest of the metadata are equal.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts
from mlnseq import collect

runner = CliRunner()
EPOCH = "1700000000"


def snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def ok(*args) -> None:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output


def pipeline(workdir: Path, source: Path) -> None:
    """The bare DESK pipeline, every stage through the CLI; lstm and priorlayer trained 2 epochs."""
    ok("collect", "--env", "desk", "--source", source, "-w", workdir)
    ok("binarize", "-w", workdir)
    ok("formulas", "-w", workdir)
    ok("learn-weights", "-w", workdir)
    ok("train", "--epochs", 2, "--seed", 3, "-w", workdir)
    ok("train", "--method", "priorlayer", "--epochs", 2, "--seed", 3, "-w", workdir)
    ok("conflate", "-w", workdir)
    ok("eval", "-w", workdir)


EXPECTED = {artifacts.FRAMES, artifacts.PREDICATES, artifacts.FORMULAS, artifacts.WEIGHTS, artifacts.LEARNED_MLN,
            "models/lstm.pt", "models/lstm.log.parquet", "models/priorlayer.pt", "models/priorlayer.log.parquet",
            artifacts.PREDICTIONS, artifacts.METRICS,
            "models/lstm.log-probs.npy", "models/priorlayer.log-probs.npy"}  # conflate's cache of the networks' output


@pytest.mark.slow
def test_two_runs_of_every_stage_are_byte_identical(tmp_path, shared_data, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", EPOCH)
    first, second = tmp_path / "first", tmp_path / "second"
    pipeline(first, shared_data / "desk-taurus")
    pipeline(second, shared_data / "desk-taurus")
    assert set(snapshot(first)) == EXPECTED
    assert snapshot(first) == snapshot(second)
    _, meta = artifacts.read_table(first / artifacts.METRICS, "metrics")
    assert meta["created"] == "2023-11-14T22:13:20+00:00"


@pytest.mark.slow
def test_a_different_seed_gives_a_different_model(tmp_path, desk_frames_workdir, monkeypatch):
    """The comparison above can fail: the seed reaches the checkpoint's bytes."""
    monkeypatch.setenv("SOURCE_DATE_EPOCH", EPOCH)
    digests = []
    for seed in (3, 4):
        workdir = tmp_path / f"seed{seed}"
        workdir.mkdir()
        shutil.copy(desk_frames_workdir / artifacts.FRAMES, workdir / artifacts.FRAMES)
        ok("train", "--epochs", 1, "--seed", seed, "-w", workdir)
        digests.append(snapshot(workdir)["models/lstm.pt"])
    assert digests[0] != digests[1]


def without_created(path: Path) -> tuple:
    table = pq.read_table(path)
    meta = json.loads(table.schema.metadata[artifacts.META_KEY])
    assert meta.pop("created")
    return table.replace_schema_metadata(None), meta


@pytest.mark.mujoco
def test_fetch_collection_is_deterministic_but_for_the_creation_time(tmp_path, monkeypatch):
    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    options = collect.CollectOptions(env="fetch", episodes=3, seed=5, goals=True)
    paths = [collect.run(tmp_path / name, options)[0] for name in ("a", "b")]
    (table_a, meta_a), (table_b, meta_b) = map(without_created, paths)
    assert table_a.equals(table_b) and meta_a == meta_b
    other = collect.run(tmp_path / "c", collect.CollectOptions(env="fetch", episodes=3, seed=6, goals=True))[0]
    assert not without_created(other)[0].equals(table_a)


def test_source_date_epoch_must_be_a_number(tmp_path, desk_frames_workdir, monkeypatch):
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "yesterday")
    shutil.copy(desk_frames_workdir / artifacts.FRAMES, tmp_path / artifacts.FRAMES)
    result = runner.invoke(app, ["binarize", "-w", str(tmp_path)])
    assert result.exit_code == 2 and "SOURCE_DATE_EPOCH='yesterday'" in result.stderr
    assert not (tmp_path / artifacts.PREDICATES).exists()
