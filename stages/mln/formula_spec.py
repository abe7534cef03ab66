"""A formulas file read and checked: what `formulas` and `learn-weights` both do with one.

``read_spec`` parses a .mln file (formulas only: the paper's declarations are added); ``formulas_for``
checks every predicate and constant against the predicate columns and the classes (as the frames name them,
or the paper's ``C<k>``), names each class by its ``C<k>`` inside, and refuses a formula written twice.
``check_mln`` holds the rules of mlnseq's database (``mlnseq.mln.grounding``) that a formula must follow.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Sequence
from pathlib import Path

from mlnseq.catalog.errors import BadInput
from mlnseq.mln.grounding import (
    CLASS, EVIDENCE, NEXT, class_aliases, default_declarations, holds_without_next, name_classes, show,
)
from mlnseq.mln.syntax import (
    MLN, Atom, Const, MLNSyntaxError, Var, WeightedFormula, atoms, format_formula, parse_mln,
)


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


def check_class_names(class_names: Sequence[str], where: str) -> None:
    """Refuse a class name that a formula cannot write (a quoted constant holds no '"' and no line break)."""
    for name in class_names:
        if '"' in name or "\n" in name or not name.strip():
            raise BadInput(f"{where}: class name {name!r} cannot be written in a formula (it holds a '\"', a line "
                           "break or nothing); rename the classes with `mlnseq collect --classes`")


def duplicates(mln: MLN, where: str, class_names: Sequence[str] | None = None) -> None:
    """Refuse a formula written twice (the same formula once its classes are resolved), naming both lines."""
    first: dict[str, int] = {}
    for item in mln.formulas:
        text = format_formula(item.formula)
        if text in first:
            raise BadInput(f"{where}:{item.line}:{item.column}: {show(item.formula, class_names)} is written twice, "
                           f"here and on line {first[text]}: remove one (a formula has one weight)")
        first[text] = item.line


def check_mln(mln: MLN, where: str, words: set[str], classes: set[str], class_names: Sequence[str] = ()) -> None:
    """Refuse what mlnseq's database cannot ground: other predicates, atoms across frames that are not joined
    by Next, unknown constants. ``classes``: the constants a class may be written as; ``class_names``: the
    frames' names, in label order, for messages."""
    for name, domains in mln.predicates.items():
        if name not in (EVIDENCE, CLASS, NEXT) or len(domains) != 2:
            raise BadInput(
                f"{where}: predicate {name}({', '.join(domains)}) is not in mlnseq's database, which holds "
                f"only {EVIDENCE}(word, page), {CLASS}(class, page) and {NEXT}(page, page)"
            )
    if any(any(flags) for flags in mln.mutex.values()):
        raise BadInput(f"{where}: mutually exclusive arguments ('!') are not supported; declare {CLASS}(class, page)")
    for item in mln.formulas:
        check_formula(item, mln, where, words, classes, class_names)


def check_formula(item: WeightedFormula, mln: MLN, where: str, words: set[str], classes: set[str],
                  class_names: Sequence[str] = ()) -> None:
    """Refuse a formula the database cannot ground: an undeclared predicate, a wrong argument, an unknown word or
    class, a variable of two kinds, frames not joined by one Next atom."""
    def at(atom: Atom | None = None) -> str:
        return f"{where}:{item.line}:{atom.column if atom is not None and atom.column else item.column}"

    frame_vars, first_domain, joins = set(), {}, []
    for atom in atoms(item.formula):
        if atom.predicate not in mln.predicates:
            declared = ", ".join(mln.predicates) or "none"
            hint = f"; declare {NEXT}(page, page) to join consecutive frames" if atom.predicate == NEXT else ""
            raise BadInput(f"{at(atom)}: unknown predicate {atom.predicate} (declared: {declared}){hint}")
        if atom.predicate == NEXT:
            names = [t.name for t in atom.args if isinstance(t, Var) and not t.expand]
            if len(atom.args) != 2 or len(names) != 2 or names[0] == names[1]:
                raise MLNSyntaxError(
                    f"{at(atom)}: syntax error: {NEXT} takes two different frame variables, {NEXT}(p, q) for the "
                    f"frame q right after p; found {format_formula(atom)}")
            joins.append(atom)
            frame_vars.update(names)
            continue
        if len(atom.args) != 2:
            raise BadInput(f"{at(atom)}: {atom.predicate} takes 2 arguments, {format_formula(atom)} has "
                           f"{len(atom.args)}")
        first, frame = atom.args
        if not isinstance(frame, Var) or frame.expand:
            raise BadInput(f"{at(atom)}: the last argument of {format_formula(atom)} must be the frame variable "
                           "(e.g. p)")
        frame_vars.add(frame.name)
        known = words if atom.predicate == EVIDENCE else classes
        if isinstance(first, Const) and first.value not in known:
            raise _unknown_constant(atom, first.value, known, class_names, at(atom))
        if isinstance(first, Var) and first_domain.setdefault(first.name, atom.predicate) != atom.predicate:
            raise BadInput(f"{at(atom)}: variable {first.name} ranges over both words and classes")
    clash = sorted(frame_vars & set(first_domain))
    if clash:
        raise BadInput(f"{at()}: variable {clash[0]} is used both as frame and as constant")
    if not joins:
        if len(frame_vars) > 1:
            raise BadInput(f"{at()}: all atoms must share one frame variable, found {', '.join(sorted(frame_vars))}; "
                           f"to relate consecutive frames, add {NEXT}(p, q) to the body")
        return
    _check_join(item, joins, at)


def _unknown_constant(atom: Atom, value: str, known: set[str], class_names: Sequence[str], at: str) -> BadInput:
    """The error for a word (a predicates.parquet column) or a class that does not exist, with the close names."""
    if atom.predicate == EVIDENCE:
        close = difflib.get_close_matches(value, sorted(known), n=3)
        hint = f"did you mean {', '.join(close)}?" if close else "see the columns of predicates.parquet"
        return BadInput(f"{at}: unknown constant {value!r} in {format_formula(atom)}: no such predicate column; {hint}")
    names = list(class_names) or sorted(known, key=lambda c: int(c[1:]) if c[1:].isdigit() else -1)
    close = difflib.get_close_matches(value, names, n=3)
    hint = f"did you mean {', '.join(close)}? " if close else ""
    paper = f" (or C0 .. C{len(names) - 1} in that order)" if class_names else ""
    return BadInput(f"{at}: unknown class {value!r} in {format_formula(atom)}: {hint}the classes "
                    f"are {', '.join(names)}{paper}")


def _check_join(item: WeightedFormula, joins: list[Atom], at: Callable[..., str]) -> None:
    """A formula over two consecutive frames: one Next atom, every other atom on its two frames, and the formula
    true whenever Next is false (else every pair of frames would count)."""
    if len(joins) > 1:
        raise BadInput(f"{at(joins[1])}: a formula joins two consecutive frames with one {NEXT} atom, found "
                       f"{len(joins)}")
    joined = joins[0]
    previous, current = (t.name for t in joined.args)  # type: ignore[union-attr]
    for atom in atoms(item.formula):
        if atom.predicate == NEXT:
            continue
        frame = atom.args[-1].name  # type: ignore[union-attr]
        if frame not in (previous, current):
            raise BadInput(f"{at(atom)}: {format_formula(atom)} is on frame {frame}, but "
                           f"{format_formula(joined)} joins only {previous} and {current}")
    soft_constant = item.weight is not None and holds_without_next(item.formula, at(), value=False)
    if not (holds_without_next(item.formula, at()) or soft_constant):
        raise BadInput(
            f"{at()}: {format_formula(item.formula)} must hold whenever {format_formula(joined)} is false (frames that "
            f"are not consecutive), else every pair of frames counts: put {format_formula(joined)} in the body, "
            f"e.g. Topic(c1, {previous}) ^ {format_formula(joined)} => Topic(c2, {current})")


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
