"""formulas: write the domain knowledge as a pracmln .mln file, ``formulas.mln``.

The file keeps `+var` templates as written (pracmln-style); `learn-weights` expands them against
the training split. Every predicate and constant is checked against predicates.parquet here, so a
typo fails now with its line and column rather than at learning.
"""

from __future__ import annotations

import importlib.resources
from dataclasses import dataclass, replace
from pathlib import Path

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.mln.formula_spec import formulas_for, read_spec
from mlnseq.mln import source_lines
from mlnseq.mln.grounding import shown
from mlnseq.mln.syntax import MLN, format_weighted

DEFAULT_SPEC = Path(importlib.resources.files("mlnseq") / "specs" / "paper.mln")  # shipped in the package


@dataclass(frozen=True)
class FormulasOptions:
    spec: Path | None = None  # .mln of hand-written formulas and templates; default the built-in paper.mln

    @property
    def spec_path(self) -> Path:
        return DEFAULT_SPEC if self.spec is None else Path(self.spec)

    def validate(self) -> None:
        if not self.spec_path.is_file():
            raise BadInput(f"--spec {self.spec_path} not found: give a .mln file of formulas")


@dataclass(frozen=True)
class WrittenFormulas:
    path: Path
    mln: MLN
    words: tuple[str, ...]  # predicate columns true somewhere in the training split
    classes: tuple[str, ...]  # the classes the training split shows, as the frames name them


def render(mln: MLN, spec: Path, words: tuple[str, ...], classes: tuple[str, ...], class_names: list[str]) -> str:
    """formulas.mln: provenance, the training constants as comments, declarations, formulas (classes as the
    frames name them)."""
    order = ([f"// label order (the paper's C0 .. C{len(class_names) - 1}): {', '.join(class_names)}"]
             if class_names else [])
    lines = [
        f"// mlnseq formulas from {spec.name}: templates are expanded by `mlnseq learn-weights`",
        f"// word = {{{', '.join(words)}}}",
        f"// class = {{{', '.join(classes)}}}",
        *order,
        "",
        *(f"{name}({', '.join(domains)})" for name, domains in mln.predicates.items()),
        "",
        *(line for item in mln.formulas for line in (  # each formula under the mark of its line in the spec
            source_lines.mark(spec, item.line),
            format_weighted(replace(item, formula=shown(item.formula, class_names))))),
    ]
    return "\n".join(lines) + "\n"


def run(workdir: Path, options: FormulasOptions) -> WrittenFormulas:
    """Read predicates.parquet and the spec; write ``workdir/formulas.mln``."""
    options.validate()
    predicates, meta = artifacts.read_table(Path(workdir) / artifacts.PREDICATES, "predicates")
    columns = artifacts.feature_columns(predicates)
    classes = meta.get("classes") or []
    mln = read_spec(options.spec_path)
    formulas_for(mln, options.spec_path, columns, list(classes))
    train = predicates.filter(predicates["split"] == "train")
    seen = train.select(columns).sum().row(0) if train.height else [0] * len(columns)
    words = tuple(c for c, n in zip(columns, seen) if n)
    labels = set(train["label"].to_list())
    present = tuple(name for k, name in enumerate(classes) if k in labels)
    path = artifacts.write_text(Path(workdir) / artifacts.FORMULAS,
                                render(mln, options.spec_path, words, present, list(classes)))
    return WrittenFormulas(path, mln, words, present)
