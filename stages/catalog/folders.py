"""A folder written whole or not at all: built in a hidden temporary folder beside its place (``.NAME.PID.*.tmp``),
which takes the place only once complete; the leftovers of writers that were killed are removed first."""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from mlnseq.catalog.artifacts import umask, writer_running
from mlnseq.catalog.errors import BadInput


def remove_leftovers(path: Path) -> None:
    """Delete the temporary folders that writers of ``path`` no longer running left beside it."""
    leftover = re.compile(rf"\.{re.escape(path.name)}\.(\d+)\..*\.tmp\Z")
    for candidate in path.parent.glob(f".{path.name}.*.tmp"):
        found = leftover.match(candidate.name)
        if found and candidate.is_dir() and not candidate.is_symlink() and not writer_running(int(found.group(1))):
            shutil.rmtree(candidate, ignore_errors=True)


@contextlib.contextmanager
def atomic_folder(path: Path) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``path``; only if the block succeeds it takes the place of ``path``
    (a folder there before is removed once the new one is in place), else it is removed."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_leftovers(path)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent))
        os.chmod(tmp, 0o777 & ~umask())  # mkdtemp makes 0700; the folder gets the mode mkdir would give it
    except OSError as error:
        raise BadInput(f"cannot write {path}: {error.strerror or error}; choose a writable folder") from error
    try:
        yield tmp
        old = tmp.with_name(f"{tmp.name[:-len('.tmp')]}.old.tmp")
        if path.exists():
            os.replace(path, old)
        try:
            os.replace(tmp, path)
        except OSError:
            if old.exists():
                os.replace(old, path)  # the folder as it was
            raise
        shutil.rmtree(old, ignore_errors=True)
    except OSError as error:
        raise BadInput(f"cannot write {path}: {error.strerror or error}; choose a writable folder") from error
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
