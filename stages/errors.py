"""The errors a stage raises on purpose; the CLI turns each into one line on stderr and an exit code."""

from __future__ import annotations


class MlnseqError(Exception):
    """A run that could not complete (exit 1)."""

    exit_code = 1


class BadInput(MlnseqError):
    """Bad usage or bad input: a file, line or option the user must fix (exit 2)."""

    exit_code = 2


class MissingArtifact(BadInput):
    """An input artifact is absent: says which stage writes it."""


class StaleArtifact(BadInput):
    """An input artifact no longer matches the inputs it was made from: says which stage to rerun."""


class StageNotAvailable(BadInput):
    """A stage command that a later version fills."""
