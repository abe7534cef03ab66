"""Bind an MLN to mlnseq's per-frame database and ground its formulas.

The database has two predicates, as in the paper: ``Has(<predicate column>, <frame>)`` is true
when that boolean column of predicates.parquet is true in the frame, and ``Topic(C<k>, <frame>)``
when the frame's label is k. Every formula relates atoms of one frame: each atom's last argument
is the same frame variable. A frame's atoms form one row of a boolean matrix (the columns first,
then the classes), so a ground formula is evaluated on all frames at once.
"""

from __future__ import annotations

import difflib

import itertools
from dataclasses import dataclass, replace

import numpy as np

from stages.errors import BadInput
from stages.mln.syntax import (
    MLN, And, Atom, Const, Equiv, Formula, Implies, Not, Or, Var, WeightedFormula, atoms, format_formula,
    map_atoms, substitute,
)

EVIDENCE = "Has"
CLASS = "Topic"
DECLARATIONS = f"{EVIDENCE}(word, page)\n{CLASS}(class, page)\n"


def class_constant(label: int) -> str:
    return f"C{label}"


@dataclass(frozen=True)
class AtomSpace:
    """The atoms of one frame: Has(word) for each word, then Topic(class) for each class."""

    words: tuple[str, ...]
    classes: tuple[str, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "_word_index", {w: i for i, w in enumerate(self.words)})
        object.__setattr__(self, "_class_index", {c: i for i, c in enumerate(self.classes)})

    @property
    def size(self) -> int:
        return len(self.words) + len(self.classes)

    def constants(self, predicate: str) -> tuple[str, ...]:
        return self.words if predicate == EVIDENCE else self.classes

    def index(self, atom: Atom) -> int:
        value = atom.args[0].value  # type: ignore[union-attr]
        if atom.predicate == EVIDENCE:
            return self._word_index[value]  # type: ignore[attr-defined]
        return len(self.words) + self._class_index[value]  # type: ignore[attr-defined]

    def contains(self, atom: Atom) -> bool:
        value = atom.args[0].value  # type: ignore[union-attr]
        table = self._word_index if atom.predicate == EVIDENCE else self._class_index  # type: ignore[attr-defined]
        return value in table


def name_classes(mln: MLN, class_names: list[str]) -> MLN:
    """Let formulas name a class as the frames do, ``Topic("lift", p)``: rewritten to its ``C<k>``.
    A constant already of the form ``C<k>`` is left as it is."""
    constants = {name: class_constant(k) for k, name in enumerate(class_names)}
    paper_form = {class_constant(k) for k in range(len(class_names))}

    def rename(atom: Atom) -> Atom:
        first = atom.args[0] if atom.args else None
        if atom.predicate == CLASS and isinstance(first, Const) and first.value not in paper_form \
                and first.value in constants:
            return Atom(atom.predicate, (Const(constants[first.value]), *atom.args[1:]))
        return atom

    mln.formulas = [replace(item, formula=map_atoms(item.formula, rename)) for item in mln.formulas]
    return mln


def check_mln(mln: MLN, where: str, words: set[str], classes: set[str]) -> None:
    """Refuse what mlnseq's database cannot ground: other predicates, cross-frame atoms, unknown constants."""
    for name, domains in mln.predicates.items():
        if name not in (EVIDENCE, CLASS) or len(domains) != 2:
            raise BadInput(
                f"{where}: predicate {name}({', '.join(domains)}) is not in mlnseq's database, which holds "
                f"only {EVIDENCE}(word, page) and {CLASS}(class, page)"
            )
    if any(any(flags) for flags in mln.mutex.values()):
        raise BadInput(f"{where}: mutually exclusive arguments ('!') are not supported; declare {CLASS}(class, page)")
    for item in mln.formulas:
        check_formula(item, mln, where, words, classes)


def check_formula(item: WeightedFormula, mln: MLN, where: str, words: set[str], classes: set[str]) -> None:
    at = f"{where}:{item.line}"
    frame_vars, first_domain = set(), {}
    for atom in atoms(item.formula):
        if atom.predicate not in mln.predicates:
            declared = ", ".join(mln.predicates) or "none"
            raise BadInput(f"{at}: unknown predicate {atom.predicate} (declared: {declared})")
        if len(atom.args) != 2:
            raise BadInput(f"{at}: {atom.predicate} takes 2 arguments, {format_formula(atom)} has {len(atom.args)}")
        first, frame = atom.args
        if not isinstance(frame, Var) or frame.expand:
            raise BadInput(f"{at}: the last argument of {format_formula(atom)} must be the frame variable (e.g. p)")
        frame_vars.add(frame.name)
        known = words if atom.predicate == EVIDENCE else classes
        if isinstance(first, Const) and first.value not in known:
            if atom.predicate == EVIDENCE:
                close = difflib.get_close_matches(first.value, sorted(known), n=3)
                hint = f"did you mean {', '.join(close)}?" if close else "see the columns of predicates.parquet"
                raise BadInput(f"{at}: unknown constant {first.value!r} in {format_formula(atom)}: "
                               f"no such predicate column; {hint}")
            raise BadInput(f"{at}: unknown constant {first.value!r} in {format_formula(atom)}: classes are "
                           f"{', '.join(sorted(known, key=lambda c: int(c[1:])))} (C<k> in the frames' class order)")
        if isinstance(first, Var):
            if first_domain.setdefault(first.name, atom.predicate) != atom.predicate:
                raise BadInput(f"{at}: variable {first.name} ranges over both words and classes")
            if first.name in frame_vars:
                raise BadInput(f"{at}: variable {first.name} is used both as frame and as constant")
    if len(frame_vars) > 1:
        raise BadInput(f"{at}: all atoms must share one frame variable, found {', '.join(sorted(frame_vars))}")


def _first_vars(formula: Formula, expand: bool) -> dict[str, str]:
    """Variables in first-argument position (expanding or not) -> their predicate."""
    found: dict[str, str] = {}
    for atom in atoms(formula):
        first = atom.args[0]
        if isinstance(first, Var) and first.expand == expand:
            found.setdefault(first.name, atom.predicate)
    return found


def is_template(formula: Formula) -> bool:
    """Whether the formula has a `+var`, to be expanded over the training constants."""
    return bool(_first_vars(formula, expand=True))


@dataclass(frozen=True)
class Expanded:
    """One formula after `+var` expansion, with its own weight."""

    formula: Formula
    weight: float | None  # None: hard
    fixed: bool
    template: int  # index of the formula in the .mln


def expand_templates(
    formulas: list[WeightedFormula], space: AtomSpace
) -> tuple[list[Expanded], list[Expanded], list[str]]:
    """Expand `+var` over the constants of ``space``; formulas over constants outside it are left out.

    Returns the expanded formulas, the left-out ones and one warning per left-out formula. A template's weight is
    learned when it is 0, else it is an expert's weight and kept fixed; hard formulas stay hard.
    """
    expanded, left_out, warnings = [], [], []
    for index, item in enumerate(formulas):
        plus = _first_vars(item.formula, expand=True)
        names = list(plus)
        for values in itertools.product(*(space.constants(plus[n]) for n in names)):
            formula = substitute(item.formula, dict(zip(names, values)))
            unseen = [a for a in atoms(formula) if isinstance(a.args[0], Const) and not space.contains(a)]
            fixed = item.weight is not None and item.weight != 0.0
            if unseen:
                left_out.append(Expanded(formula, item.weight, fixed, index))
                warnings.append(
                    f"line {item.line}: {format_formula(formula)} uses {format_formula(unseen[0])}, which the "
                    "training split never shows; its weight stays 0"
                )
                continue
            expanded.append(Expanded(formula, item.weight, fixed, index))
    return expanded, left_out, warnings


def ground(formula: Formula, space: AtomSpace) -> list[Formula]:
    """Substitute the (non-frame) variables by every constant: the ground formulas of one frame."""
    free = _first_vars(formula, expand=False)
    names = list(free)
    return [
        substitute(formula, dict(zip(names, values)))
        for values in itertools.product(*(space.constants(free[n]) for n in names))
    ]


def truth(formula: Formula, rows: np.ndarray, space: AtomSpace, flip: int = -1) -> np.ndarray:
    """Truth of a ground formula on each row of the atom matrix, with atom ``flip`` negated."""
    if isinstance(formula, Atom):
        index = space.index(formula)
        column = rows[:, index]
        return ~column if index == flip else column
    if isinstance(formula, Not):
        return ~truth(formula.operand, rows, space, flip)
    if isinstance(formula, And):
        return np.logical_and.reduce([truth(o, rows, space, flip) for o in formula.operands])
    if isinstance(formula, Or):
        return np.logical_or.reduce([truth(o, rows, space, flip) for o in formula.operands])
    if isinstance(formula, Implies):
        return ~truth(formula.body, rows, space, flip) | truth(formula.head, rows, space, flip)
    assert isinstance(formula, Equiv)
    return truth(formula.left, rows, space, flip) == truth(formula.right, rows, space, flip)


def atom_matrix(evidence: np.ndarray, labels: np.ndarray | None, n_classes: int) -> np.ndarray:
    """[n, words + classes] bool: the word columns, then the one-hot labels (all false when None)."""
    one_hot = np.zeros((len(evidence), n_classes), dtype=bool)
    if labels is not None:
        one_hot[np.arange(len(evidence)), labels] = True
    return np.concatenate([evidence.astype(bool), one_hot], axis=1)


def atom_indices(formula: Formula, space: AtomSpace) -> list[int]:
    return sorted({space.index(a) for a in atoms(formula)})
