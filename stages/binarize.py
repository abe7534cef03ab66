"""binarize: turn ``frames.parquet`` into ``predicates.parquet``, one boolean column per ground predicate.

The spec (its language and parser: stages/predicates/spec.py) declares derived channels and predicates;
stages/predicates/rules.py holds the rules that give each frame its codes. The core, :func:`binarize`,
checks the frames against the spec and evaluates it over them; :func:`run` reads and writes the files.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.predicates import rules as predicate_rules
from mlnseq.catalog.errors import BadInput, MlnseqError
from mlnseq.predicates.spec import (
    MAX_COLUMNS, Distance, Predicate, PredicateSpec, default_spec_path, load_spec, parse_spec,
)

__all__ = ["BinarizeOptions", "Binarized", "PredicateSpec", "binarize", "default_spec_path", "load_spec",
           "parse_spec", "run", "true_shares"]


@dataclass(frozen=True)
class BinarizeOptions:
    """Options of `mlnseq binarize`."""

    spec: Path | None = None  # default: the built-in stages/specs/<frames source>.binarize.toml
    suggest: Path | None = None  # learn a spec (and formulas) from the frames, write it here, then binarize with it
    replace: bool = False  # --suggest may overwrite a file edited by hand
    max_columns: int = MAX_COLUMNS  # refuse a spec that makes more predicate columns

    def validate(self) -> None:
        if self.max_columns < 1:
            raise BadInput(f"--max-columns {self.max_columns}: allow at least 1 column")
        if self.spec is not None and self.suggest is not None:
            raise BadInput("--spec and --suggest: give one (--suggest writes a spec from the data, --spec reads yours)")
        if self.spec is not None and not Path(self.spec).is_file():
            raise BadInput(f"--spec {self.spec} not found: point it at a .binarize.toml file")



@dataclass(frozen=True)
class Binarized:
    """What a binarization made: the predicates table and its metadata."""

    predicates: pl.DataFrame
    meta: dict[str, Any]
    path: Path | None = None  # where it was read from (``as_it_is``); None: just made


def binarize(frames: pl.DataFrame, spec: PredicateSpec) -> pl.DataFrame:
    """The predicates table of ``frames``: its keys, then one boolean column per ground predicate value."""
    if frames.height == 0:
        raise BadInput("frames.parquet holds no frames; rerun `mlnseq collect`")
    frames = frames.sort("episode", "frame", maintain_order=True)
    episode = frames["episode"].to_numpy()
    first = np.ones(len(episode), dtype=bool)
    first[1:] = episode[1:] != episode[:-1]
    for derived in spec.channels:
        if derived.name in frames.columns:
            raise BadInput(f"{spec.where(derived, 'name')}: key 'name' of [[channel]] {derived.name!r}: "
                           "frames.parquet already has a column of that name; rename the channel")

    def raw(entry: Distance | Predicate, name: str, key: str) -> np.ndarray:
        if name not in frames.columns or name in artifacts.KEY_COLUMNS:
            known = artifacts.feature_columns(frames) + [c.name for c in spec.channels]
            raise predicate_rules.missing_channel(spec, entry, name, key, "frames.parquet", known)
        values = frames[name].cast(pl.Float64).to_numpy()
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            row = frames.row(int(bad[0]), named=True)
            raise BadInput(f"frames.parquet column {name!r} is NaN or infinite at episode {row['episode']} "
                           f"frame {row['frame']}; repair the frames and rerun `mlnseq collect`")
        return values

    evidence = predicate_rules.evidence(spec, predicate_rules.channels_of(spec, raw), first)
    names = names_of(spec)
    return frames.select(artifacts.KEY_COLUMNS).with_columns(
        pl.Series(name, evidence[:, i], dtype=pl.Boolean) for i, name in enumerate(names))


def as_it_is(workdir: Path) -> Binarized | None:
    """The workdir's predicates as they are (``binarize --table`` without a spec: nothing rewritten, nothing made
    stale), or None where it has none."""
    path = Path(workdir) / artifacts.PREDICATES
    if not path.exists():
        return None
    return Binarized(*artifacts.read_table(path, "predicates"), path=path)


def true_shares(predicates: pl.DataFrame, columns: dict[str, list[str]]) -> list[tuple[str, str, float]]:
    """(predicate, column, share of frames where it is true) for every column, in order."""
    means = predicates.select(pl.col(c).mean() for cols in columns.values() for c in cols).row(0, named=True)
    return [(name, column, float(means[column])) for name, cols in columns.items() for column in cols]


def formulas_of(spec: Path) -> Path:
    from mlnseq.learning.learned_files import formulas_path

    return formulas_path(spec).resolve()


def write_learned(spec: Path, frames: pl.DataFrame, frames_meta: dict[str, Any], replace: bool) -> Any:
    """--suggest: learn predicates and formulas from the training split (stages/learning/learned_logic.py) and write
    them to ``spec`` and the formulas file beside it; a file of either edited by hand is kept unless ``replace``. The
    record says what was learned and how (its formulas file, the few formulas in words, the search)."""
    from mlnseq.learning.learned_spec import untouched
    from mlnseq.learning.learned_files import formulas_path, learn

    formulas = formulas_path(spec)
    for path, mark in ((spec, "#"), (formulas, "//")):
        if not replace and path.exists() and not untouched(path.read_text(encoding="utf-8"), mark):
            raise BadInput(f"{path} was edited since it was learned: binarize with it by --spec {spec} (and "
                           f"`mlnseq formulas --spec {formulas}`), or remove it (or --force) to learn again")
    learned = learn(frames, list(frames_meta.get("classes", [])), frames_meta.get("source", ""))
    artifacts.write_text(formulas, learned.formulas)
    artifacts.write_text(spec, learned.spec)
    return learned


def fold_predicates(frames: pl.DataFrame, learned: Any, spec: Path, columns: list[str]) -> pl.DataFrame:
    """The learned predicates learned again without each fold, binarized: each fold's table over every frame
    (column ``fold``), with the columns of ``columns`` (the whole split's) then any a fold adds; a column a fold's
    predicates lack is false there."""
    tables = []
    for k, text in enumerate(learned.fold_specs):
        try:
            table = binarize(frames, parse_spec(text, spec.with_name(f"{spec.name} without fold {k}")))
        except BadInput:  # a fold where no predicate was found: no evidence there
            table = frames.select(artifacts.KEY_COLUMNS)
        tables.append(table.with_columns(pl.lit(k, dtype=pl.Int16).alias("fold")))
    every = list(dict.fromkeys(columns + [c for t in tables for c in artifacts.feature_columns(t) if c != "fold"]))
    return pl.concat([t.select(*artifacts.KEY_COLUMNS, "fold", *(pl.col(c) if c in t.columns else
                                                                  pl.lit(False).alias(c) for c in every))
                      for t in tables])


def run(workdir: Path, options: BinarizeOptions) -> tuple[Path, Binarized]:
    """Binarize ``workdir/frames.parquet`` into ``workdir/predicates.parquet`` (atomically)."""
    options.validate()
    frames_path = Path(workdir) / artifacts.FRAMES
    frames, frames_meta = artifacts.read_table(frames_path, "frames")
    frames = artifacts.labelled(frames)  # unlabelled recordings are learned from elsewhere (mlnseq.labelling)
    source = frames_meta.get("source", "")
    learned = None
    if options.suggest is not None:
        learned = write_learned(Path(options.suggest), frames, frames_meta, options.replace)
        spec_path = Path(options.suggest)
    else:
        spec_path = Path(options.spec) if options.spec is not None else default_spec_path(source)
        if options.spec is None and not spec_path.is_file():
            spec_path = made_from(Path(workdir)) or spec_path
    if options.spec is None and not spec_path.is_file():
        raise BadInput(f"no built-in spec for frames of source {source!r}: pass --spec FILE, or --suggest to write a "
                       "starter spec from these frames (`mlnseq binarize --suggest`)")
    spec = load_spec(spec_path, options.max_columns)
    predicates = binarize(frames, spec)
    meta = {
        "predicates": spec.columns(),
        "spec": {"path": str(spec_path.resolve()), "text": spec.text},
        "learned": None if learned is None else {**learned.record, "formulas": str(formulas_of(spec_path)),
                                                 "said": learned.said},
        "classes": frames_meta.get("classes", []),
        "source": source,
        "options": {"spec": str(options.spec) if options.spec is not None else None,
                    "suggest": str(options.suggest) if options.suggest is not None else None},
    }
    path = artifacts.write_table(
        predicates, Path(workdir) / artifacts.PREDICATES, "predicates", meta, inputs=[frames_path, spec_path]
    )
    folded = Path(workdir) / artifacts.FOLD_PREDICATES
    if learned is not None and learned.folds:
        artifacts.write_table(fold_predicates(frames, learned, spec_path, names_of(spec)), folded, "fold_predicates",
                              {"folds": learned.folds, "spec_text": spec.text}, inputs=[frames_path])
    elif folded.exists() and fold_spec_text(folded) != spec.text:
        folded.unlink()  # another spec's, or older frames': stale
    return path, Binarized(predicates, meta)


def fold_spec_text(path: Path) -> str | None:
    """The spec text a predicates.folds.parquet was learned for (None: unreadable, or made from older frames)."""
    try:
        return artifacts.read_metadata(path, "fold_predicates").get("spec_text")
    except MlnseqError:
        return None


def made_from(workdir: Path) -> Path | None:
    """The spec file the workdir's predicates were made from, where it still holds the text they were made from (a
    bag workdir's learned or own spec, for `binarize --table` without --spec)."""
    import json

    import pyarrow.parquet as pq

    try:
        made = json.loads(pq.read_schema(workdir / artifacts.PREDICATES).metadata[artifacts.META_KEY])["spec"]
        path = Path(made["path"])
        return path if path.is_file() and path.read_text(encoding="utf-8") == made["text"] else None
    except Exception:  # no predicates yet, or not ours
        return None


def names_of(spec: PredicateSpec) -> list[str]:
    return [column for columns in spec.columns().values() for column in columns]
