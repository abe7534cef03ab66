"""A weights.parquet table read for people: its strongest formulas (the learn-weights summary, the report's
Table II), and what each formula's body holds in (the comments of learned.mln)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import polars as pl


def strongest(weights: pl.DataFrame, per_class: int = 3) -> pl.DataFrame:
    """The ``per_class`` largest weights of each class among the per-frame formulas (hard formulas first); classes
    in the order they first appear."""
    per_frame = weights.filter(~pl.col("temporal")) if "temporal" in weights.columns else weights
    per_frame = per_frame.filter(pl.col("class").is_not_null())
    order = {name: i for i, name in enumerate(dict.fromkeys(per_frame["class"].to_list()))}
    return (
        per_frame.with_columns(pl.col("class").replace_strict(order, return_dtype=pl.Int64).alias("_order"))
        .sort(["_order", "hard", "weight"], descending=[False, True, True]).drop("_order")
        .group_by("class", maintain_order=True).head(per_class)
    )


def strongest_temporal(weights: pl.DataFrame, count: int = 5) -> pl.DataFrame:
    """The hard temporal formulas, then the ``count`` temporal formulas of largest |weight|."""
    if "temporal" not in weights.columns:
        return weights.clear()
    temporal = weights.filter(pl.col("temporal"))
    return pl.concat([temporal.filter(pl.col("hard")),
                      temporal.filter(~pl.col("hard")).sort(pl.col("weight").abs(), descending=True).head(count)])


def body_comments(formulas: Sequence, rows: np.ndarray, starts: np.ndarray, space, classes: Sequence[str]) -> list[str]:
    """Per formula (Expanded, in order), a comment line where its body changes from the formula before: the training
    frames (pairs of consecutive frames, for a temporal formula) its body holds in, by class: its support and what
    it separates. ``rows``: the training frames' atoms (words, then one-hot classes over ``space``)."""
    from mlnseq.mln.grounding import PairSpace, is_temporal, next_atom, show, truth
    from mlnseq.mln.syntax import Implies, atoms, format_formula

    labels = rows[:, len(space.words):].argmax(axis=1) if len(space.classes) else np.zeros(len(rows), dtype=int)
    names = [classes[int(c[1:])] if c[1:].isdigit() and int(c[1:]) < len(classes) else c for c in space.classes]
    pairs = np.flatnonzero(~np.asarray(starts, dtype=bool))
    pair_rows = np.concatenate([rows[pairs - 1], rows[pairs]], axis=1)
    said, before = [], None
    for item in formulas:
        formula = item.formula
        body = formula.body if isinstance(formula, Implies) else formula
        key = format_formula(body)
        if key == before:
            said.append("")
            continue
        before = key
        if not all(space.contains(atom) for atom in atoms(body)):
            said.append(f"// {show(body, classes)}: never in the training split (its weight stays 0)")
            continue
        if is_temporal(formula):
            joined = next_atom(formula)
            holds = truth(body, pair_rows, PairSpace(space, joined.args[0].name, joined.args[1].name))
            counts = np.bincount(labels[pairs][holds], minlength=len(names))
            what = "pairs of consecutive training frames ({:.0%}); the later frame's class"
        else:
            holds = truth(body, rows, space)
            counts, what = np.bincount(labels[holds], minlength=len(names)), "training frames ({:.0%}), by class"
        by_class = ", ".join(f"{names[k]} {int(n)}" for k, n in sorted(enumerate(counts), key=lambda kn: -kn[1])
                             if n)
        said.append(f"// {show(body, classes)}: {int(holds.sum())} {what.format(holds.mean() if holds.size else 0)}: "
                    f"{by_class or 'none'}")
    return said
