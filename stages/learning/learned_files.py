"""What the learned predicates and formulas are written as, and said as: `WORKDIR/learned.binarize.toml` (the spec,
for `binarize --spec`), `WORKDIR/learned.formulas.mln` (the formulas, for `formulas --spec`; learn-weights then
writes each expanded formula with its weight, commented, to `WORKDIR/learned.mln`), a few lines in words for the
summary, and a record for predicates.parquet's metadata (`binarize --suggest`, `mlnseq fit` without --spec)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.learning import learned_spec
from mlnseq.learning import learned_logic
from mlnseq.learning.learned_logic import Conjunction, Searched

FORMULAS_SUFFIX = ".formulas.mln"
SAID = 5  # formulas said in words
FORMULAS_HEADER = ("// The formulas `mlnseq binarize --suggest` learned with the predicates of the spec beside this\n"
                   "// file (edit freely, then `mlnseq formulas --spec THIS_FILE`; `mlnseq learn-weights` learns "
                   "each 0.0 weight).\n\n")


def formulas_path(spec: Path) -> Path:
    """Where the learned formulas go beside the learned spec: ``NAME.binarize.toml`` -> ``NAME.formulas.mln``."""
    name = spec.name.removesuffix(".toml").removesuffix(".binarize")
    return spec.with_name(name + FORMULAS_SUFFIX)


@dataclass(frozen=True)
class Learned:
    """The learned spec's and formulas' text, the lines that say them, and their record."""

    spec: str
    formulas: str
    said: list[str]
    record: dict[str, Any] = field(default_factory=dict)
    fold_specs: list[str] = field(default_factory=list)  # the predicates learned again without each fold
    folds: dict[str, Any] | None = None  # the folds they were learned without (Folds.record)


def words(column: str) -> str:
    return column.replace("_", " ")


def conjunction_comment(body: Conjunction, classes: list[str], frames: int) -> str:
    counts = ", ".join(f"{classes[k]} {int(n)}" for k, n in sorted(enumerate(body.classes), key=lambda kn: -kn[1])
                       if n)
    total = int(body.classes.sum())
    return f"{body.first} ^ {body.second}: {total} training frames ({total / max(frames, 1):.0%}): {counts}"


def in_words(weights: pl.DataFrame, classes: list[str], count: int = SAID) -> list[str]:
    """The per-frame formulas that matter most, in words: per class its formula of largest positive weight, the
    ``count`` largest of those (``gripper closed ^ load high => transport, weight 2.1``)."""
    from mlnseq.mln.grounding import CLASS, EVIDENCE, is_temporal
    from mlnseq.mln.syntax import atoms, parse_formula

    best: dict[str, tuple[float, str]] = {}
    for text, weight in weights.select("formula", "weight").iter_rows():
        formula = parse_formula(text, "weights")
        if is_temporal(formula) or not weight > 0:
            continue
        found = atoms(formula)
        head = next((a.args[0].value for a in found if a.predicate == CLASS), None)
        body = " ^ ".join(words(a.args[0].value) for a in found if a.predicate == EVIDENCE)
        name = classes[int(head[1:])] if head and head[1:].isdigit() and int(head[1:]) < len(classes) else head
        if name is not None and weight > best.get(name, (0.0, ""))[0]:
            best[name] = (float(weight), f"{body} => {name}, weight {weight:.1f}")
    return [line for _, line in sorted(best.values(), reverse=True)[:count]]


def learn(frames: pl.DataFrame, classes: list[str], source: str) -> Learned:
    """Search ``frames`` (any order) for predicates and formulas and write them as text (learned_logic.search;
    without folds, the candidates of best information gain, not cross-validated)."""
    frames = frames.sort("episode", "frame", maintain_order=True)
    n_classes = max(len(classes), int(frames["label"].max()) + 1)
    names = list(classes) + [f"C{k}" for k in range(len(classes), n_classes)]
    searched = learned_logic.search(frames, n_classes)
    if searched is None or not searched.predicates:
        searched = learned_logic.uncrossed(frames, n_classes)
    if not searched.predicates:
        from mlnseq.catalog.errors import BadInput

        raise BadInput("binarize --suggest: no channel of the training split varies with its classes, so no predicate "
                       "can be learned; write a spec of your own and pass it with --spec")
    labels = searched.frames["label"].to_numpy().astype(np.int64)
    train = searched.train
    header = header_lines(searched, int(train.sum()), source)
    spec = learned_spec.render(searched.predicates, searched.distances, labels, train, names, header)
    comments = [conjunction_comment(c, names, int(train.sum())) for c in searched.conjunctions]
    formulas = learned_spec.with_digest(FORMULAS_HEADER + learned_logic.formulas_text(searched.conjunctions, comments),
                                        "//")
    said = [learned_spec.briefly(c) for c in searched.predicates]
    said += in_words(searched.weights, names) if searched.weights is not None else []
    record = {"predicates": [c.predicate.name for c in searched.predicates],
              "conjunctions": [f"{c.first} ^ {c.second}" for c in searched.conjunctions], "folds": searched.folds,
              "cross_validated": searched.figures, "path": searched.path, "candidates": searched.candidates,
              "channels": searched.channels,
              **({"searched_episodes": list(searched.sampled)} if searched.sampled else {})}
    k = searched.fold_record["k"] if searched.fold_record else 0
    fold_specs = [learned_spec.plain([f for c in searched.predicates if (f := c.by_fold[j]) is not None],
                                     searched.distances) for j in range(k)]
    return Learned(spec, formulas, said, record, fold_specs, searched.fold_record)


def header_lines(searched: Searched, frames: int, source: str) -> list[str]:
    """The learned spec's leading comment, wrapped: what was read, how the predicates were chosen, their figures."""
    import textwrap

    kept = ", ".join(c.predicate.name for c in searched.predicates)
    if searched.folds:
        figures = searched.figures
        chosen = (f"chosen by forward selection on {searched.folds} cross-validation of the MLN alone "
                  f"(docs/first-day.md): {kept}. Cross-validated, decoded by {figures.get('decoder', 'filter')}: "
                  f"frame accuracy {figures['frame_accuracy']:.1f}%, segment accuracy "
                  f"{figures['segment_accuracy']:.1f}%, edit {figures['edit']:.1f}.")
    else:
        chosen = f"too few training frames for 2 folds: the candidates of best information gain, {kept}; not " \
                 "cross-validated."
    read = f"{frames:,} training frames" if not searched.sampled else (
        f"{frames:,} training frames of {searched.sampled[0]} of its {searched.sampled[1]} episodes, drawn evenly from "
        "every fold")
    text = (f"Predicates `mlnseq binarize --suggest` learned from the training split of frames of source {source!r} "
            f"({read}; {searched.candidates} candidates on {searched.channels} channels), {chosen} "
            "Edit freely, then `mlnseq binarize --spec THIS_FILE`. Keys: docs/predicates.md.")
    return textwrap.wrap(text, 114, break_on_hyphens=False)
