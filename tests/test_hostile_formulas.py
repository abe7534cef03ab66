"""Formulas and predicate specs a user gets subtly wrong, through the real CLI on the DESK workdir: a fixed weight
keeps its value through formulas.mln, an unquoted lowercase constant is refused, and a template or spec that
would expand past a bound is refused before anything is built, naming the bound and the option to raise it."""

from __future__ import annotations

import shutil
from pathlib import Path

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from refusals import refused
from mlnseq.catalog import artifacts

runner = CliRunner()


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


@pytest.fixture
def workdir(tmp_path, desk_mln_workdir) -> Path:
    return Path(shutil.copytree(desk_mln_workdir, tmp_path / "work"))


def ok(*args) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def test_a_tiny_and_a_huge_fixed_weight_come_back_from_formulas_mln_as_written(workdir, tmp_path):
    spec = tmp_path / "fixed.mln"
    spec.write_text('0.0 Has(+w, p) => Topic(+c, p)\n'
                    '1e-7 Has("left_gripper_closed", p) ^ Has("right_gripper_closed", p) => Topic(C4, p)\n'
                    '100000 Has("left_gripper_open", p) ^ Has("right_gripper_open", p) => Topic(C0, p)\n')
    ok("formulas", "--spec", spec, "-w", workdir)
    ok("learn-weights", "-w", workdir)
    weights = pl.read_parquet(workdir / artifacts.WEIGHTS).filter(pl.col("template") > 0).sort("template")
    assert weights["weight"].to_list() == [1e-7, 100000.0]
    assert weights["fixed"].to_list() == [True, True]


def test_an_unquoted_lowercase_constant_is_refused_not_made_a_variable(workdir, tmp_path):
    spec = tmp_path / "lower.mln"
    spec.write_text('0.0 Has(+w, p) => Topic(+c, p)\n0.0 Has(left_gripper_closed, p) => Topic(+c, p)\n')
    refused("formulas", "--spec", spec, "-w", workdir,
            needles=("lower.mln:2:5", "left_gripper_closed", 'Has("left_gripper_closed", p)', "+left_gripper_closed"))


def test_a_template_of_six_variables_is_refused_before_it_is_expanded(workdir, tmp_path):
    spec = tmp_path / "six.mln"
    spec.write_text("0.0 Has(+a,p) ^ Has(+b,p) ^ Has(+c,p) ^ Has(+d,p) ^ Has(+e,p) ^ Has(+f,p) => Topic(+k,p)\n")
    ok("formulas", "--spec", spec, "-w", workdir)
    before = (workdir / artifacts.WEIGHTS).read_bytes()
    refused("learn-weights", "-w", workdir, needles=(f"{spec}:1: ", "--max-formulas 20,000", "raise --max-formulas"))
    assert (workdir / artifacts.WEIGHTS).read_bytes() == before


def test_max_formulas_bounds_the_paper_template_too(workdir):
    refused("learn-weights", "--max-formulas", 50, "-w", workdir, needles=("--max-formulas 50",))


def test_a_pair_of_two_large_bins_is_refused_before_its_columns_are_made(workdir, tmp_path):
    edges = ", ".join(str(k / 2000) for k in range(1, 2000))
    values = ", ".join(f'"b{k}"' for k in range(2000))
    spec = tmp_path / "pairs.binarize.toml"
    spec.write_text("".join(f'[[predicate]]\nname = "{name}"\nkind = "bins"\nchannel = "{name}"\n'
                            f"edges = [{edges}]\nvalues = [{values}]\n\n" for name in ("left_gripper", "right_gripper"))
                    + '[[predicate]]\nname = "both"\nkind = "pair"\nof = ["left_gripper", "right_gripper"]\n')
    before = (workdir / artifacts.PREDICATES).read_bytes()
    refused("binarize", "--spec", spec, "-w", workdir,
            needles=("pairs.binarize.toml:18", "'both'", "4,000,000 columns", "--max-columns 10,000"))
    assert (workdir / artifacts.PREDICATES).read_bytes() == before


def test_a_spec_nested_fifty_thousand_deep_is_one_line(workdir, tmp_path):
    spec = tmp_path / "deep.binarize.toml"
    spec.write_text("x = " + "[" * 50_000 + "]" * 50_000 + "\n")
    refused("binarize", "--spec", spec, "-w", workdir, needles=("deep.binarize.toml", "nested too deep"))
