"""What the commands print, whatever the terminal: a summary line is one line at any width and path length,
coloured on a terminal; --verbose adds a traceback and keeps the exit code; counts are singular for one."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mlnseq_cli.console import counted
from mlnseq_cli.main import app

# Runs each `mlnseq ARGS` of a JSON list in this one process and prints their outputs and exit codes.
RUN_EACH = """
import contextlib, io, json, sys
from mlnseq_cli.main import main
done = []
for args in json.loads(sys.argv[1]):
    sys.argv = ["mlnseq", *args]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        try:
            main()
            code = 0
        except SystemExit as exit:
            code = exit.code or 0
    done.append({"args": args, "output": out.getvalue(), "code": code})
print(json.dumps(done))
"""
ANSI = re.compile(r"\x1b\[[0-9;]*m")


@pytest.fixture(scope="module")
def long_folder(tmp_path_factory) -> Path:
    """A folder whose path alone is longer than a wide terminal."""
    folder = tmp_path_factory.mktemp("long") / ("d" * 100) / ("e" * 100)
    folder.mkdir(parents=True)
    return folder


def run_each(commands: list[list[str]], **env: str) -> list[dict]:
    environment = {**os.environ, "MLNSEQ_VERBOSE": "", **env}
    done = subprocess.run([sys.executable, "-c", RUN_EACH, json.dumps(commands)], capture_output=True, text=True,
                          env=environment)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def summary(output: str, stage: str, path: Path) -> str:
    """The one line that says what the stage wrote; it names the whole path and closes its parenthesis."""
    lines = [line for line in output.splitlines() if ": wrote " in line]
    assert len(lines) == 1, output
    line = lines[0]
    assert line.startswith(stage) and str(path) in line, output
    assert line.count("(") == line.count(")"), output
    return line


def test_summary_lines_are_one_line_at_40_columns_after_a_long_path(long_folder, desk_full_workdir,
                                                                   desk_test_recording):
    workdir = Path(shutil.copytree(desk_full_workdir, long_folder / "work"))
    collected = long_folder / "collected"
    recording = Path(shutil.copy(desk_test_recording, long_folder / "recording.csv"))
    out = long_folder / "out.parquet"
    w = ["-w", str(workdir)]
    commands = {  # stage -> (its arguments, the file its summary names); eval and export before their inputs change
        "collect": (["collect", "--env", "table", "--source", str(recording), "--train-frames", "10000",
                     "-w", str(collected)], collected / "frames.parquet"),
        "eval": (["eval", *w], workdir / "metrics.parquet"),
        "export": (["export", "--method", "lstm", *w], workdir / "lstm.mlnseq"),
        "predict": (["predict", str(workdir / "lstm.mlnseq"), "--source", str(recording), "-o", str(out)], out),
        "binarize": (["binarize", *w], workdir / "predicates.parquet"),
        "formulas": (["formulas", *w], workdir / "formulas.mln"),
        "learn-weights": (["learn-weights", *w], workdir / "weights.parquet"),
    }
    assert len(str(workdir / "predicates.parquet")) > 200
    results = run_each([args for args, _ in commands.values()], COLUMNS="40")
    for (stage, (_, path)), result in zip(commands.items(), results):
        assert result["code"] == 0, (stage, result["output"])
        line = summary(result["output"], stage, path)
        assert "\x1b" not in line  # into a pipe: no colour codes


def test_a_summary_on_a_colour_terminal_keeps_its_colour_and_its_one_line(long_folder, desk_mln_workdir):
    workdir = Path(shutil.copytree(desk_mln_workdir, long_folder / "colour"))
    [result] = run_each([["binarize", "-w", str(workdir)]], COLUMNS="40", FORCE_COLOR="1", TERM="xterm-256color")
    assert result["code"] == 0, result["output"]
    line = summary(ANSI.sub("", result["output"]), "binarize", workdir / "predicates.parquet")
    assert line.endswith("binarize.toml)")
    assert "\x1b[32mbinarize" in result["output"]  # the stage's name in green


def test_verbose_shows_the_traceback_and_keeps_a_bad_inputs_exit_code(monkeypatch, tmp_path):
    monkeypatch.setenv("MLNSEQ_VERBOSE", "")  # --verbose sets it for this process: restored (unset) after the test
    runner = CliRunner()
    plain = runner.invoke(app, ["eval", "-w", str(tmp_path)])
    verbose = runner.invoke(app, ["--verbose", "eval", "-w", str(tmp_path)])
    assert plain.exit_code == verbose.exit_code == 2
    assert "Traceback" not in plain.stderr and plain.stderr.count("\n") == 1
    assert "Traceback" in verbose.stderr and "stages/catalog/artifacts.py" in verbose.stderr  # where it was raised
    assert verbose.stderr.strip().splitlines()[-1] == plain.stderr.strip()  # the same one line, last


@pytest.mark.parametrize(("n", "one", "many", "expected"), [
    (1, "episode", None, "1 episode"), (2, "episode", None, "2 episodes"), (0, "predicate", None, "0 predicates"),
    (1, "class", "classes", "1 class"), (7, "class", "classes", "7 classes"), (20924, "frame", None, "20,924 frames"),
])
def test_a_count_is_singular_only_for_one(n, one, many, expected):
    assert counted(n, one, many) == expected
