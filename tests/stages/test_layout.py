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


def test_only_the_command_line_and_the_packages_fit_and_sweep_import_the_pipeline():
    importers = {module for module, path in {**modules(), **modules(REPO / "mlnseq_cli", "mlnseq_cli")}.items()
                 if library_of(module) != COMPOSER
                 and any(library_of(name) == COMPOSER for name in imported_modules(ast.parse(path.read_text())))}
    assert importers == {"mlnseq", "mlnseq_cli.fit", "mlnseq_cli.sweep"}
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


def folder_imports() -> dict[str, set[str]]:
    folders = defaultdict(set)
    for module, targets in module_graph().items():
        for target in targets:
            source, dest = library_of(module), library_of(target)
            if source and dest and source != dest:
                folders[source].add(dest)
    return folders


def test_the_library_folders_import_one_way():
    assert cycle(folder_imports()) == []


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


# --- the tests' layout, as docs/layout.md says it ---------------------------------------------------------------

TESTS = REPO / "tests"
WHOLE_PRODUCT = ("bad_inputs", "benchmarks", "desk_bags", "determinism", "examples", "hostile", "interruption",
                 "properties", "reproduce", "stage_server", "wheel")  # the tests directly in tests/


def test_the_tests_mirror_the_library():
    """A test folder per library folder; directly in tests/stages/ only the stages' own tests (test_STAGE*.py) and
    this one; directly in tests/ only the whole product's."""
    untested = [folder for folder in LIBRARIES if folder != "specs"
                and not list((TESTS / "stages" / folder).glob("test_*.py"))]
    assert untested == []
    stray = [path.name for path in (TESTS / "stages").glob("test_*.py") if path.stem != "test_layout" and not any(
        path.stem == f"test_{stage}" or path.stem.startswith(f"test_{stage}_") for stage in STAGE_FILES)]
    assert stray == []
    assert [path.name for path in TESTS.glob("test_*.py") if not path.stem.removeprefix("test_").startswith(
        WHOLE_PRODUCT)] == []
    assert {path.name for path in TESTS.iterdir() if path.is_dir() and not path.name.startswith((".", "__"))} >= {
        "stages", "cli", "docs"}


# --- the plan kept true: docs/layout.md's floors and modules, the Makefile's stage sources ----------------------

LAYOUT_PAGE = REPO / "docs" / "layout.md"
MAKEFILE = REPO / "Makefile"


def documented_floors(page: str) -> dict[str, int]:
    """Each library folder's floor as the floors block of docs/layout.md draws it."""
    block = page.split("## The floors", 1)[1].split("```", 2)[1]
    floors = {}
    for line in block.splitlines():
        words = line.split()
        if words[:1] == ["floor"]:
            floors |= {word.rstrip("/"): int(words[1]) for word in words[2:] if word.endswith("/")}
    return floors



def imports_up(floors: dict[str, int], imports: dict[str, set[str]]) -> list[str]:
    return sorted(f"{source}/ (floor {floors[source]}) imports {dest}/ (floor {floors[dest]})"
                  for source, targets in imports.items() for dest in targets if floors[dest] >= floors[source])


def documented_imports(page: str) -> dict[str, set[str]]:
    """Each library folder's imports as the folders table of docs/layout.md lists them ("the stages": stage files)."""
    found = {}
    for line in page.splitlines():
        cells = [cell.strip() for cell in line.split("|")]
        if line.startswith("| `") and len(cells) == 5 and (folder := cells[1].strip("`").rstrip("/")) in LIBRARIES:
            found[folder] = {word.strip() for word in cells[3].split(",")} - {"—", ""}
    return found


def code_imports() -> dict[str, set[str]]:
    """Each library folder's imports as its code makes them: other folders, and "the stages" where it imports one."""
    found = {folder: set(targets) for folder, targets in folder_imports().items()}
    for module, targets in module_graph().items():
        if (folder := library_of(module)) and any(stage_of(target) for target in targets):
            found.setdefault(folder, set()).add("the stages")
    return {folder: found.get(folder, set()) for folder in LIBRARIES if folder != "specs"}


def test_the_imports_column_lists_what_each_folder_imports():
    assert documented_imports(LAYOUT_PAGE.read_text()) == code_imports()


def test_the_imports_rule_finds_a_folder_left_out():
    page = LAYOUT_PAGE.read_text().replace("| catalog, timeline, predicates, mln, fusion |", "| catalog, mln, fusion |")
    assert documented_imports(page)["explaining"] != code_imports()["explaining"]


def test_every_library_folder_stands_on_a_documented_floor():
    floors = documented_floors(LAYOUT_PAGE.read_text())
    assert set(LIBRARIES) - {"specs"} <= set(floors), set(LIBRARIES) - set(floors)


def test_no_import_runs_up_the_documented_floors():
    assert imports_up(documented_floors(LAYOUT_PAGE.read_text()), folder_imports()) == []


def test_the_floor_rule_finds_an_import_up_or_sideways():
    floors = {"catalog": 0, "mln": 1, "sources": 1}
    assert imports_up(floors, {"catalog": {"mln"}, "mln": {"sources", "catalog"}}) == [
        "catalog/ (floor 0) imports mln/ (floor 1)", "mln/ (floor 1) imports sources/ (floor 1)"]


def named_by_folder(page: str) -> dict[str, str]:
    """The text docs/layout.md gives each folder: its row of the folders table and the sections headed by it."""
    said: dict[str, str] = defaultdict(str)
    folder = ""
    for line in page.splitlines():
        if line.startswith("#"):
            heading = [word.strip("`:") for word in line.split() if word.strip("`:").startswith("stages/")]
            folder = heading[0].removeprefix("stages/").strip("/") if heading else ""
            continue
        cells = line.split("|")
        row_folder = cells[1].strip().strip("`").rstrip("/") if line.startswith("|") and len(cells) > 2 else ""
        said[row_folder if row_folder in LIBRARIES else folder] += line + "\n"
    return said


def unnamed_modules(page: str) -> list[str]:
    said = named_by_folder(page)
    missing = [path.name for path in STAGES.glob("*.py") if path.stem != "__init__" and f"`{path.name}`" not in said[""]]
    for folder in LIBRARIES:
        missing += [f"{folder}/{path.name}" for path in sorted((STAGES / folder).glob("*.py"))
                    if path.stem != "__init__" and path.name not in said[folder]]
    return missing


def test_docs_layout_names_every_module_in_its_folder():
    assert unnamed_modules(LAYOUT_PAGE.read_text()) == []


def test_the_naming_rule_finds_a_missing_module():
    page = LAYOUT_PAGE.read_text()
    assert unnamed_modules(page.replace("`fuse.py`", "`fused.py`")) == ["fusion/fuse.py"]


def makefile_sources(makefile: str) -> dict[str, tuple[set[str], set[str]]]:
    """Each ``X_SOURCES`` list of the Makefile: its own files and its library folders, variables expanded."""
    joined = makefile.replace("\\\n", " ")
    variables = {name.strip(): value.strip() for name, value in
                 (line.split(":=", 1) for line in joined.splitlines() if ":=" in line and not line.startswith("\t"))}
    lists = {}
    for name, value in variables.items():
        if name.endswith("_SOURCES") and "$(call libraries," in value:
            for variable, expansion in variables.items():
                value = value.replace(f"$({variable})", expansion)
            files, call = value.split("$(call libraries,", 1)
            lists[name] = (set(files.split()), set(call.split(")", 1)[0].split()))
    return lists


def imported_libraries(start: list[str]) -> set[str]:
    """The library folders ``start`` imports, directly or through other modules; the package's own __init__ (in
    every list) is not followed: it names the Python API's entry points lazily, for Python callers."""
    graph, seen, todo = module_graph(), set(), list(start)
    while todo:
        if (module := todo.pop()) not in seen:
            seen.add(module)
            todo += graph.get(module, ()) if module != "mlnseq" else ()
    return {folder for module in seen if (folder := library_of(module))}


def test_the_makefile_stage_sources_follow_the_imports():
    wrong = {}
    for name, (files, folders) in makefile_sources(MAKEFILE.read_text()).items():
        start = [f"mlnseq.{Path(f).stem}" if f.startswith("stages/") else f"mlnseq_cli.{Path(f).stem}" for f in files]
        if folders != (needed := imported_libraries(start)):
            wrong[name] = f"has {sorted(folders)}, its stage imports {sorted(needed)}"
    assert wrong == {}


def table_rows(page: str, heading: str) -> list[list[str]]:
    """The body rows of the first table under ``heading`` in ``page``, as cells."""
    section = page.split(heading, 1)[1]
    rows = [line for line in section.split("\n\n#", 1)[0].splitlines() if line.startswith("|")]
    return [[cell.strip() for cell in row.strip("|").split("|")] for row in rows[2:]]


def named(cell: str) -> list[str]:
    return [word.strip("`/ ") for word in cell.split(",") if word.strip("`/ ")]


def test_the_source_and_network_tables_are_the_registries():
    from mlnseq import networks, sources

    page = LAYOUT_PAGE.read_text()
    documented = {env: module for env, module, *_ in table_rows(page, "## The source table")}
    assert documented == {f"`{s.name}`": f"`{s.module.rsplit('.', 1)[1]}.py`" for s in sources.SOURCES}
    cells = {name: named(module)[0] for names, module, _ in table_rows(page, "## Networks") for name in named(names)}
    assert cells == {t.name: f"{t.module.rsplit('.', 1)[1]}.py" for t in networks.TYPES.values()}


def test_where_a_change_goes_names_every_library_folder():
    folders = {folder for _, goes in table_rows(LAYOUT_PAGE.read_text(), "## Where a change goes")
               for folder in named(goes.split(";")[0]) + named(goes.split(";")[1].split(":")[1] if ";" in goes else "")}
    assert folders == set(LIBRARIES) - {"specs"}


def test_each_command_is_a_small_face_over_the_library():
    """Every command's module of mlnseq_cli/ is under 110 lines (config.py, the project file's machinery as well as
    `mlnseq config`, apart); nothing but mlnseq and mlnseq_cli is installed at the top level."""
    import tomllib

    modules = {command.module for command in COMMANDS.values()} - {"config"}
    long = {m: n for m in modules if (n := len((REPO / "mlnseq_cli" / f"{m}.py").read_text().splitlines())) >= 110}
    assert long == {}
    assert set(tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]) == {
        "mlnseq", "mlnseq_cli"}


def test_the_wheel_packages_every_library_folder():
    import tomllib

    packages = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    assert {f"mlnseq.{folder}" for folder in LIBRARIES} - set(packages) == set()
