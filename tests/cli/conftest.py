"""The CLI tests read tables and help panels as a 200-column terminal draws them, whatever terminal runs the
tests (COLUMNS unset, 40, ...): rich fits a table to the width and cuts its cells. Summary lines never wrap at
any width (tests/cli/test_output_cli.py runs them at 40 columns)."""

from __future__ import annotations

import pytest

from mlnseq_cli.console import console

WIDTH = 200


@pytest.fixture(autouse=True)
def wide_terminal(monkeypatch):
    monkeypatch.setenv("COLUMNS", str(WIDTH))  # typer's help and error panels, and the commands run as processes
    monkeypatch.setattr(console, "width", WIDTH)  # the commands' console, made when mlnseq_cli was imported
