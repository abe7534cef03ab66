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
from mlnseq.catalog.errors import BadInput
from mlnseq.predicates.spec import (
    MAX_COLUMNS, Distance, Predicate, PredicateSpec, default_spec_path, load_spec, parse_spec,
)

__all__ = ["BinarizeOptions", "Binarized", "PredicateSpec", "binarize", "default_spec_path", "load_spec",
           "parse_spec", "run", "true_shares"]


@dataclass(frozen=True)
class BinarizeOptions:
    """Options of `mlnseq binarize`."""

    spec: Path | None = None  # default: the built-in stages/specs/<frames source>.binarize.toml
    suggest: Path | None = None  # write a starter spec from the frames here (stages/predicates/suggest.py), then use it
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
    names = [column for columns in spec.columns().values() for column in columns]
    return frames.select(artifacts.KEY_COLUMNS).with_columns(
        pl.Series(name, evidence[:, i], dtype=pl.Boolean) for i, name in enumerate(names))


def true_shares(predicates: pl.DataFrame, columns: dict[str, list[str]]) -> list[tuple[str, str, float]]:
    """(predicate, column, share of frames where it is true) for every column, in order."""
    means = predicates.select(pl.col(c).mean() for cols in columns.values() for c in cols).row(0, named=True)
    return [(name, column, float(means[column])) for name, cols in columns.items() for column in cols]


def run(workdir: Path, options: BinarizeOptions) -> tuple[Path, Binarized]:
    """Binarize ``workdir/frames.parquet`` into ``workdir/predicates.parquet`` (atomically)."""
    options.validate()
    frames_path = Path(workdir) / artifacts.FRAMES
    frames, frames_meta = artifacts.read_table(frames_path, "frames")
    source = frames_meta.get("source", "")
    if options.suggest is not None:
        from mlnseq.predicates.suggest import edited, suggest_spec

        if not options.replace and edited(Path(options.suggest), Path(workdir)):
            raise BadInput(f"{options.suggest} was edited since it was suggested: binarize with it by --spec "
                           f"{options.suggest}, or remove it (or --force) to suggest again")
        artifacts.write_text(Path(options.suggest), suggest_spec(frames, source))
        spec_path = Path(options.suggest)
    else:
        spec_path = Path(options.spec) if options.spec is not None else default_spec_path(source)
    if options.spec is None and not spec_path.is_file():
        raise BadInput(f"no built-in spec for frames of source {source!r}: pass --spec FILE, or --suggest to write a "
                       "starter spec from these frames (`mlnseq binarize --suggest`)")
    spec = load_spec(spec_path, options.max_columns)
    predicates = binarize(frames, spec)
    meta = {
        "predicates": spec.columns(),
        "spec": {"path": str(spec_path.resolve()), "text": spec.text},
        "classes": frames_meta.get("classes", []),
        "source": source,
        "options": {"spec": str(options.spec) if options.spec is not None else None,
                    "suggest": str(options.suggest) if options.suggest is not None else None},
    }
    path = artifacts.write_table(
        predicates, Path(workdir) / artifacts.PREDICATES, "predicates", meta, inputs=[frames_path, spec_path]
    )
    return path, Binarized(predicates, meta)
