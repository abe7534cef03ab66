"""`mlnseq formulas` through the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.mln.published_codes import desk_predicates, write_predicates

runner = CliRunner()


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    """Errors as users see them: one line, no traceback (another test may have set --verbose)."""
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


def test_formulas_writes_the_template(tmp_path: Path, shared_data: Path) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data, train_limit=300), "desk")
    result = runner.invoke(app, ["formulas", "--workdir", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "(1 formula of which 1 with +variables; " in result.output
    assert "Has(+w,p) => Topic(+c,p)" in (tmp_path / "formulas.mln").read_text()


def test_syntax_error_is_one_line_with_position(tmp_path: Path, shared_data: Path) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data, train_limit=300), "desk")
    spec = tmp_path / "bad.mln"
    spec.write_text("Has(word, page)\nTopic(class, page)\n0.0 Has(+w, p) => => Topic(+c, p)\n")
    result = runner.invoke(app, ["formulas", "--spec", str(spec), "--workdir", str(tmp_path)])
    assert result.exit_code == 2
    assert result.stderr.strip().splitlines() == [f"error: {spec}:3:19: expected a predicate, '!' or '(', found '=>'"]
    assert not (tmp_path / "formulas.mln").exists()


def test_missing_predicates_names_binarize(tmp_path: Path) -> None:
    result = runner.invoke(app, ["formulas", "--workdir", str(tmp_path)])
    assert result.exit_code == 2 and "run `mlnseq binarize` first" in result.stderr
