"""Bind an MLN to mlnseq's database of frames and ground its formulas.

The database has two predicates, as in the paper: ``Has(<predicate column>, <frame>)`` is true
when that boolean column of predicates.parquet is true in the frame, and ``Topic(C<k>, <frame>)``
when the frame's label is k; and one relation, ``Next(<frame>, <frame>)``, true exactly when the
second frame follows the first in one chain (consecutive rows of one episode and split).

A per-frame formula relates atoms of one frame: each atom's last argument is the same frame
variable. A temporal formula relates two consecutive frames: exactly one ``Next(p, q)`` atom with
two different frame variables, every other atom on p or q, and it must hold whenever ``Next(p, q)``
is false (``Next`` in the body; a soft formula may instead be false there, a conjunction with ``Next``),
so that pairs of frames that are not consecutive count for nothing
and the formula is a factor between neighbours. A frame's atoms form one row of a boolean matrix (the
columns first, then the classes), a consecutive pair's atoms the previous row then the current one,
so a ground formula is evaluated on all frames or pairs at once.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.mln.syntax import (
    MLN, And, Atom, Const, Equiv, Formula, Implies, Not, Or, Var, WeightedFormula, atoms,
    format_formula, map_atoms, substitute,
)

EVIDENCE = "Has"
CLASS = "Topic"
NEXT = "Next"
DECLARATIONS = f"{EVIDENCE}(word, page)\n{CLASS}(class, page)\n"
NEXT_DECLARATION = f"{NEXT}(page, page)\n"
MAX_CHECKED_ATOMS = 20  # a temporal formula's distinct atoms: its Next-false check enumerates 2^n worlds


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

    def index(self, atom: Atom) -> int | None:
        """The atom's column in a frame's row (None for Next, which is not a frame's atom)."""
        if atom.predicate == NEXT:
            return None
        value = atom.args[0].value  # type: ignore[union-attr]
        if atom.predicate == EVIDENCE:
            return self._word_index[value]  # type: ignore[attr-defined]
        return len(self.words) + self._class_index[value]  # type: ignore[attr-defined]

    def contains(self, atom: Atom) -> bool:
        if atom.predicate == NEXT:
            return True
        value = atom.args[0].value  # type: ignore[union-attr]
        table = self._word_index if atom.predicate == EVIDENCE else self._class_index  # type: ignore[attr-defined]
        return value in table


@dataclass(frozen=True)
class PairSpace:
    """The atoms of two consecutive frames, the earlier one's first: a temporal formula is evaluated on
    rows [previous frame's atoms | current frame's atoms], where its Next atom is true."""

    frame: AtomSpace
    previous: str  # the frame variables of Next(previous, current)
    current: str

    @property
    def size(self) -> int:
        return 2 * self.frame.size

    def constants(self, predicate: str) -> tuple[str, ...]:
        return self.frame.constants(predicate)

    def index(self, atom: Atom) -> int | None:
        index = self.frame.index(atom)
        if index is None:
            return None
        return index + (self.frame.size if atom.args[-1].name == self.current else 0)  # type: ignore[union-attr]

    def contains(self, atom: Atom) -> bool:
        return self.frame.contains(atom)


def next_atom(formula: Formula) -> Atom | None:
    """The formula's Next atom, if any."""
    return next((a for a in atoms(formula) if a.predicate == NEXT), None)


def is_temporal(formula: Formula) -> bool:
    return next_atom(formula) is not None


def space_of(formula: Formula, frame: AtomSpace) -> AtomSpace | PairSpace:
    """Where the formula is evaluated: one frame's atoms, or a consecutive pair's (temporal formulas)."""
    joined = next_atom(formula)
    if joined is None:
        return frame
    return PairSpace(frame, joined.args[0].name, joined.args[1].name)  # type: ignore[union-attr]


def default_declarations(mln: MLN) -> str:
    """The declarations a file of formulas only gets: the paper's two predicates, and Next if it is used."""
    return DECLARATIONS + (NEXT_DECLARATION if any(is_temporal(f.formula) for f in mln.formulas) else "")


def class_aliases(class_names: Sequence[str]) -> dict[str, str]:
    """What a formula may call each class -> its constant ``C<k>`` inside mlnseq: the frames' own name, or the
    paper's ``C<k>`` (a frames' name wins where the two forms clash)."""
    aliases = {class_constant(k): class_constant(k) for k in range(len(class_names))}
    aliases.update({name: class_constant(k) for k, name in enumerate(class_names)})
    return aliases


def rename_classes(formula: Formula, names: dict[str, str]) -> Formula:
    """The formula with each Topic constant found in ``names`` replaced by what it maps to."""
    def rename(atom: Atom) -> Atom:
        first = atom.args[0] if atom.args else None
        if atom.predicate == CLASS and isinstance(first, Const) and first.value in names:
            return Atom(atom.predicate, (Const(names[first.value]), *atom.args[1:]), atom.column)
        return atom

    return map_atoms(formula, rename)


def name_classes(mln: MLN, class_names: Sequence[str]) -> MLN:
    """Turn the classes a formula names, ``Topic("lift", p)`` or the paper's ``Topic(C2, p)``, into the constants
    mlnseq grounds (``C<k>`` by label); ``shown`` turns them back into the frames' names."""
    aliases = class_aliases(class_names)
    mln.formulas = [replace(item, formula=rename_classes(item.formula, aliases)) for item in mln.formulas]
    return mln


def shown(formula: Formula, class_names: Sequence[str] | None) -> Formula:
    """The formula with each ``C<k>`` as the frames name class k (None: kept as ``C<k>``)."""
    if class_names is None:
        return formula
    return rename_classes(formula, {class_constant(k): name for k, name in enumerate(class_names)})


def show(formula: Formula, class_names: Sequence[str] | None) -> str:
    """``format_formula`` with the frames' class names."""
    return format_formula(shown(formula, class_names))


@dataclass(frozen=True)
class _Propositions:
    """Each distinct atom of one formula as a column of a truth table; Next is the last column."""

    columns: dict[tuple, int]

    def index(self, atom: Atom) -> int:
        return len(self.columns) if atom.predicate == NEXT else self.columns[(atom.predicate, atom.args)]


def holds_without_next(formula: Formula, where: str = "formula", value: bool = True) -> bool:
    """Whether the formula is true (``value`` False: false) in every world where its Next atom is false (its
    other atoms taken as independent propositions: a sufficient check). A soft formula false there, such as
    the conjunction Topic(c1, p) ^ Next(p, q) ^ Topic(c2, q), counts for nothing on pairs that are not
    consecutive, as one true there does."""
    keys = list(dict.fromkeys((a.predicate, a.args) for a in atoms(formula) if a.predicate != NEXT))
    if len(keys) > MAX_CHECKED_ATOMS:
        raise BadInput(f"{where}: a temporal formula may hold at most {MAX_CHECKED_ATOMS} distinct atoms, "
                       f"this one has {len(keys)}")
    worlds = (np.arange(2 ** len(keys))[:, None] >> np.arange(len(keys))[None, :]) & 1
    worlds = np.concatenate([worlds.astype(bool), np.zeros((len(worlds), 1), dtype=bool)], axis=1)
    return bool((truth(formula, worlds, _Propositions({k: i for i, k in enumerate(keys)})) == value).all())


def _first_vars(formula: Formula, expand: bool) -> dict[str, str]:
    """Variables in first-argument position (expanding or not) -> their predicate."""
    found: dict[str, str] = {}
    for atom in atoms(formula):
        if atom.predicate == NEXT:
            continue
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
    formulas: list[WeightedFormula], space: AtomSpace, class_names: Sequence[str] | None = None
) -> tuple[list[Expanded], list[Expanded], list[str]]:
    """Expand `+var` over the constants of ``space``; formulas over constants outside it are left out.

    Returns the expanded formulas, the left-out ones and the warnings (one per left-out formula, one per template
    whose expansions repeat formulas of other lines: each formula is learned once, a written one's weight winning
    over a template's, an earlier template's over a later one's). A template's weight is learned when it is 0, else
    it is an expert's weight and kept fixed; hard formulas stay hard. ``class_names``: for the warnings.
    """
    expanded, left_out, warnings = [], [], []
    seen = {format_formula(item.formula): item.line for item in formulas if not is_template(item.formula)}
    for index, item in enumerate(formulas):
        plus = _first_vars(item.formula, expand=True)
        names = list(plus)
        repeated: dict[int, int] = {}  # line of the formula kept -> how many of this template's expansions repeat it
        for values in itertools.product(*(space.constants(plus[n]) for n in names)):
            formula = substitute(item.formula, dict(zip(names, values)))
            if names:
                line = seen.setdefault(format_formula(formula), item.line)
                if line != item.line:
                    repeated[line] = repeated.get(line, 0) + 1
                    continue
            unseen = [a for a in atoms(formula) if isinstance(a.args[0], Const) and not space.contains(a)]
            fixed = item.weight is not None and item.weight != 0.0
            if unseen:
                left_out.append(Expanded(formula, item.weight, fixed, index))
                warnings.append(
                    f"line {item.line}: {show(formula, class_names)} uses {show(unseen[0], class_names)}, which the "
                    "training split never shows; its weight stays 0"
                )
                continue
            expanded.append(Expanded(formula, item.weight, fixed, index))
        warnings += [f"line {item.line}: {count} expansion(s) of this template repeat the formula(s) of line {line}: "
                     f"each is learned once, as line {line} gives it" for line, count in repeated.items()]
    return expanded, left_out, warnings


def ground(formula: Formula, space: AtomSpace) -> list[Formula]:
    """Substitute the (non-frame) variables by every constant: the ground formulas of one frame."""
    free = _first_vars(formula, expand=False)
    names = list(free)
    return [
        substitute(formula, dict(zip(names, values)))
        for values in itertools.product(*(space.constants(free[n]) for n in names))
    ]


def truth(formula: Formula, rows: np.ndarray, space, flip: int = -1) -> np.ndarray:
    """Truth of a ground formula on each row of the atom matrix of ``space`` (an AtomSpace, or a PairSpace
    whose rows are consecutive pairs: Next is true), with atom ``flip`` negated."""
    if isinstance(formula, Atom):
        index = space.index(formula)
        if index is None:
            return np.ones(len(rows), dtype=bool)
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


def atom_indices(formula: Formula, space) -> list[int]:
    """The columns of the formula's atoms in the rows of ``space`` (Next, not a frame's atom, has none)."""
    return sorted({i for a in atoms(formula) if (i := space.index(a)) is not None})
