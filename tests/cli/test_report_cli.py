"""report through the CLI: its help, and one clear line when there is no run to report on."""

import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app

runner = CliRunner()


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


def test_help_says_what_it_reads_and_writes():
    result = runner.invoke(app, ["report", "--help"])
    assert result.exit_code == 0
    assert "REPORT.md" in result.output and "timings.tsv" in result.output


@pytest.mark.parametrize("make_runs", [False, True])
def test_no_run_is_one_error_line(tmp_path, make_runs):
    runs = tmp_path / "runs"
    if make_runs:
        (runs / "fetch").mkdir(parents=True)
    result = runner.invoke(app, ["report", "--runs", str(runs), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "make reproduce" in lines[0]
    assert not (tmp_path / "out").exists()
