"""Where each learned formula was written: the user's file, its line and that line as written.

`mlnseq formulas` writes ``// from FILE:LINE`` above each formula it copies into formulas.mln
(stages/mln/source_lines.py), and weights.parquet's ``template`` names the formula of formulas.mln each row was
expanded from. Export adds what they point at to the model file's weights table, as the columns ``file``, ``line``
and ``written``, so that an explanation names the user's line ("line 12 of my.mln") wherever the model goes.
A model without them (exported before) explains with the formulas alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import polars as pl

from mlnseq.catalog.errors import BadInput
from mlnseq.mln.source_lines import MARK
from mlnseq.mln.syntax import parse_mln

COLUMNS = {"file": pl.String, "line": pl.Int32, "written": pl.String}


@dataclass(frozen=True)
class Written:
    """A formula's file and line, and that line as written there (a template's line for each of its expansions)."""

    file: str | None = None
    line: int | None = None
    text: str | None = None


def _spec_line(path: str, line: int) -> str | None:
    """Line ``line`` of the spec file ``path`` when it still holds one formula there (else None)."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return None
    if not 1 <= line <= len(lines):
        return None
    try:
        return lines[line - 1].strip() if len(parse_mln(lines[line - 1]).formulas) == 1 else None
    except BadInput:
        return None


def written_lines(text: str, path: Path) -> list[Written]:
    """Each formula of a formulas.mln (``text``, read from ``path``), in its order: the spec's file and line its mark
    names and that line as the spec holds it; formulas.mln's own line where the spec cannot be read or has changed."""
    lines = text.splitlines()
    out = []
    for item in parse_mln(text, str(path)).formulas:
        own = lines[item.line - 1].strip()
        mark = MARK.match(lines[item.line - 2]) if item.line >= 2 else None
        if mark is None:
            out.append(Written(str(path), item.line, own))
            continue
        out.append(Written(mark["path"], int(mark["line"]), _spec_line(mark["path"], int(mark["line"])) or own))
    return out


def formulas_of(weights_path: Path, meta: dict[str, Any]) -> Path | None:
    """The formulas file a weights table was learned from (its recorded input ending in .mln), if it is there."""
    for name in meta.get("inputs", {}):
        if name.endswith(".mln"):
            path = Path(name) if Path(name).is_absolute() else Path(weights_path).resolve().parent / name
            return path if path.is_file() else None
    return None


def annotated(weights: pl.DataFrame, written: list[Written]) -> pl.DataFrame:
    """The weights table with each row's ``file``, ``line`` and ``written`` (by its ``template``); unchanged when a
    template index falls outside ``written`` (the formulas file is not the one learned from)."""
    templates = weights["template"].to_list()
    if any(t is None or not 0 <= t < len(written) for t in templates):
        return weights
    rows = [written[t] for t in templates]
    return weights.with_columns(pl.Series("file", [r.file for r in rows], dtype=pl.String),
                                pl.Series("line", [r.line for r in rows], dtype=pl.Int32),
                                pl.Series("written", [r.text for r in rows], dtype=pl.String))


def read_written(weights: pl.DataFrame) -> list[Written]:
    """Each row's Written, as a model file's weights table holds them (empty ones where it has none)."""
    if not all(name in weights.columns and weights.schema[name] == kind for name, kind in COLUMNS.items()):
        return [Written() for _ in range(weights.height)]
    return [Written(*row) for row in weights.select(*COLUMNS).iter_rows()]
