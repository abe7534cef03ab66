"""learn-weights: learn the formulas' weights on the training split (pracmln's BPLL objective).

Reads predicates.parquet and a .mln file; writes ``weights.parquet`` (one row per expanded
formula: formula, class, weight, fixed, hard, template) and ``learned.mln``, the weighted,
expanded formulas as a .mln pracmln can read. Engines: ``native`` (stages.mln.bpll) and
``pracmln`` (the paper's engine, through stages.mln.pracmln_compat).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import polars as pl

from stages import artifacts
from stages.errors import BadInput, MlnseqError
from stages.formulas import formulas_for, read_spec
from stages.mln import bpll, pracmln_compat
from stages.mln.grounding import CLASS, AtomSpace, Expanded, atom_matrix, class_constant, expand_templates
from stages.mln.syntax import MLN, WeightedFormula, atoms, format_formula, format_weighted, parse_formula

ENGINES = ("native", "pracmln")


@dataclass(frozen=True)
class LearnWeightsOptions:
    formulas: Path = Path(artifacts.FORMULAS)  # relative to the current folder, else to the workdir
    engine: str = "native"

    def validate(self) -> None:
        if self.engine not in ENGINES:
            raise BadInput(f"unknown --engine {self.engine!r}: choose one of {', '.join(ENGINES)}")

    def formulas_path(self, workdir: Path) -> Path:
        path = Path(self.formulas)
        if path.is_file() or path.is_absolute():
            return path
        return Path(workdir) / path


@dataclass(frozen=True)
class Learned:
    weights: pl.DataFrame
    learned_mln: str
    warnings: list[str]


def training_space(predicates: pl.DataFrame, n_classes: int) -> tuple[AtomSpace, np.ndarray, list[str]]:
    """The constants the training split shows, its atom matrix, and warnings for unseen classes."""
    train = predicates.filter(predicates["split"] == "train")
    if train.height == 0:
        raise BadInput("predicates.parquet has no training frames (split 'train'); rerun `mlnseq collect` with training frames")
    columns = artifacts.feature_columns(predicates)
    evidence = train.select(columns).to_numpy().astype(bool)
    labels = train["label"].to_numpy().astype(np.int64)
    if labels.min() < 0 or labels.max() >= n_classes:
        raise BadInput(f"predicates.parquet has labels outside the {n_classes} classes of its metadata; rerun `mlnseq binarize`")
    words = [c for c, seen in zip(columns, evidence.any(axis=0)) if seen]
    present = sorted(set(labels.tolist()))
    warnings = [
        f"class {class_constant(k)} never occurs in the training split; formulas about it get weight 0"
        for k in range(n_classes) if k not in present
    ]
    space = AtomSpace(tuple(words), tuple(class_constant(k) for k in present))
    rows = atom_matrix(evidence[:, [columns.index(w) for w in words]], None, 0)
    one_hot = labels[:, None] == np.array(present)[None, :]
    return space, np.concatenate([rows, one_hot], axis=1), warnings


def database(rows: np.ndarray, space: AtomSpace) -> str:
    """The training frames as a pracmln database: one page P<i> per frame, true atoms only."""
    names = [f'Has("{w}",P{{i}})' for w in space.words] + [f'Topic("{c}",P{{i}})' for c in space.classes]
    lines = [name.format(i=i) for i, row in enumerate(rows) for name, on in zip(names, row) if on]
    return "\n".join(lines) + "\n"


def pracmln_weights(mln: MLN, expanded: list[Expanded], space: AtomSpace, rows: np.ndarray) -> np.ndarray:
    """Learn with pracmln itself (it expands the templates) and match its formulas to ``expanded``."""
    kept = sorted({e.template for e in expanded})
    text = "".join(f"{n}({', '.join(d)})\n" for n, d in mln.predicates.items())
    text += "".join(format_weighted(mln.formulas[i]) + "\n" for i in kept)
    fixed = [mln.formulas[i].weight is not None and mln.formulas[i].weight != 0.0 for i in kept]
    learned = {format_formula(parse_formula(f, "pracmln")): w for f, w in pracmln_compat.learn_weights(text, database(rows, space), fixed)}
    weights = []
    for item in expanded:
        key = format_formula(item.formula)
        if key not in learned:
            raise MlnseqError(f"pracmln returned no weight for {key}")
        weights.append(np.inf if item.weight is None else learned[key])
    return np.array(weights, dtype=np.float64)


def head_class(item: Expanded) -> str | None:
    """The class a formula is about: its one Topic constant, else None."""
    constants = {a.args[0].value for a in atoms(item.formula) if a.predicate == CLASS and hasattr(a.args[0], "value")}
    return constants.pop() if len(constants) == 1 else None


def learn(predicates: pl.DataFrame, n_classes: int, mln: MLN, engine: str = "native") -> Learned:
    """Expand and learn the weights of ``mln`` on the training split of ``predicates`` (pure)."""
    space, rows, warnings = training_space(predicates, n_classes)
    expanded, left_out, expand_warnings = expand_templates(mln.formulas, space)
    warnings += expand_warnings
    if engine == "native":
        weights = bpll.learn(expanded, rows, space)
    else:
        weights = pracmln_weights(mln, expanded, space, rows) if expanded else np.zeros(0)
    every = expanded + left_out
    values = np.concatenate([weights, np.zeros(len(left_out))])
    table = pl.DataFrame(
        {
            "formula": [format_formula(e.formula) for e in every],
            "class": [head_class(e) for e in every],
            "weight": values,
            "fixed": [e.fixed for e in every],
            "hard": [e.weight is None for e in every],
            "template": [e.template for e in every],
        },
        schema={"formula": pl.String, "class": pl.String, "weight": pl.Float64, "fixed": pl.Boolean,
                "hard": pl.Boolean, "template": pl.Int32},
    )
    return Learned(table, render_learned(mln, every, values, engine), warnings)


def render_learned(mln: MLN, formulas: list[Expanded], weights: np.ndarray, engine: str) -> str:
    lines = [f"// mlnseq learn-weights ({engine} BPLL): weighted, expanded formulas", ""]
    lines += [f"{name}({', '.join(domains)})" for name, domains in mln.predicates.items()] + [""]
    lines += [format_weighted(WeightedFormula(e.formula, None if e.weight is None else float(w)))
              for e, w in zip(formulas, weights)]
    return "\n".join(lines) + "\n"


def strongest(weights: pl.DataFrame, per_class: int = 3) -> pl.DataFrame:
    """The ``per_class`` largest weights of each class (hard formulas first)."""
    return (
        weights.filter(pl.col("class").is_not_null())
        .sort(["class", "hard", "weight"], descending=[False, True, True])
        .group_by("class", maintain_order=True).head(per_class)
    )


def run(workdir: Path, options: LearnWeightsOptions) -> tuple[Path, Learned]:
    """Read predicates.parquet and the formulas; write weights.parquet and learned.mln."""
    options.validate()
    workdir = Path(workdir)
    predicates_path = workdir / artifacts.PREDICATES
    predicates, meta = artifacts.read_table(predicates_path, "predicates")
    formulas_path = options.formulas_path(workdir)
    if not formulas_path.is_file():
        raise BadInput(f"{options.formulas} not found here nor in {workdir}: run `mlnseq formulas` first")
    mln = read_spec(formulas_path)
    classes = meta.get("classes") or []
    formulas_for(mln, formulas_path, artifacts.feature_columns(predicates), list(classes))
    learned = learn(predicates, len(classes), mln, options.engine)
    record = {k: str(v) for k, v in asdict(options).items()}
    table_meta = {"options": record, "engine": options.engine, "classes": classes,
                  "source": meta.get("source"), "warnings": learned.warnings}
    with artifacts.atomic_path(workdir / artifacts.LEARNED_MLN) as staged:  # both or neither
        staged.write_text(learned.learned_mln, encoding="utf-8")
        path = artifacts.write_table(learned.weights, workdir / artifacts.WEIGHTS, "weights", table_meta,
                                     inputs=[predicates_path, formulas_path])
    return path, learned
