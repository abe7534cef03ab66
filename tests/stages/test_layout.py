"""The layout's rules, read from the source: the files directly under stages/ are the stages, one per
command, and its folders the libraries they share; no library imports a stage but pipeline/ (the one that composes
them, which only the command line and the package's ``mlnseq.fit`` import), the folders' imports run one way (no
circle between folders, none between modules), no module is over 400 lines, no function over 60 and no line over
120 characters."""

from __future__ import annotations

import ast
import importlib
from collections import defaultdict
from pathlib import Path

from mlnseq_cli.main import COMMANDS

REPO = Path(__file__).resolve().parents[2]
STAGES = REPO / "stages"  # installed as the package `mlnseq`
MAX_LINES = 400
MAX_FUNCTION_LINES = 60  # from its def (or first decorator) to its last line
MAX_LINE_CHARACTERS = 120


def imported_modules(tree: ast.AST, package: str = "mlnseq") -> set[str]:
    """Every module an import statement names, ``from mlnseq import x`` as ``mlnseq.x`` (lazy imports too)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return {name for name in names if name.split(".")[0] in (package, "mlnseq_cli")}


def modules(root: Path = STAGES, package: str = "mlnseq") -> dict[str, Path]:
    found = {}
    for path in sorted(root.rglob("*.py")):
        parts = (package, *path.relative_to(root).with_suffix("").parts)
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


STAGE_FILES = sorted(path.stem for path in STAGES.glob("*.py") if path.stem != "__init__")
LIBRARIES = sorted(path.name for path in STAGES.iterdir()
                   if path.is_dir() and (path / "__init__.py").is_file())


def stage_of(module: str) -> str | None:
    """The stage a dotted module name belongs to (``mlnseq.report`` -> report), or None for a library."""
    parts = module.split(".")
    return parts[1] if len(parts) == 2 and parts[0] == "mlnseq" and parts[1] in STAGE_FILES else None


def library_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "mlnseq" and parts[1] in LIBRARIES else None


def test_the_files_under_stages_are_the_commands():
    commands = {name.replace("-", "_") for name in COMMANDS}
    assert set(STAGE_FILES) <= commands, set(STAGE_FILES) - commands
    assert {"collect", "binarize", "formulas", "learn_weights", "train", "conflate", "eval", "export", "predict",
            "stream", "info", "report"} <= set(STAGE_FILES)
    for stage in STAGE_FILES:
        assert callable(getattr(importlib.import_module(f"mlnseq.{stage}"), "run", None)) or stage == "info", stage


COMPOSER = "pipeline"  # the one library that composes the stages (mlnseq.fit), like Kedro's runner


def test_no_library_imports_a_stage_and_no_stage_imports_another():
    crossings = []
    for module, path in modules().items():
        own = stage_of(module)
        for name in imported_modules(ast.parse(path.read_text())):
            other = stage_of(name)
            if other is not None and other != own and library_of(module) != COMPOSER:
                crossings.append(f"{path.relative_to(REPO)} imports {name}")
            if name.startswith("mlnseq_cli"):
                crossings.append(f"{path.relative_to(REPO)} imports the command line ({name})")
    assert not crossings, "\n".join(crossings)


def test_only_the_command_line_and_the_packages_fit_import_the_pipeline():
    importers = {module for module, path in {**modules(), **modules(REPO / "mlnseq_cli", "mlnseq_cli")}.items()
                 if library_of(module) != COMPOSER
                 and any(library_of(name) == COMPOSER for name in imported_modules(ast.parse(path.read_text())))}
    assert importers == {"mlnseq", "mlnseq_cli.fit"}
    assert COMPOSER in LIBRARIES


def cycle(graph: dict[str, set[str]]) -> list[str]:
    """One circle of ``graph`` as a path that comes back to its start, or []."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return stack[stack.index(nxt):] + [nxt]
            if nxt not in state and (found := visit(nxt)):
                return found
        stack.pop()
        state[node] = 2
        return []

    for node in sorted(graph):
        if node not in state and (found := visit(node)):
            return found
    return []


def module_graph() -> dict[str, set[str]]:
    known = {**modules(), **modules(REPO / "mlnseq_cli", "mlnseq_cli")}
    graph = defaultdict(set)
    for module, path in known.items():
        for name in imported_modules(ast.parse(path.read_text())):
            target = name if name in known else name.rsplit(".", 1)[0]
            if target in known and target != module and not module.startswith(target + "."):
                graph[module].add(target)
    return graph


def test_the_library_folders_import_one_way():
    folders = defaultdict(set)
    for module, targets in module_graph().items():
        for target in targets:
            source, dest = library_of(module), library_of(target)
            if source and dest and source != dest:
                folders[source].add(dest)
    assert cycle(folders) == []


def test_no_import_circle_between_modules():
    assert cycle(module_graph()) == []


def test_the_circle_finder_finds_one():
    assert cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert cycle({"a": {"b"}, "b": {"c"}}) == []


def test_no_module_under_stages_is_over_400_lines():
    long = {str(path.relative_to(REPO)): n for path in modules().values()
            if (n := len(path.read_text().splitlines())) > MAX_LINES}
    assert long == {}


def long_functions(source: str) -> dict[str, int]:
    """Each function (method, nested function) of ``source`` over MAX_FUNCTION_LINES lines, by its dotted name."""
    found = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            name = f"{prefix}{getattr(child, 'name', '')}"
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([child.lineno, *(d.lineno for d in child.decorator_list)])
                if (length := child.end_lineno - first + 1) > MAX_FUNCTION_LINES:
                    found[name] = length
            visit(child, f"{name}." if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                  else prefix)

    visit(ast.parse(source), "")
    return found


def test_no_function_under_stages_is_over_60_lines():
    long = {f"{path.relative_to(REPO)}:{name}": n for path in modules().values()
            for name, n in long_functions(path.read_text()).items()}
    assert long == {}


def test_no_line_under_stages_is_over_120_characters():
    long = [f"{path.relative_to(REPO)}:{number} ({len(line)})" for path in modules().values()
            for number, line in enumerate(path.read_text().splitlines(), start=1) if len(line) > MAX_LINE_CHARACTERS]
    assert long == []


def test_the_length_rules_measure_functions_whole():
    body = "\n".join(f"    x = {i}" for i in range(59))
    assert long_functions(f"def short():\n{body}\n") == {}  # 60 lines with its def
    method = "\n".join(f"        x = {i}" for i in range(59))
    assert long_functions(f"class A:\n    @staticmethod\n    def long():\n{method}\n        y = 1\n") == {"A.long": 62}


def test_the_import_rule_sees_each_form_of_import():
    tree = ast.parse("import mlnseq.train\nfrom mlnseq import formulas\nfrom mlnseq.report import run\n"
                     "def late():\n    from mlnseq.export import run\n")
    assert {stage_of(name) for name in imported_modules(tree)} >= {"train", "formulas", "report", "export"}
