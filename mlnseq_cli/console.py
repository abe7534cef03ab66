"""What every command shares: the rich consoles, the --workdir option and error reporting."""

from __future__ import annotations

import contextlib
import os
import sys
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from mlnseq.catalog.artifacts import DEFAULT_WORKDIR
from mlnseq.catalog.errors import MlnseqError, missing_extra
from mlnseq.catalog.notes import counted  # noqa: F401  (every command's summary counts with it)

# soft_wrap: a printed line is never broken at the terminal's width (a summary names a file people copy and
# grep; the terminal folds a long line itself); tables still fit the width.
console = Console(soft_wrap=True)

WorkdirOption = Annotated[
    Path,
    typer.Option("--workdir", "-w", help="Folder holding this dataset's artifacts.", file_okay=False),
]
DEFAULT = DEFAULT_WORKDIR


def verbose() -> bool:
    return os.environ.get("MLNSEQ_VERBOSE", "") not in ("", "0")


def fail(message: str, exit_code: int) -> typer.Exit:
    """Print one line on stderr and return the Exit to raise."""
    print(f"error: {message}", file=sys.stderr)
    return typer.Exit(exit_code)


@contextlib.contextmanager
def reported_errors() -> Iterator[None]:
    """Turn a stage's errors into one stderr line and an exit code (a traceback before it with --verbose, the
    exit code unchanged)."""
    try:
        yield
    except MlnseqError as error:
        if verbose():
            traceback.print_exc(file=sys.stderr)
        raise fail(str(error), error.exit_code) from None
    except KeyboardInterrupt:
        raise fail("interrupted; artifacts written before the interruption are intact", 130) from None
    except (typer.Exit, typer.Abort):
        raise
    except Exception as error:  # a bug or an unforeseen input: still one line, the traceback on request
        missing = missing_extra(error) if isinstance(error, ImportError) else None
        if missing is not None:  # an optional library absent: the extra that installs it
            if verbose():
                traceback.print_exc(file=sys.stderr)
            raise fail(str(missing), missing.exit_code) from None
        if verbose():
            raise
        raise fail(
            f"{type(error).__name__}: {error} (rerun with --verbose for the traceback)", 1
        ) from None
