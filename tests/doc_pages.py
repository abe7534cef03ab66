"""The docs test's machinery: README.md and docs/*.md parsed with Sybil, each page's shell blocks run as
written, in order, in a fresh folder of its own, and what the pages quote from a run compared with what the
run printed (docs/testing.md says how to mark a page).

The markers are HTML comments (invisible on the rendered page), each alone on the line before a fenced block:

- ``<!-- skip: next -- REASON -->``: the next block is not run here, for REASON (``skip: start -- REASON`` ...
  ``skip: end`` for several); a skip without a reason is an error;
- ``<!-- file: NAME -->``: the next block is saved as NAME in the page's folder (a script the page runs);
- ``<!-- exit: N -->``: the next shell block ends with exit status N (a refusal shown on purpose);
- ``<!-- output -->``: the next block is what the shell block before it prints: each of its lines is found, in
  order, among the printed lines (``...`` stands for any text), with the same numbers;
- ``<!-- continues: PAGE -->`` (anywhere in a page): the page runs in a copy of PAGE's folder after PAGE ran;

and, inside prose or a table, right after a number: ``<!-- figure: [PAGE:] PATTERN [~ TOLERANCE] -->``: the
number is what PATTERN's ``{}`` matches in the first printed line of the page (or PAGE) that PATTERN matches.
TOLERANCE is absolute (``~ 0.5``) or a factor (``~ 4x``); without it the numbers must be equal, as seeded runs
repeat exactly. No figure is a time: how long a run takes is a benchmark's figure (docs/benchmarks.md).

With MLNSEQ_DOCS_FIGURES=write (``make docs-figures``) every quoted number is rewritten from the run instead.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from unittest import SkipTest

from sybil import Document, Region
from sybil.evaluators.skip import Skipper
from sybil.parsers.markdown.lexers import DirectiveInHTMLCommentLexer, FencedCodeBlockLexer

REPO = Path(__file__).resolve().parents[1]
SHELLS = ("bash", "sh", "shell")
LINKED = (".venv", "Makefile", "pyproject.toml", "README.md", "benchmarks", "docs", "mlnseq_cli", "scripts", "stages",
          "tests")  # a page folder links these from the checkout; examples/ is copied (a sweep writes into it)
COPIED = ("examples",)
WRITE = os.environ.get("MLNSEQ_DOCS_FIGURES") == "write"
BLOCK_TIMEOUT = 600
NUMBER = r"-?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?"
FIGURE = re.compile(r"<!--\s*figure:\s*(?:(?P<page>[\w./-]+\.md):\s*)?(?P<pattern>.*?)"
                    r"(?:\s+~\s*(?P<tolerance>[\d.]+x?))?\s*-->")


def pages() -> list[Path]:
    """README.md, then every page of docs/ by name: a new page is picked up as it is added."""
    return [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]


def page_name(path: Path) -> str:
    """A page by its path from the checkout's root (a page elsewhere, as the runner's own tests write: its name)."""
    return path.relative_to(REPO).as_posix() if path.is_relative_to(REPO) else path.name


@dataclass(frozen=True)
class Block:
    """A fenced block: its language (maybe empty) and text."""

    language: str
    text: str


@dataclass(frozen=True)
class Directive:
    """A marker line ``<!-- NAME: ARGUMENT -->`` (file, exit, output, continues)."""

    name: str
    argument: str


@dataclass(frozen=True)
class Step:
    """One check of a page: a shell block run, an output block compared, or a figure in prose compared."""

    page: str
    kind: str  # "block", "output" or "figure"
    line: int
    index: int  # blocks: the example's position in the page; figures: the marker's position in the text

    def __str__(self) -> str:
        return f"{self.page}:{self.line}:{self.kind}"


# --- parsing: Sybil's Markdown lexers; a region per fenced block and per marker ----------------------------

class ReasonedSkipParser:
    """Sybil's skip directive in this project's form, ``skip: next -- REASON``, skipped by Sybil's own Skipper
    (which evaluates a reason as Python: the parser hands it over as a string literal)."""

    def __init__(self) -> None:
        self.lexer = DirectiveInHTMLCommentLexer("skip")
        self.skipper = Skipper("skip")

    def __call__(self, document: Document):
        for lexed in self.lexer(document):
            action, _, reason = (lexed.lexemes["arguments"] or "").partition("--")
            action, reason = action.strip(), reason.strip()
            if action in ("next", "start") and not reason:
                raise ValueError(f"{document.path}: '<!-- skip: {action} -->' must say why: "
                                 f"'<!-- skip: {action} -- REASON -->'")
            yield Region(lexed.start, lexed.end, (action, repr(reason) if reason else None), self.skipper)


def directives(document: Document):
    for name in ("file", "exit", "output", "continues"):
        for lexed in DirectiveInHTMLCommentLexer(name, arguments=".*?")(document):
            yield Region(lexed.start, lexed.end, Directive(name, (lexed.lexemes["arguments"] or "").strip()),
                         evaluate_directive)


def fenced_blocks(document: Document):
    for lexed in FencedCodeBlockLexer(r"[\w+-]*")(document):
        yield Region(lexed.start, lexed.end, Block(lexed.lexemes["language"], str(lexed.lexemes["source"])),
                     evaluate_block)


def parse(path: Path) -> Document:
    document = Document.parse(str(path), ReasonedSkipParser(), directives, fenced_blocks)
    document.namespace["page"] = page_name(path)
    return document


def builds_on(document: Document) -> str | None:
    """The page this one continues (``<!-- continues: PAGE -->``, PAGE relative to this page), or None."""
    for _, region in document.regions:
        if isinstance(region.parsed, Directive) and region.parsed.name == "continues":
            return page_name((Path(document.path).parent / region.parsed.argument).resolve(strict=False))
    return None


def steps(document: Document) -> list[Step]:
    """The page's checks in page order: its shell and output blocks, then the figures of its prose."""
    page = document.namespace["page"]
    found, before = [], None
    for index, example in enumerate(document.examples()):
        parsed = example.region.parsed
        if isinstance(parsed, Block):
            if before == "output":
                found.append(Step(page, "output", example.line, index))
            elif parsed.language in SHELLS and before != "file":
                found.append(Step(page, "block", example.line, index))
        before = parsed.name if isinstance(parsed, Directive) else None
    for match in FIGURE.finditer(document.text):
        line_start = document.text.rfind("\n", 0, match.start()) + 1
        if document.text[line_start:match.start()].count("`") % 2 == 0:  # not a marker shown in inline code
            found.append(Step(page, "figure", document.text.count("\n", 0, match.start()) + 1, match.start()))
    return found


# --- evaluating: a page's shell blocks in its folder, what they printed kept for the checks -----------------

def evaluate_directive(example) -> None:
    example.namespace["pending"] = example.region.parsed


def evaluate_block(example) -> None:
    pending = example.namespace.pop("pending", None)
    block: Block = example.region.parsed
    run: PageRun = example.namespace["run"]
    if pending is not None and pending.name == "file":
        (run.folder / pending.argument).write_text(block.text, encoding="utf-8")
    elif pending is not None and pending.name == "output":
        return run.check_output(example.line, example.region.start, block.text)
    elif block.language in SHELLS:
        run.run_block(example.line, block.text, int(pending.argument) if pending and pending.name == "exit" else 0)
    return None


@dataclass
class Printed:
    line: int  # the block's line in its page
    text: str  # its stdout and stderr as they came


@dataclass
class PageRun:
    """A page's folder and what its shell blocks printed."""

    page: str
    path: Path  # the page's file
    folder: Path
    env: dict[str, str]
    printed: list[Printed] = field(default_factory=list)

    def run_block(self, line: int, source: str, expected: int) -> None:
        trap = "set -eo pipefail\ntrap 'echo \"docs test: this command failed: $BASH_COMMAND\" >&2' ERR\n"
        script = (trap if expected == 0 else "set -o pipefail\n") + source
        done = subprocess.run(["bash", "-c", script], cwd=self.folder, env=self.env, stdin=subprocess.DEVNULL,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=BLOCK_TIMEOUT)
        self.printed.append(Printed(line, done.stdout))
        if done.returncode != expected:
            tail = "\n".join(done.stdout.splitlines()[-30:])
            raise AssertionError(f"{self.page}:{line}: the block ended with exit status {done.returncode}, "
                                 f"not {expected} (in {self.folder}):\n{tail}")

    def check_output(self, line: int, start: int, shown: str) -> str | None:
        """The shown lines against what the last shell block printed: None when each is there, in order."""
        if not self.printed:
            return f"{self.page}:{line}: an output block with no shell block before it"
        printed, at, rewritten = self.printed[-1].text.splitlines(), 0, []
        for wanted in shown.splitlines():
            pattern = line_pattern(wanted)
            match = next((m for k in range(at, len(printed)) if (m := pattern.search(printed[k]))), None)
            if match is None:
                return (f"{self.page}:{line}: this shown line is not printed (in order):\n  {wanted}\nprinted:\n"
                        + "\n".join(f"  {p}" for p in printed[-30:]))
            at = printed.index(match.string, at) + 1
            numbers = [n for n in match.groups()]
            rewritten.append(re.sub(NUMBER, lambda _: numbers.pop(0), wanted))
        if WRITE:
            WRITTEN.append((self.path, start, shown, "\n".join(rewritten) + "\n"))
        return None

    def figure(self, pattern: str) -> str | None:
        """The number PATTERN's ``{}`` stands for in the first printed line it matches."""
        head, _, tail = pattern.partition("{}")
        regex = re.compile(line_pattern(head, capture=False).pattern + f"({NUMBER})"
                           + line_pattern(tail, capture=False).pattern)
        for printed in self.printed:
            for text in printed.text.splitlines():
                if (match := regex.search(text)) is not None:
                    return match.group(1)
        return None


def line_pattern(shown: str, capture: bool = True) -> re.Pattern:
    """A shown line as a pattern: ``...`` any text, each number itself (any number when writing figures)."""
    parts = []
    for piece in re.split(r"(\.\.\.|" + NUMBER + ")", shown.strip() if capture else shown):
        if piece == "...":
            parts.append(".*?")
        elif piece and re.fullmatch(NUMBER, piece) and capture:
            parts.append(f"({NUMBER if WRITE else re.escape(piece)})")
        else:
            parts.append(re.escape(piece))
    return re.compile("".join(parts))


WRITTEN: list[tuple[Path, int, str, str]] = []  # (page, where, old text, new text): written at the session's end


def within(quoted: str, measured: str, tolerance: str | None) -> bool:
    a, b = (float(x.replace(",", "")) for x in (quoted, measured))
    if tolerance is None:
        return a == b
    if tolerance.endswith("x"):
        return b / float(tolerance[:-1]) <= a <= b * float(tolerance[:-1])
    return abs(a - b) <= float(tolerance)


def quoted_before(text: str, end: int) -> re.Match | None:
    """The number a figure's marker follows (perhaps after a unit: ' %', ' s')."""
    return re.search(f"({NUMBER})(?:\\s?(?:%|s|x|KB|MB))?$", text[:end])


def figure_check(path: Path, text: str, at: int, page: str, measured_in) -> str | None:
    """The figure whose marker starts at ``at`` of the page ``text``: None when its number is the run's.
    ``measured_in(PAGE)`` gives the PageRun of a page, run to its end."""
    marker = FIGURE.match(text, at)
    quoted = quoted_before(text, at)
    line = text.count("\n", 0, at) + 1
    if quoted is None:
        return f"{page}:{line}: no number right before the figure marker {marker.group(0)}"
    source = page_name((path.parent / marker.group("page")).resolve()) if marker.group("page") else page
    measured = measured_in(source).figure(marker.group("pattern"))
    if measured is None:
        return f"{page}:{line}: {source}'s run printed no line matching {marker.group('pattern')!r}"
    if WRITE:
        WRITTEN.append((path, quoted.start(1), quoted.group(1), measured))
        return None
    if not within(quoted.group(1), measured, marker.group("tolerance")):
        tolerance = f" within {marker.group('tolerance')}" if marker.group("tolerance") else ""
        return f"{page}:{line}: the page quotes {quoted.group(1)}, the run printed {measured} (not equal{tolerance})"
    return None


def write_figures() -> list[str]:
    """MLNSEQ_DOCS_FIGURES=write: the numbers measured written into the pages; returns the pages changed."""
    changed = []
    for path in sorted({w[0] for w in WRITTEN}):
        text = original = path.read_text(encoding="utf-8")
        for _, start, old, new in sorted((w for w in WRITTEN if w[0] == path), key=lambda w: -w[1]):
            at = text.index(old, start)
            text = text[:at] + new + text[at + len(old):]
        if text != original:
            path.write_text(text, encoding="utf-8")
            changed.append(page_name(path))
    WRITTEN.clear()
    return changed


def environment() -> dict[str, str]:
    """A user's shell after the README's set-up: .venv's commands first on PATH; no terminal width, no --verbose,
    no make of ours around it."""
    dropped = ("COLUMNS", "LINES", "MLNSEQ_VERBOSE", "MAKEFLAGS", "MAKELEVEL", "MFLAGS", "VIRTUAL_ENV")
    env = {k: v for k, v in os.environ.items() if k not in dropped}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


def new_folder(root: Path, page: str, after: Path | None = None) -> Path:
    """A fresh folder laid out as the checkout (links to it, a copy of examples/) with ../shared beside it, or a
    copy of ``after``, the folder of the page this one continues."""
    if not (root / "shared").exists():
        (root / "shared").symlink_to(REPO.parent / "shared")
    folder = root / page.replace("/", "_").removesuffix(".md")
    if after is not None:
        shutil.copytree(after, folder, symlinks=True)
        return folder
    folder.mkdir()
    for name in LINKED:
        if (REPO / name).exists():
            (folder / name).symlink_to(REPO / name)
    for name in COPIED:
        shutil.copytree(REPO / name, folder / name, ignore=left_behind)
    return folder


def left_behind(folder: str, names: list[str]) -> set[str]:
    """What a copy of examples/ leaves out: what a run there wrote (a sweep's OUT, a workdir, a model)."""
    made = {"__pycache__", "mlnseq-work"} | ({"sweep"} if Path(folder).name == "sweep" else set())
    return {name for name in names if name in made or name.endswith(".mlnseq")}


class Runs:
    """Every page's run in this session, each done once, lazily and in page order: a check of block k runs the
    page's blocks before it first (and the page it continues, to its end)."""

    def __init__(self, root: Path, paths: list[Path] | None = None) -> None:
        self.root = root
        self.documents = {page_name(path): parse(path) for path in paths or pages()}
        self.runs: dict[str, PageRun] = {}
        self.done: dict[str, dict[int, BaseException | None]] = {}  # page -> example index -> its outcome

    def run_to(self, page: str, last: int | None = None) -> PageRun:
        document = self.documents[page]
        if page not in self.runs:
            after = builds_on(document)
            folder = new_folder(self.root, page, self.run_to(after).folder if after else None)
            self.runs[page] = PageRun(page, Path(document.path), folder, environment())
            document.namespace["run"] = self.runs[page]
            self.done[page] = {}
        outcomes = self.done[page]
        for index, example in enumerate(document.examples()):
            if last is not None and index > last:
                break
            if index not in outcomes:
                outcomes[index] = self.evaluate(example, outcomes)
        return self.runs[page]

    @staticmethod
    def evaluate(example, outcomes) -> BaseException | None:
        failed = [o for o in outcomes.values() if o is not None and not isinstance(o, SkipTest)]
        if failed:
            return SkipTest(f"an earlier block of the page failed: {str(failed[0]).splitlines()[0]}")
        try:
            example.evaluate()
        except (SkipTest, Exception) as error:  # noqa: BLE001 - each outcome is reported by its own check
            return error
        return None

    def outcome(self, step: Step) -> BaseException | None:
        if step.kind == "figure":
            document = self.documents[step.page]
            problem = figure_check(Path(document.path), document.text, step.index, step.page, self.run_to)
            return AssertionError(problem) if problem else None
        self.run_to(step.page, step.index)
        return self.done[step.page][step.index]
