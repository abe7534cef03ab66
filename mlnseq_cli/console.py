"""What every command shares: the rich consoles, the --workdir option and error reporting."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from stages.artifacts import DEFAULT_WORKDIR
from stages.errors import MlnseqError

console = Console()

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
    """Turn a stage's errors into one stderr line and an exit code (a traceback only with --verbose)."""
    try:
        yield
    except MlnseqError as error:
        if verbose():
            raise
        raise fail(str(error), error.exit_code) from None
    except KeyboardInterrupt:
        raise fail("interrupted; artifacts written before the interruption are intact", 130) from None
    except (typer.Exit, typer.Abort):
        raise
    except Exception as error:  # a bug or an unforeseen input: still one line, the traceback on request
        if verbose():
            raise
        raise fail(
            f"{type(error).__name__}: {error} (rerun with --verbose for the traceback)", 1
        ) from None
