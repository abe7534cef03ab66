"""A formulas file read and checked: what `formulas` and `learn-weights` both do with one.

``read_spec`` parses a .mln file (formulas only: the paper's declarations are added); ``formulas_for``
checks every predicate and constant against the predicate columns and the classes (as the frames name them,
or the paper's ``C<k>``), names each class by its ``C<k>`` inside, and refuses a formula written twice.
"""

from __future__ import annotations

from pathlib import Path

from mlnseq.catalog.errors import BadInput
from mlnseq.mln.grounding import (
    EVIDENCE, NEXT, check_class_names, check_mln, class_aliases, default_declarations, duplicates, name_classes,
)
from mlnseq.mln.syntax import MLN, Var, atoms, format_formula, parse_mln


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
    refuse_variables_named_as_constants(mln, str(spec), set(columns), set(class_aliases(class_names)))
    name_classes(mln, class_names)
    duplicates(mln, str(spec), class_names)


def refuse_variables_named_as_constants(mln: MLN, where: str, words: set[str], classes: set[str]) -> None:
    """``Has(gripper_closed, p)``: unquoted and lowercase, a variable over every column, yet it names one."""
    for item in mln.formulas:
        for atom in atoms(item.formula):
            first = atom.args[0] if atom.args and atom.predicate != NEXT else None
            known = words if atom.predicate == EVIDENCE else classes
            if isinstance(first, Var) and not first.expand and first.name in known:
                what = "predicate column" if atom.predicate == EVIDENCE else "class"
                raise BadInput(
                    f"{where}:{item.line}:{atom.column or item.column}: {first.name} in {format_formula(atom)} is a "
                    f"variable (unquoted, it starts with a small letter) over every {what}, yet it names the {what} "
                    f"{first.name!r}: write {atom.predicate}(\"{first.name}\", {atom.args[-1].name}) for that "
                    f"{what}, or +{first.name} for one formula per {what}")
