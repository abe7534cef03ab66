"""What docs/cli.md says about output holds (issue 55): every command that writes a file prints exactly one
summary line `STAGE: wrote PATH`, wherever it falls among its notes and tables; the commands that write nothing
print none; `mlnseq --help` names every network type train fits. On the real DESK data, the bare pipeline."""

from __future__ import annotations

import re
import shutil

from typer.testing import CliRunner

from mlnseq import networks
from mlnseq_cli.main import app

runner = CliRunner()
WRITES = ("collect", "binarize", "formulas", "learn-weights", "train", "conflate", "eval", "export", "predict")
SILENT = ("info", "explain")


def summary_lines(name: str, output: str) -> list[str]:
    return [line for line in output.splitlines() if re.match(rf"{re.escape(name)}( \([^)]*\))?: wrote ", line)]


def test_each_command_that_writes_says_so_in_one_line_and_the_others_in_none(tmp_path, shared_data, repo_root,
                                                                             desk_test_recording):
    work, model = tmp_path / "work", tmp_path / "mln.mlnseq"
    lines = {
        "collect": ["--env", "desk", "--source", shared_data / "desk-taurus"], "binarize": [], "formulas": [],
        "learn-weights": [], "train": ["--epochs", 1], "conflate": [], "eval": [],
        "export": ["--method", "mln", "-o", model],
    }
    said = {}
    for name, args in lines.items():
        done = runner.invoke(app, [name, *map(str, args), "-w", str(work)])
        assert done.exit_code == 0, done.output
        said[name] = done.stdout
    source = ["--source", str(desk_test_recording)]
    said["predict"] = runner.invoke(app, ["predict", str(model), *source, "-o", str(tmp_path / "p.parquet")]).stdout
    said["info"] = runner.invoke(app, ["info", str(model)]).stdout
    said["explain"] = runner.invoke(app, ["explain", str(model), *source, "--frame", "10"]).stdout
    assert {name: len(summary_lines(name, said[name])) for name in WRITES} == {name: 1 for name in WRITES}
    assert all(": wrote " not in said[name] for name in SILENT)
    assert summary_lines("predict", said["predict"]) != said["predict"].splitlines()[-1:]  # metrics after it
    text = (repo_root / "docs" / "cli.md").read_text()
    assert "Each command that writes a file prints one summary line naming it" in text
    assert "`predict` prints the metrics of labelled recordings after it" in text


def test_the_commands_help_names_every_network_type_train_fits():
    listing = runner.invoke(app, ["--help"], env={"COLUMNS": "200"}).output
    train = next(line for line in listing.splitlines() if " train " in line)
    assert all(cell in train for cell in networks.CELLS), train


def test_eval_stores_the_confusion_matrix_it_does_not_print_as_stages_md_says(desk_full_workdir, repo_root, tmp_path):
    import polars as pl

    from mlnseq.catalog import artifacts

    page = " ".join((repo_root / "docs" / "stages.md").read_text().split())
    assert "the confusion matrix, which it stores only: `metrics.parquet`'s rows of metric `confusion`" in page
    work = tmp_path / "work"
    shutil.copytree(desk_full_workdir, work)
    printed = runner.invoke(app, ["eval", "-w", str(work)]).stdout
    assert not any("confusion" in line for line in printed.splitlines() if ": wrote " not in line)  # tmp path
    metrics = pl.read_parquet(work / artifacts.METRICS).filter(pl.col("metric") == "confusion")
    assert metrics.height and all(" -> " in item for item in metrics["item"])
