"""Every workaround pracmln 1.2.4 needs, in one place, and the pracmln learning engine.

pracmln's package ``__init__`` imports its Tk GUI: on Python 3.11 ``from tkinter.filedialog
import StringVar`` fails (the name moved to ``tkinter``), and a Python without Tk cannot import
it at all. We alias the name, or install stub tkinter modules, before the import. pracmln also
prints progress on stdout; a learning run is silenced.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import sys
import types
import warnings
from typing import Any

from mlnseq.catalog.errors import BadInput, MlnseqError

TK_MODULES = ("tkinter", "tkinter.filedialog", "tkinter.messagebox", "tkinter.simpledialog",
              "tkinter.constants", "tkinter.ttk", "tkinter.font", "tkinter.scrolledtext")


def _stub_module(name: str) -> types.ModuleType:
    module = types.ModuleType(name)

    def attribute(attr: str) -> Any:
        if attr.startswith("__"):
            raise AttributeError(attr)
        stub = type(attr, (), {"__init__": lambda self, *a, **k: None})
        setattr(module, attr, stub)
        return stub

    module.__getattr__ = attribute  # type: ignore[method-assign]
    return module


def install_tk_workaround() -> None:
    """Make ``import pracmln`` work: alias StringVar, or stub tkinter where Tk is missing."""
    try:
        import tkinter
        import tkinter.filedialog
    except ImportError:
        for name in TK_MODULES:
            sys.modules[name] = _stub_module(name)
        for name in TK_MODULES[1:]:
            setattr(sys.modules["tkinter"], name.split(".")[1], sys.modules[name])
        return
    if not hasattr(tkinter.filedialog, "StringVar"):
        tkinter.filedialog.StringVar = tkinter.StringVar  # type: ignore[attr-defined]


def import_pracmln() -> types.ModuleType:
    """The pracmln package, or a clear error naming the installer."""
    install_tk_workaround()
    try:
        with contextlib.redirect_stdout(_sink()), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return importlib.import_module("pracmln")
    except ImportError as error:
        raise BadInput(
            f"--engine pracmln needs pracmln 1.2.4 ({error}); install it with scripts/install_pracmln.sh .venv"
        ) from error


def learn_weights(mln_text: str, db_text: str, fixed: list[bool], evidence: tuple[str, ...] = (),
                  l2: float = 0.0) -> list[tuple[str, float]]:
    """Run pracmln's pseudo-likelihood learner on one database; (formula text as pracmln writes it, weight) per formula.

    ``fixed`` flags the formulas of ``mln_text`` (in order) whose weight is held constant;
    pracmln expands `+var` templates itself, an expanded formula inherits its template's flag.
    With no ``evidence`` predicates: BPLL_CG, every ground atom scored given the others (the paper's
    learner). With some (Next): DBPLL_CG with those as evidence, whose atoms are conditioned on but
    not scored. ``l2`` > 0 adds pracmln's Gaussian prior of standard deviation 1/sqrt(l2).
    """
    import_pracmln()
    from pracmln.mln.base import parse_mln
    from pracmln.mln.database import parse_db
    from pracmln.mln.learning.bpll import BPLL_CG, DBPLL_CG

    params = {"multicore": False, "verbose": False}
    if evidence:
        params["epreds"] = list(evidence)
    if l2 > 0:
        params["prior_stdev"] = 1.0 / l2 ** 0.5
    sink = _sink()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mln = parse_mln(mln_text, grammar="StandardGrammar", logic="FirstOrderLogic")
            mln.fixweights = list(fixed)
            databases = parse_db(mln, db_text)
            learned = mln.learn(databases, method=DBPLL_CG if evidence else BPLL_CG, **params)
    except Exception as error:  # pracmln raises bare Exceptions with its own messages
        raise MlnseqError(f"pracmln failed: {type(error).__name__}: {error}") from error
    return [(str(formula), float(weight)) for formula, weight in zip(learned.formulas, learned.weights)]


def _sink() -> io.TextIOWrapper:
    """A throwaway stdout; it has ``.buffer`` because pracmln binds ``sys.stdout.buffer`` at import."""
    return io.TextIOWrapper(io.BytesIO(), encoding="utf-8")
