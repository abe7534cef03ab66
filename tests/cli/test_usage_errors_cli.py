"""A usage error is one line on stderr, as docs/cli.md and the README promise for every error (issue 55: an
unknown option was a 5-line box): the mistake, then which --help lists what the command takes; exit 2."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from typer.testing import CliRunner

from mlnseq_cli.main import app


@pytest.mark.parametrize("args, said", [
    (["train", "--bogus"], "error: No such option: --bogus (mlnseq train --help lists the options)"),
    (["train", "--epochs", "x"], "error: Invalid value for '--epochs': "),
    (["explain", "m.mlnseq", "--frame", "3"], "error: Missing option '--source'. (mlnseq explain --help lists"),
    (["trian"], "error: No such command 'trian'. Did you mean 'train'? (mlnseq --help lists the commands)"),
])
def test_a_usage_error_is_one_line(args, said):
    done = subprocess.run([sys.executable, "-m", "mlnseq_cli.main", *args], capture_output=True, text=True,
                          env={**os.environ, "COLUMNS": "80"})
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and done.stderr.startswith(said), done.stderr


def test_the_pages_say_so(repo_root):
    assert "An error is one line on stderr, `error: ...`" in (repo_root / "docs" / "cli.md").read_text()
    assert "Errors are one line on stderr" in (repo_root / "README.md").read_text()
    done = CliRunner().invoke(app, ["eval", "--nothing"])
    assert done.exit_code == 2 and done.stderr.count("\n") == 1


def test_no_arguments_still_shows_the_help():
    done = CliRunner().invoke(app, [])
    assert "Usage: mlnseq" in done.output and "error:" not in done.output
