"""What if one predicate had another value at a frame: `mlnseq explain --what-if "PREDICATE=VALUE"`.

PREDICATE is a predicate of the model's spec (``left_gripper``) and VALUE one of its values (``closed``): the
frame's columns of that predicate become that value (one true, the others false), and a pair predicate built on it
(``grippers``) follows. Or PREDICATE is one column (``grippers_closed_closed``) and VALUE true or false. The frame is
then scored again, the whole recording with it (the change reaches the frames after through the chain, and the
network through PriorLayer's input), and decided by the same decoder.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from mlnseq.catalog.errors import BadInput
from mlnseq.predicates.rules import pair_code
from mlnseq.predicates.spec import Pair, PredicateSpec

TRUE, FALSE = ("true", "1", "yes"), ("false", "0", "no")


@dataclass(frozen=True)
class WhatIf:
    """One predicate's value (or one column's truth) to put in place of the frame's."""

    text: str  # as written
    predicate: str | None  # a predicate of the spec, or None: a column
    value: str

    def edit(self, spec: PredicateSpec, columns: list[str], row: int) -> Callable[[np.ndarray], np.ndarray]:
        """Evidence [T, W] -> the same with the change at ``row``."""
        def edited(evidence: np.ndarray) -> np.ndarray:
            changed = evidence.copy()
            changed[row] = self.row(spec, columns, evidence[row])
            return changed

        return edited

    def row(self, spec: PredicateSpec, columns: list[str], values: np.ndarray) -> np.ndarray:
        """One evidence row with the change."""
        out = np.asarray(values, dtype=bool).copy()
        if self.predicate is None:
            out[columns.index(self.value.partition("=")[0])] = self.value.partition("=")[2] in TRUE
            return out
        groups = spec.columns()
        codes = {name: int(np.argmax(out[[columns.index(c) for c in group]])) for name, group in groups.items()}
        codes[self.predicate] = list(groups[self.predicate]).index(f"{self.predicate}_{self.value}")
        sizes = {p.name: len(p.values) for p in spec.predicates}
        for predicate in spec.predicates:  # pairs after their parts, as the spec lists them
            if isinstance(predicate, Pair) and self.predicate in (predicate.first, predicate.second):
                codes[predicate.name] = pair_code(codes[predicate.first], codes[predicate.second],
                                                  sizes[predicate.second])
        for name, group in groups.items():
            for index, column in enumerate(group):
                out[columns.index(column)] = index == codes[name]
        return out


def parse_what_if(text: str, spec: PredicateSpec | None, columns: list[str]) -> WhatIf:
    """``PREDICATE=VALUE`` checked against the model's spec; a bad one names what there is to choose."""
    if spec is None:
        raise BadInput("--what-if: this model has no MLN, so no predicate to change")
    name, equals, value = (part.strip() for part in text.partition("="))
    if not equals or not name or not value:
        raise BadInput(f"--what-if {text!r}: write PREDICATE=VALUE, e.g. left_gripper=closed")
    predicates = {p.name: p for p in spec.predicates}
    if name in predicates:
        if isinstance(predicates[name], Pair):
            raise BadInput(f"--what-if {text!r}: {name} is the pair of {predicates[name].first} and "
                           f"{predicates[name].second}; change one of them")
        if value not in predicates[name].values:
            raise BadInput(f"--what-if {text!r}: {name} is one of {', '.join(predicates[name].values)}")
        return WhatIf(text, name, value)
    if name in columns:
        if value.lower() not in TRUE + FALSE:
            raise BadInput(f"--what-if {text!r}: a column is true or false")
        return WhatIf(text, None, f"{name}={value.lower()}")
    raise BadInput(f"--what-if {text!r}: {name} is neither a predicate of the model's spec "
                   f"({', '.join(predicates)}) nor one of its columns")
