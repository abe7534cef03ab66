"""The one check of a refused command, shared by the bad-input tests: exit 2, one `error:` line on stderr naming
what the test expects, no traceback, and (``refused_in``) the files of a folder left as they were."""

from __future__ import annotations

import hashlib
from pathlib import Path

from typer.testing import CliRunner

from mlnseq_cli.main import app

runner = CliRunner()


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones too) -> its sha256 (size and mtime if we cannot read it)."""
    def digest(path: Path) -> str:
        try:
            return hashlib.sha256(path.read_bytes()).hexdigest()
        except PermissionError:
            return f"unreadable {path.stat().st_size} {path.stat().st_mtime_ns}"

    return {str(p.relative_to(folder)): digest(p) for p in sorted(folder.rglob("*")) if p.is_file()}


def refused(*args, needles: tuple[str, ...] = ()) -> str:
    """Run ``mlnseq ARGS``; assert exit 2, one error line holding every needle, no traceback; return the line."""
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 2, (args, result.exit_code, result.output)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr
    assert "Traceback" not in result.output
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


def refused_in(folder: Path, *args, needles: tuple[str, ...] = ()) -> str:
    """As ``refused``, and the files under ``folder`` are as they were before."""
    before = snapshot(folder)
    line = refused(*args, needles=needles)
    assert snapshot(folder) == before, "a refused command changed the files"
    return line
