"""`mlnseq binarize`: not available yet (a later issue fills it)."""

from __future__ import annotations

from mlnseq_cli.console import DEFAULT, WorkdirOption, reported_errors
from stages.errors import StageNotAvailable


def binarize(workdir: WorkdirOption = DEFAULT) -> None:
    """Not available yet."""
    with reported_errors():
        raise StageNotAvailable("stage 'binarize' is not available yet in this version of mlnseq")
