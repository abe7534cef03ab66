"""A formulas file read and checked: what `formulas` and `learn-weights` both do with one.

``read_spec`` parses a .mln file (formulas only: the paper's declarations are added); ``formulas_for``
checks every predicate and constant against the predicate columns and the classes (as the frames name them,
or the paper's ``C<k>``), names each class by its ``C<k>`` inside, and refuses a formula written twice.
"""

from __future__ import annotations

from pathlib import Path

from mlnseq.catalog.errors import BadInput
from mlnseq.mln.grounding import (
    check_class_names, check_mln, class_aliases, default_declarations, duplicates, name_classes,
)
from mlnseq.mln.syntax import MLN, parse_mln


def read_spec(path: Path) -> MLN:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise BadInput(f"cannot read {path}: {error}") from error
    mln = parse_mln(text, str(path))
    if not mln.predicates:  # formulas only: the paper's two predicates (and Next if used)
        defaults = parse_mln(default_declarations(mln))
        mln.predicates, mln.mutex = defaults.predicates, defaults.mutex
    if not mln.formulas:
        raise BadInput(f"{path} holds no formula: add e.g. `0.0 Has(+w, p) => Topic(+c, p)`")
    return mln


def formulas_for(mln: MLN, spec: Path, columns: list[str], class_names: list[str]) -> None:
    """Check the spec against the predicate columns and the classes (as the frames name them, or the paper's
    ``C<k>``), then write each class as its ``C<k>``; a formula written twice is refused."""
    check_class_names(class_names, str(spec))
    check_mln(mln, str(spec), set(columns), set(class_aliases(class_names)), class_names)
    name_classes(mln, class_names)
    duplicates(mln, str(spec), class_names)
