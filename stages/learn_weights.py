"""learn-weights: learn the formulas' weights on the training split.

Reads predicates.parquet and a .mln file; writes ``weights.parquet`` (one row per expanded
formula: formula, class, weight, fixed, hard, template, temporal) and ``learned.mln``, the weighted,
expanded formulas as a .mln pracmln can read. Objectives: ``pll``, pracmln's pseudo-likelihood
(mlnseq.mln.bpll), and ``cll``, the exact conditional likelihood of each chain's classes given its
evidence (mlnseq.mln.cll), the default when a formula uses Next. Engines: ``native`` and ``pracmln``
(the paper's engine, pll only, through mlnseq.mln.pracmln_compat). The chains are the runs of training
frames of one episode (a change of split within an episode cuts it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput, MlnseqError, check_choice
from mlnseq.mln import bpll, cll, pracmln_compat
from mlnseq.mln.chain import chain_starts
from mlnseq.mln.formula_spec import formulas_for, read_spec
from mlnseq.mln.grounding import (
    CLASS, NEXT, AtomSpace, Expanded, atom_matrix, class_constant, expand_templates, ground, is_temporal, next_atom,
    show, shown, space_of, truth,
)
from mlnseq.mln.syntax import MLN, Const, Var, WeightedFormula, atoms, format_formula, format_weighted, parse_formula

ENGINES = ("native", "pracmln")
OBJECTIVES = ("pll", "cll")
SHOWN_FRAMES = 5  # frames named when a hard formula is broken
MAX_FORMULAS = 20_000  # ground formulas the templates and variables may expand to (--max-formulas)


@dataclass(frozen=True)
class LearnWeightsOptions:
    formulas: Path = Path(artifacts.FORMULAS)  # relative to the current folder, else to the workdir
    engine: str = "native"
    objective: str | None = None  # pll | cll; None: cll when a formula uses Next, else pll
    l2: float | None = None  # L2 penalty on the learned weights; None: 0 for pll, cll.DEFAULT_L2 for cll
    # K > 0: also learn each fold's weights without it (weights.folds.parquet), see stages/choosing/folds.py
    folds: int = 0
    max_formulas: int = MAX_FORMULAS  # refuse formulas whose templates and variables expand past this many

    def validate(self) -> None:
        check_choice("engine", self.engine, ENGINES)
        if self.max_formulas < 1:
            raise BadInput(f"--max-formulas {self.max_formulas}: allow at least 1 formula")
        if self.objective is not None:
            check_choice("objective", self.objective, OBJECTIVES)
        if self.l2 is not None and not (math.isfinite(self.l2) and self.l2 >= 0):
            raise BadInput(f"--l2 must be a number >= 0, got {self.l2}")
        if self.folds < 0:
            raise BadInput(f"--folds {self.folds}: use 0 (no folds) or at least 2 folds")

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
    objective: str = "pll"
    l2: float = 0.0


@dataclass(frozen=True)
class Training:
    """The training split as the learners see it."""

    space: AtomSpace  # the predicate columns and the classes the training split shows
    rows: np.ndarray  # bool [n, words + present classes]: each frame's atoms
    labels: np.ndarray  # [n] class of each frame (0 .. n_classes - 1)
    starts: np.ndarray  # bool [n]: where a chain starts
    episodes: np.ndarray  # [n] for messages
    frames: np.ndarray
    warnings: list[str]

    @property
    def evidence(self) -> np.ndarray:
        return self.rows[:, :len(self.space.words)]

    def frame_name(self, index: int) -> str:
        return f"episode {self.episodes[index]} frame {self.frames[index]}"


def training_data(predicates: pl.DataFrame, n_classes: int, class_names: Sequence[str] | None = None) -> Training:
    """The constants the training split shows, its atom matrix and chains, and warnings for unseen classes."""
    starts = chain_starts(predicates["episode"].to_numpy(), predicates["split"].to_numpy())
    is_train = (predicates["split"] == "train").to_numpy()
    train = predicates.filter(pl.Series(is_train))
    if train.height == 0:
        raise BadInput("predicates.parquet has no training frames (split 'train'); rerun `mlnseq collect` with "
                       "training frames")
    columns = artifacts.feature_columns(predicates)
    evidence = train.select(columns).to_numpy().astype(bool)
    labels = train["label"].to_numpy().astype(np.int64)
    if labels.min() < 0 or labels.max() >= n_classes:
        raise BadInput(f"predicates.parquet has labels outside the {n_classes} classes of its metadata; "
                       "rerun `mlnseq binarize`")
    words = [c for c, seen in zip(columns, evidence.any(axis=0)) if seen]
    present = sorted(set(labels.tolist()))
    warnings = [
        f"class {class_constant(k) if class_names is None else class_names[k]} never occurs in the training split; "
        "formulas about it get weight 0"
        for k in range(n_classes) if k not in present
    ]
    space = AtomSpace(tuple(words), tuple(class_constant(k) for k in present))
    rows = atom_matrix(evidence[:, [columns.index(w) for w in words]], None, 0)
    one_hot = labels[:, None] == np.array(present)[None, :]
    return Training(space, np.concatenate([rows, one_hot], axis=1), labels, starts[is_train],
                    train["episode"].to_numpy(), train["frame"].to_numpy(), warnings)


def check_hard(expanded: list[Expanded], mln: MLN, training: Training, where: str,
               class_names: Sequence[str] | None = None) -> None:
    """Refuse a hard formula that the training frames (or consecutive pairs) break, naming the frames."""
    pairs = np.flatnonzero(~training.starts)
    pair_rows = np.concatenate([training.rows[pairs - 1], training.rows[pairs]], axis=1)
    for item in expanded:
        if item.weight is not None:
            continue
        space = space_of(item.formula, training.space)
        rows, frames = ((pair_rows, pairs) if is_temporal(item.formula)
                        else (training.rows, np.arange(len(training.rows))))
        broken = np.zeros(len(rows), dtype=bool)
        for grounding in ground(item.formula, space):
            broken |= ~truth(grounding, rows, space)
        if broken.any():
            named = ", ".join(training.frame_name(i) for i in frames[broken][:SHOWN_FRAMES])
            more = f" and {broken.sum() - SHOWN_FRAMES} more" if broken.sum() > SHOWN_FRAMES else ""
            raise BadInput(f"{where}:{mln.formulas[item.template].line}: hard formula "
                           f"{show(item.formula, class_names)} is "
                           f"false at {broken.sum()} training frame(s): {named}{more}; fix their labels, or give the "
                           "formula a weight to make it soft")


def resolve_objective(options: LearnWeightsOptions, temporal: bool) -> tuple[str, float]:
    objective = options.objective or ("cll" if temporal else "pll")
    if options.engine == "pracmln" and objective != "pll":
        raise BadInput(f"--engine pracmln learns by pseudo-likelihood only; add --objective pll "
                       f"({'the formulas use Next, so the default is cll' if temporal else 'or use --engine native'})")
    l2 = options.l2 if options.l2 is not None else (cll.DEFAULT_L2 if objective == "cll" else 0.0)
    return objective, l2


def database(training: Training, temporal: bool) -> str:
    """The training frames as a pracmln database: one page P<i> per frame, true atoms only, and (``temporal``)
    Next(P<i>, P<i+1>) between consecutive frames of a chain."""
    space = training.space
    names = [f'Has("{w}",P{{i}})' for w in space.words] + [f'Topic("{c}",P{{i}})' for c in space.classes]
    lines = [name.format(i=i) for i, row in enumerate(training.rows) for name, on in zip(names, row) if on]
    lines += [f"{NEXT}(P{i - 1},P{i})" for i in np.flatnonzero(~training.starts)] if temporal else []
    return "\n".join(lines) + "\n"


def pracmln_weights(mln: MLN, expanded: list[Expanded], training: Training, l2: float) -> np.ndarray:
    """Learn with pracmln itself (it expands the templates) and match its formulas to ``expanded``."""
    kept = sorted({e.template for e in expanded})
    temporal = any(is_temporal(mln.formulas[i].formula) for i in kept)
    text = "".join(f"{n}({', '.join(d)})\n" for n, d in mln.predicates.items() if n != NEXT or temporal)
    text += "".join(format_weighted(mln.formulas[i]) + "\n" for i in kept)
    fixed = [mln.formulas[i].weight is not None and mln.formulas[i].weight != 0.0 for i in kept]
    learned = {format_formula(parse_formula(f, "pracmln")): w for f, w in pracmln_compat.learn_weights(
        text, database(training, temporal), fixed, evidence=(NEXT,) if temporal else (), l2=l2)}
    weights = []
    for item in expanded:
        key = format_formula(item.formula)
        if key not in learned:
            raise MlnseqError(f"pracmln returned no weight for {key}")
        weights.append(np.inf if item.weight is None else learned[key])
    return np.array(weights, dtype=np.float64)


def head_class(item: Expanded, class_names: Sequence[str] | None = None) -> str | None:
    """The class a formula is about: its one Topic constant (a temporal formula: on the later frame), else None;
    as the frames name it (``class_names``) or as its C<k>."""
    joined = next_atom(item.formula)
    constants = {a.args[0].value for a in atoms(item.formula) if a.predicate == CLASS and isinstance(a.args[0], Const)
                 and (joined is None or a.args[-1] == joined.args[1])}
    if len(constants) != 1:
        return None
    constant = constants.pop()
    return constant if class_names is None else class_names[int(constant[1:])]


def check_expansion(mln: MLN, space: AtomSpace, limit: int, where: str) -> None:
    """Count the ground formulas each formula's `+var`s and variables make over ``space`` before any is built;
    refuse past ``limit``, naming the largest."""
    counts = []
    for item in mln.formulas:
        count = 1
        for predicate in _first_variables(item.formula).values():
            count *= len(space.constants(predicate))
        counts.append(count)
    if counts and sum(counts) > limit:
        largest = mln.formulas[int(np.argmax(counts))]
        raise BadInput(f"{where}:{largest.line}: the formulas expand to {sum(counts):,} ground formulas over the "
                       f"training split's constants ({max(counts):,} from this line's variables), over "
                       f"--max-formulas {limit:,}: use fewer template variables, or raise --max-formulas")


def _first_variables(formula) -> dict[str, str]:
    """Every variable in a first-argument position (a `+var` or not) -> its predicate."""
    return {a.args[0].name: a.predicate for a in atoms(formula)
            if a.predicate != NEXT and a.args and isinstance(a.args[0], Var)}


def learn(predicates: pl.DataFrame, n_classes: int, mln: MLN, engine: str = "native", objective: str | None = None,
          l2: float | None = None, where: str = artifacts.FORMULAS, class_names: Sequence[str] | None = None,
          max_formulas: int = MAX_FORMULAS, near: dict[str, float] | None = None) -> Learned:
    """Expand and learn the weights of ``mln`` on the training split of ``predicates`` (pure); ``where`` names
    the formulas in messages; ``class_names`` (label order) name the classes in the weights table, learned.mln
    and messages (None: the paper's C<k>). ``near``: weights by formula (as the table writes it) near the optimum,
    the CLL learner's start (a fold's learner starts from the whole split's: the same optimum, in a few steps)."""
    options = LearnWeightsOptions(engine=engine, objective=objective, l2=l2)
    options.validate()
    training = training_data(predicates, n_classes, class_names)
    warnings = list(training.warnings)
    check_expansion(mln, training.space, max_formulas, where)
    expanded, left_out, expand_warnings = expand_templates(mln.formulas, training.space, class_names)
    warnings += expand_warnings
    uses_next = [item for item in mln.formulas if is_temporal(item.formula)]
    objective, l2 = resolve_objective(options, bool(uses_next))
    if uses_next and training.starts.all():
        raise BadInput(f"{where}:{uses_next[0].line}: {show(uses_next[0].formula, class_names)} uses {NEXT}, but every "
                       "episode of the training split has one frame: no transitions can be learned; collect longer "
                       f"episodes or remove the formulas with {NEXT}")
    check_hard(expanded, mln, training, where, class_names)
    if not expanded:
        weights = np.zeros(0)
    elif engine == "pracmln":
        weights = pracmln_weights(mln, expanded, training, l2)
    elif objective == "pll":
        weights = bpll.learn(expanded, training.rows, training.space, training.starts, l2=l2)
    else:
        states = AtomSpace(training.space.words, tuple(class_constant(k) for k in range(n_classes)))
        initial = None if near is None else np.array([near.get(show(e.formula, class_names), 0.0) for e in expanded])
        weights = cll.learn(expanded, training.evidence, training.labels, training.starts, states, l2=l2,
                            initial=initial)
    every = expanded + left_out
    values = np.concatenate([weights, np.zeros(len(left_out))])
    table = pl.DataFrame(
        {
            "formula": [show(e.formula, class_names) for e in every],
            "class": [head_class(e, class_names) for e in every],
            "weight": values,
            "fixed": [e.fixed for e in every],
            "hard": [e.weight is None for e in every],
            "template": [e.template for e in every],
            "temporal": [is_temporal(e.formula) for e in every],
        },
        schema=artifacts.WEIGHTS_SCHEMA,
    )
    from mlnseq.mln.weights_table import body_comments

    comments = body_comments(every, training.rows, training.starts, training.space, class_names or [])
    return Learned(table, render_learned(mln, every, values, engine, objective, l2, class_names, comments), warnings,
                   objective, l2)


def render_learned(mln: MLN, formulas: list[Expanded], weights: np.ndarray, engine: str, objective: str,
                   l2: float, class_names: Sequence[str] | None = None, comments: Sequence[str] = ()) -> str:
    """learned.mln: the expanded formulas with their weights, each body under a comment of its support (``comments``,
    one per formula, '' where the body is the formula before's). Read back by `formulas --spec`, each weight as
    written is kept (a written weight is an expert's); 0.0 is learned again."""
    temporal = any(is_temporal(e.formula) for e in formulas)
    lines = [f"// mlnseq learn-weights ({engine} {objective.upper()}, l2 {l2:g}): weighted, expanded formulas; read "
             "back (`mlnseq formulas --spec THIS_FILE`), each", "// weight is kept as written (0.0: learned again). "
             "Above each body: the training frames it holds in, by class.", ""]
    lines += [f"{name}({', '.join(domains)})" for name, domains in mln.predicates.items() if name != NEXT or temporal]
    for e, w, comment in zip(formulas, weights, list(comments) or [""] * len(formulas)):
        lines += ["", comment] if comment else []
        lines.append(format_weighted(WeightedFormula(shown(e.formula, class_names),
                                                     None if e.weight is None else float(w))))
    return "\n".join(lines) + "\n"


def with_episode_names(predicates: pl.DataFrame, workdir: Path) -> pl.DataFrame:
    """``predicates`` with each episode named as frames.parquet's recordings name it (a bag's folder, a file),
    where the workdir's frames record the names; else as it is."""
    path = Path(workdir) / artifacts.FRAMES
    names = artifacts.read_metadata(path, "frames").get("episode_names") if path.exists() else None
    index = predicates["episode"]
    if not names or index.min() < 0 or index.max() >= len(names) or len(set(map(str, names))) != len(names):
        return predicates
    return predicates.with_columns(pl.Series("episode", [str(n) for n in names]).gather(index))


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
    from mlnseq.mln import source_lines

    mln, where = source_lines.to_source(mln, formulas_path.read_text(encoding="utf-8"), formulas_path)  # user's lines
    folds = None
    if options.folds:
        from mlnseq.choosing import folds as folding

        folds = folding.assign(predicates["episode"].to_numpy(), predicates["split"].to_numpy(),
                               predicates["label"].to_numpy(), options.folds)
    named = with_episode_names(predicates, workdir)  # messages name episodes as the recordings do
    learned = learn(named, len(classes), mln, options.engine, options.objective, options.l2, where, list(classes),
                    options.max_formulas)
    learned.warnings[:] = source_lines.located(learned.warnings, where)
    record = {k: str(v) for k, v in asdict(options).items()}
    table_meta = {"options": record, "engine": options.engine, "objective": learned.objective, "l2": learned.l2,
                  "classes": classes, "source": meta.get("source"), "warnings": learned.warnings}
    per_fold = []
    near = dict(learned.weights.filter(~pl.col("hard")).select("formula", "weight").iter_rows())
    if folds is not None:
        from mlnseq.choosing.folds import fold_predicates

        tables, read = fold_predicates(workdir, folds, named, meta)
        for k in range(folds.k):
            held_out = tables[k].with_columns(pl.Series("episode", named["episode"]),
                                              pl.Series("split", folds.splits(k)))
            fold = learn(held_out, len(classes), mln, options.engine, options.objective, options.l2, where,
                         list(classes), options.max_formulas, near)
            fold.warnings[:] = source_lines.located(fold.warnings, where)
            per_fold.append(fold.weights.with_columns(pl.lit(k, dtype=pl.Int32).alias("fold")))
            learned.warnings.extend(f"fold {k}: {w}" for w in fold.warnings if w not in learned.warnings)
    with artifacts.atomic_path(workdir / artifacts.LEARNED_MLN) as staged:  # all or none
        staged.write_text(learned.learned_mln, encoding="utf-8")
        path = artifacts.write_table(learned.weights, workdir / artifacts.WEIGHTS, "weights", table_meta,
                                     inputs=[predicates_path, formulas_path])
        if folds is None:  # an earlier run's fold weights (other frames or formulas) are no longer these weights'
            (workdir / artifacts.FOLD_WEIGHTS).unlink(missing_ok=True)
        else:
            artifacts.write_table(pl.concat(per_fold), workdir / artifacts.FOLD_WEIGHTS, "fold_weights",
                                  {**table_meta, "folds": folds.record(), "fold_predicates": bool(read),
                                   "training_episodes": int(
                                      predicates.filter(pl.col("split") == "train")["episode"].n_unique())},
                                  inputs=[predicates_path, formulas_path, path, *read])
    return path, learned
