"""Docs that run: every shell block of README.md and docs/*.md, as written, in order, in a fresh folder per page
(or in a copy of the folder of the page it continues), with the real data in ../shared; a block marked
``<!-- skip: next -- REASON -->`` is reported skipped with its reason. What a page quotes from a run (an output
block, a figure in prose) is compared with what the run printed. How to mark a page: docs/testing.md."""

from __future__ import annotations

from unittest import SkipTest

import pytest

import doc_pages

pytestmark = [pytest.mark.slow, pytest.mark.mujoco]

STEPS = [step for path in doc_pages.pages() for step in doc_pages.steps(doc_pages.parse(path))]


@pytest.mark.parametrize("step", STEPS, ids=str)
def test_the_page_runs_as_written(step, doc_runs):
    outcome = doc_runs.outcome(step)
    if isinstance(outcome, SkipTest):
        pytest.skip(f"{step}: {outcome}")
    if outcome is not None:
        raise outcome
