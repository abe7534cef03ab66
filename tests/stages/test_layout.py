"""The layout's two rules, read from the source: no module under stages/ imports a stage module other than
itself (a shared piece lives in a module named for it), and none is over 400 lines."""

from __future__ import annotations

import ast
from pathlib import Path

STAGES = Path(__file__).resolve().parents[2] / "stages"
STAGE_NAMES = ("collect", "binarize", "formulas", "learn_weights", "train", "conflate", "eval", "export", "predict",
               "stream", "info", "report")
MAX_LINES = 400


def imported_modules(tree: ast.AST) -> set[str]:
    """Every module an import statement names, ``from stages import x`` as ``stages.x``."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return names


def stage_of(module: str) -> str | None:
    """The stage a dotted module name belongs to (``stages.report.tables`` -> report), or None."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "stages" and parts[1] in STAGE_NAMES else None


def modules() -> list[tuple[str, Path]]:
    found = []
    for path in sorted(STAGES.rglob("*.py")):
        parts = path.relative_to(STAGES.parent).with_suffix("").parts
        found.append((".".join(parts[:-1] if parts[-1] == "__init__" else parts), path))
    return found


def test_no_module_under_stages_imports_another_stage():
    crossings = []
    for module, path in modules():
        own = stage_of(module)
        for name in imported_modules(ast.parse(path.read_text())):
            other = stage_of(name)
            if other is not None and other != own:
                crossings.append(f"{path.relative_to(STAGES.parent)} imports {name}")
    assert not crossings, "\n".join(crossings)


def test_no_module_under_stages_is_over_400_lines():
    long = {str(path.relative_to(STAGES.parent)): n for _, path in modules()
            if (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert long == {}


def test_the_import_rule_sees_each_form_of_import():
    tree = ast.parse("import stages.train\nfrom stages import formulas\nfrom stages.report.tables import fmt\n"
                     "def late():\n    from stages.export import run\n")
    assert {stage_of(name) for name in imported_modules(tree)} >= {"train", "formulas", "report", "export"}
