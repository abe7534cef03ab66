"""A formulas file read and checked: what `formulas` and `learn-weights` both do with one.

``read_spec`` parses a .mln file (formulas only: the paper's declarations are added); ``formulas_for``
names the classes ``C<k>`` and checks every predicate and constant against the predicate columns.
"""

from __future__ import annotations

from pathlib import Path

from stages.errors import BadInput
from stages.mln.grounding import class_constant, check_mln, default_declarations, name_classes
from stages.mln.syntax import MLN, parse_mln


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
    """Write class names as their ``C<k>``, then check the spec against the predicate columns and classes."""
    name_classes(mln, class_names)
    check_mln(mln, str(spec), set(columns), {class_constant(k) for k in range(len(class_names))})
