"""`mlnseq learn-weights` through the CLI: the table of strongest formulas and clear errors."""

from __future__ import annotations

from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.mln import cll
from mlnseq.mln.published_codes import desk_predicates, write_predicates

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
    assert 'Has("grippers_closed_closed",p) => Topic("S5",p)' in result.output
    assert "│ S5 " in result.output  # the class column too, as the frames name it
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
    assert result.exit_code == 0 and "class S7 never occurs in the training split" in result.output


def test_missing_formulas_names_the_stage(tmp_path: Path, shared_data: Path) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data, train_limit=100), "desk")
    result = runner.invoke(app, ["learn-weights", "-w", str(tmp_path)])
    assert result.exit_code == 2 and "run `mlnseq formulas` first" in result.stderr
    assert not (tmp_path / "weights.parquet").exists()


TEMPORAL_SPEC = Path(__file__).resolve().parents[2] / "examples" / "temporal.mln"


def one_line_refusal(result, *needles: str) -> str:
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in result.output, result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_temporal_formulas_learn_by_cll_and_show_transitions(tmp_path: Path, shared_data: Path) -> None:
    write_predicates(tmp_path, *desk_predicates(shared_data), "desk")
    assert runner.invoke(app, ["formulas", "--spec", str(TEMPORAL_SPEC), "-w", str(tmp_path)]).exit_code == 0
    result = runner.invoke(app, ["learn-weights", "-w", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "temporal formulas" in result.output and 'Next(p,q) => Topic("S' in result.output
    assert f"(native, cll, l2 {cll.DEFAULT_L2:g})" in " ".join(result.output.split())
    weights = pl.read_parquet(tmp_path / "weights.parquet")
    assert weights["temporal"].sum() == 49
    result = runner.invoke(app, ["learn-weights", "--objective", "pll", "--l2", "0.5", "-w", str(tmp_path)])
    assert result.exit_code == 0 and "(native, pll, l2 0.5)" in " ".join(result.output.split())


def test_objective_help_names_the_default_penalty() -> None:
    result = runner.invoke(app, ["learn-weights", "--help"])
    assert f"{cll.DEFAULT_L2:g} for cll" in " ".join(result.output.split())


def test_temporal_bad_inputs_are_one_line_and_write_nothing(tmp_path: Path, shared_data: Path) -> None:
    table, predicates = desk_predicates(shared_data, train_limit=200)
    write_predicates(tmp_path, table, predicates, "desk")
    spec = tmp_path / "bad.mln"
    spec.write_text('0.0 Topic(+c1, p) ^ Next(p, "C1") => Topic(+c2, q)\n')
    one_line_refusal(runner.invoke(app, ["formulas", "--spec", str(spec), "-w", str(tmp_path)]),
                     f"{spec}:1:21: syntax error: Next takes two different frame variables")
    assert not (tmp_path / "formulas.mln").exists()
    spec.write_text('Topic("S1", p) ^ Next(p, q) => Topic("S1", q).\n')  # S1 -> S2 happens in training
    assert runner.invoke(app, ["formulas", "--spec", str(spec), "-w", str(tmp_path)]).exit_code == 0
    one_line_refusal(runner.invoke(app, ["learn-weights", "-w", str(tmp_path)]),
                     f"{spec}:1: hard formula", "training frame(s): episode 0 frame")  # the user's file and line
    assert not (tmp_path / "weights.parquet").exists() and not (tmp_path / "learned.mln").exists()
    one_line_refusal(runner.invoke(app, ["learn-weights", "--objective", "ml", "-w", str(tmp_path)]), "--objective 'ml'")
    one_line_refusal(runner.invoke(app, ["learn-weights", "--engine", "pracmln", "-w", str(tmp_path)]),
                     "--engine pracmln learns by pseudo-likelihood only")
    single = table.head(30).with_columns(pl.int_range(pl.len()).cast(pl.Int32).alias("episode"),
                                         pl.lit(0).cast(pl.Int32).alias("frame"))
    write_predicates(tmp_path, single, predicates, "desk")
    spec.write_text("0.0 Topic(+c1, p) ^ Next(p, q) => Topic(+c2, q)\n")
    assert runner.invoke(app, ["formulas", "--spec", str(spec), "-w", str(tmp_path)]).exit_code == 0
    one_line_refusal(runner.invoke(app, ["learn-weights", "-w", str(tmp_path)]), "no transitions can be learned")
    assert not (tmp_path / "weights.parquet").exists()
