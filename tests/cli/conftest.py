"""The CLI tests read tables and help panels as a 200-column terminal draws them, whatever terminal runs the
tests (COLUMNS unset, 40, ...): rich fits a table to the width and cuts its cells. Summary lines never wrap at
any width (tests/cli/test_output_cli.py runs them at 40 columns). The review page's tests need chromium."""

from __future__ import annotations

import os

import pytest

from mlnseq_cli.console import console

WIDTH = 200


@pytest.fixture(autouse=True)
def wide_terminal(monkeypatch):
    monkeypatch.setenv("COLUMNS", str(WIDTH))  # typer's help and error panels, and the commands run as processes
    monkeypatch.setattr(console, "width", WIDTH)  # the commands' console, made when mlnseq_cli was imported


@pytest.fixture
def needs_browser() -> None:
    """Skip, saying why, where chromium or Playwright is missing; under CI (CI=true), fail instead."""
    import review_browser

    why = review_browser.missing()
    if why is not None:
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(why)
        pytest.skip(why)
