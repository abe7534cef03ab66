"""Where a formula of the generated formulas.mln was written: the user's spec file and line.

`mlnseq formulas` writes ``// from FILE:LINE`` above each formula it copies from the spec; learn-weights reads
those back, so that its warnings and errors name the user's file and line, not formulas.mln's."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

from mlnseq.mln.syntax import MLN

MARK = re.compile(r"^// from (?P<path>.+):(?P<line>\d+)$")
WARNING_LINE = re.compile(r"^line (\d+): ")


def mark(spec: Path, line: int) -> str:
    """The comment written above a formula copied from ``spec``'s ``line``."""
    return f"// from {spec}:{line}"


def to_source(mln: MLN, text: str, path: Path) -> tuple[MLN, str]:
    """``mln`` (read from ``text`` at ``path``) with each formula's line as its spec gives it, and the spec's
    path for messages; unchanged (and ``path``) when a formula has no mark or the marks name several files."""
    lines = text.splitlines()
    found = [MARK.match(lines[item.line - 2]) if 2 <= item.line <= len(lines) + 1 else None for item in mln.formulas]
    files = {m["path"] for m in found if m}
    if not mln.formulas or None in found or len(files) != 1:
        return mln, str(path)
    formulas = [replace(item, line=int(m["line"])) for item, m in zip(mln.formulas, found)]
    return replace(mln, formulas=formulas), files.pop()


def located(warnings: list[str], where: str) -> list[str]:
    """Warnings that begin ``line N:`` with the file named: ``FILE:N:``."""
    return [WARNING_LINE.sub(lambda m: f"{where}:{m[1]}: ", warning) for warning in warnings]
