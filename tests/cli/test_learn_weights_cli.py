"""`mlnseq learn-weights` through the CLI: the table of strongest formulas and clear errors."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from stages.mln.published_codes import desk_predicates, write_predicates

runner = CliRunner()


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    """Errors as users see them: one line, no traceback (another test may have set --verbose)."""
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


def test_learn_weights_prints_the_strongest_formulas(tmp_path: Path, shared_data: Path) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data), "desk")
    assert runner.invoke(app, ["formulas", "-w", str(tmp_path)]).exit_code == 0
    result = runner.invoke(app, ["learn-weights", "-w", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert 'Has("grippers_closed_closed",p) => Topic("C4",p)' in result.output
    weights = pl.read_parquet(tmp_path / "weights.parquet")
    assert weights.height == 119 and (tmp_path / "learned.mln").exists()


def test_formulas_path_relative_to_cwd_then_workdir(tmp_path: Path, shared_data: Path, monkeypatch) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data, train_limit=100), "desk")
    (tmp_path / "mine.mln").write_text('Has(word, page)\nTopic(class, page)\n0.0 Has("left_gripper_open",p) => Topic("C0",p)\n')
    monkeypatch.chdir(tmp_path.parent)
    result = runner.invoke(app, ["learn-weights", "mine.mln", "-w", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert pl.read_parquet(tmp_path / "weights.parquet").height == 1


def test_bad_engine_and_class_never_in_training(tmp_path: Path, shared_data: Path) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data, train_limit=100), "desk")
    assert runner.invoke(app, ["formulas", "-w", str(tmp_path)]).exit_code == 0
    result = runner.invoke(app, ["learn-weights", "--engine", "alchemy", "-w", str(tmp_path)])
    assert result.exit_code == 2 and result.stderr.strip() == "error: unknown --engine 'alchemy': choose one of native, pracmln"
    result = runner.invoke(app, ["learn-weights", "-w", str(tmp_path)])
    assert result.exit_code == 0 and "class C6 never occurs in the training split" in result.output


def test_missing_formulas_names_the_stage(tmp_path: Path, shared_data: Path) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data, train_limit=100), "desk")
    result = runner.invoke(app, ["learn-weights", "-w", str(tmp_path)])
    assert result.exit_code == 2 and "run `mlnseq formulas` first" in result.stderr
    assert not (tmp_path / "weights.parquet").exists()
