"""The full command that remakes an artifact, from the options its metadata records: what a "rerun" message says,
so that following it works (`mlnseq learn-weights --folds 4`, not a bare command that loses
the folds the next stage asks for)."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

# per stage: (option as recorded, flag, its default as recorded): flags written only where they differ
FLAGS: dict[str, list[tuple[str, str, Any]]] = {
    "learn-weights": [("engine", "--engine", "native"), ("objective", "--objective", "None"), ("l2", "--l2", "None"),
                      ("folds", "--folds", "0")],
    "binarize": [("spec", "--spec", None)],
    "train": [("method", "--method", "always"), ("mode", "--mode", "segment"), ("cell", "--cell", "lstm"),
              ("epochs", "--epochs", 100), ("seed", "--seed", 0), ("select", "--select", "none"),
              ("folds", "--folds", None)],
}


def command(stage: str, options: dict[str, Any] | None, workdir: Path | None = None) -> str:
    """``mlnseq STAGE [the recorded options that differ from the defaults] [-w WORKDIR]``."""
    options = dict(options or {})
    if stage == "binarize" and options.get("suggest") and not options.get("spec"):
        options["spec"] = options["suggest"]  # the suggested spec as written then, edits kept
    words = ["mlnseq", *stage.split()]
    formulas = options.get("formulas") if stage == "learn-weights" else None
    if formulas and Path(formulas).name != "formulas.mln":
        words.append(str(formulas))
    for key, flag, default in FLAGS.get(stage.split()[0], []):
        if key in options and options[key] != default and str(options[key]) != str(default):
            words += [flag, str(options[key])]
    if workdir is not None:
        words += ["-w", str(workdir)]
    return " ".join(shlex.quote(w) for w in words)
