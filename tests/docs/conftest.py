"""The docs test's pages, run once per session (tests/doc_pages.py)."""

from __future__ import annotations

import pytest

import doc_pages


@pytest.fixture(scope="session")
def doc_runs(tmp_path_factory) -> doc_pages.Runs:
    """Every page's run, each done once when a check first needs it; with MLNSEQ_DOCS_FIGURES=write the
    figures measured are written into the pages at the end."""
    runs = doc_pages.Runs(tmp_path_factory.mktemp("pages"))
    yield runs
    if doc_pages.WRITE:
        for page in doc_pages.write_figures():
            print(f"docs-figures: rewrote {page}")
