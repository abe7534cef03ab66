"""The errors a stage raises on purpose; the CLI turns each into one line on stderr and an exit code."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


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



def check_choice(option: str, value: Any, allowed: Iterable[Any], more: str = "") -> None:
    """Refuse a value of ``--option`` that is not one of ``allowed``: "unknown --option 'x': choose one of a, b"
    (then ``more``, the other forms the option takes, if any)."""
    allowed = tuple(allowed)
    if value not in allowed:
        raise BadInput(f"unknown --{option} {value!r}: choose one of {', '.join(map(str, allowed))}"
                       + (f", {more}" if more else ""))
