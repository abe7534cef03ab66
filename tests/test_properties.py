"""Property-based tests of the two hand-written inputs: the .mln parser and the predicate spec loader.

Random text, structured documents and mutations of the real files in examples/ and stages/specs/ never end in an
unexpected exception: they parse, or they raise the one-line BadInput that names the file (and the
line where there is one). Binarizing with any spec that loads never crashes either. Through the CLI a
few broken files give exit 2 and a single stderr line, no traceback.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts
from mlnseq import binarize
from mlnseq.catalog.errors import BadInput
from mlnseq.mln.formula_spec import check_mln
from mlnseq.mln.syntax import format_weighted, parse_mln

REPO = Path(__file__).resolve().parents[1]
MLN_FILES = sorted([*REPO.glob("examples/**/*.mln"), *REPO.glob("stages/specs/*.mln")])
SPEC_FILES = sorted([*REPO.glob("examples/**/*.binarize.toml"), *REPO.glob("stages/specs/*.binarize.toml")])

# Derandomized so CI sees the same examples every run; no deadline (the 2-core CI box is slow).
FAST = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])

MLN_PATH = "rules.mln"
SPEC_PATH = Path("my.binarize.toml")


def assert_one_line(error: BadInput, prefix: str, with_line: bool = True) -> None:
    message = str(error)
    assert message and "\n" not in message and "\r" not in message, message
    assert message.startswith(prefix), message
    if with_line:
        assert re.match(rf"{re.escape(prefix)}:\d+", message), message


# ---- strategies ------------------------------------------------------------------------------------

MLN_ALPHABET = st.sampled_from(list("()!^v=>.<,{}+\"-0123456789 \tHasTopicpwcC_xy/#e\n"))
MLN_TOKENS = st.sampled_from([
    "Has", "Topic", "Foo", "(", ")", "+w", "+c", "w", "p", "q", '"gripper_open"', '"nope"', "C1", "C9", "=>",
    "<=>", "^", " v ", "!", ",", ".", "0.5 ", "-2 ", "1e3 ", "\n", "// note", " ", "word = {a, b}", "Has(word, page)",
    "Topic(class, page!)", '"', "#", "{", "}", "=",
])
MLN_TEXT = st.one_of(st.text(MLN_ALPHABET, max_size=80), st.lists(MLN_TOKENS, max_size=30).map("".join))


def mutate(text: str, data: st.DataObject) -> str:
    """Apply a few random edits: delete, insert, replace or duplicate a span; swap or drop a line."""
    for _ in range(data.draw(st.integers(1, 4), label="edits")):
        kind = data.draw(st.sampled_from(["delete", "insert", "replace", "duplicate", "swap", "drop"]))
        n = len(text)
        start = data.draw(st.integers(0, n), label="start")
        stop = data.draw(st.integers(start, min(n, start + 12)), label="stop")
        if kind == "delete":
            text = text[:start] + text[stop:]
        elif kind == "insert":
            text = text[:start] + data.draw(st.text(MLN_ALPHABET, max_size=6)) + text[start:]
        elif kind == "replace":
            text = text[:start] + data.draw(st.text(max_size=4)) + text[stop:]
        elif kind == "duplicate":
            text = text[:stop] + text[start:stop] + text[stop:]
        else:
            lines = text.split("\n")
            i = data.draw(st.integers(0, len(lines) - 1))
            j = data.draw(st.integers(0, len(lines) - 1))
            if kind == "swap":
                lines[i], lines[j] = lines[j], lines[i]
            else:
                del lines[i]
            text = "\n".join(lines)
    return text


# ---- the .mln parser -------------------------------------------------------------------------------


def check_mln_text(text: str) -> None:
    """Parse and, when it parses, check against a small database: a result or a one-line BadInput."""
    try:
        mln = parse_mln(text, MLN_PATH)
    except BadInput as error:
        assert_one_line(error, MLN_PATH)
        return
    for item in mln.formulas:  # what parses is written back (formulas.mln, learned.mln) and reads the same
        assert parse_mln(format_weighted(item), "written.mln").formulas[0].formula == item.formula
    try:
        check_mln(mln, MLN_PATH, {"gripper_open", "gripper_closed"}, {"C0", "C1"})
    except BadInput as error:
        assert_one_line(error, MLN_PATH, with_line=False)


@FAST
@given(text=MLN_TEXT)
@example(text="1.0 " + "(" * 600 + "Has(w, p)" + ")" * 600)
@example(text="2.0 " + "!" * 3000 + "Has(w, p)")
@example(text="1e999 Has(+w, p) => Topic(+c, p)")
@example(text='Has(w, p)\n0.5 Has("x", p) <=> !Topic(C1, p) v Has(w,p) ^ Topic(c, p)')
@example(text="word = {a, b\n#include other.mln\n")
def test_random_mln_text_parses_or_gives_one_line(text):
    check_mln_text(text)


@FAST
@given(text=st.text(max_size=60))
def test_arbitrary_unicode_mln_text_parses_or_gives_one_line(text):
    check_mln_text(text)


@pytest.mark.parametrize("path", MLN_FILES, ids=lambda p: p.name)
def test_the_example_mln_files_parse(path):
    assert parse_mln(path.read_text(), str(path)).formulas


@pytest.mark.parametrize("path", MLN_FILES, ids=lambda p: p.name)
@FAST
@given(data=st.data())
def test_mutated_example_mln_files_parse_or_give_one_line(path, data):
    check_mln_text(mutate(path.read_text(), data))


# ---- the predicate spec loader ------------------------------------------------------------------------

SPEC_KEYS = ["name", "kind", "channel", "edges", "values", "threshold", "open_above", "closed_below",
             "previous_scale", "of", "hint", "from", "to", "decimals", "bogus"]
WORDS = ["g", "arm", "left_gripper", "right_gripper", "arm_distance", "bins", "change", "gripper", "pair",
         "distance", "open", "closed", "x", "y", "z", "Bad Name", "", "episode", "label", "g_open"]
SCALARS = st.one_of(
    st.integers(-5, 200), st.floats(allow_nan=True, allow_infinity=True), st.booleans(), st.sampled_from(WORDS),
)
VALUES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=4), max_leaves=8)


def toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    return "[" + ", ".join(toml_value(v) for v in value) + "]"


def toml_document(sections: list[tuple[str, dict]]) -> str:
    lines = []
    for section, table in sections:
        lines.append(f"[[{section}]]")
        lines += [f"{key} = {toml_value(value)}" for key, value in table.items()]
        lines.append("")
    return "\n".join(lines)


TABLES = st.dictionaries(st.sampled_from(SPEC_KEYS), VALUES, max_size=7)
DOCUMENTS = st.lists(st.tuples(st.sampled_from(["predicate", "predicate", "channel", "other"]), TABLES), max_size=5)


@pytest.fixture(scope="module")
def tiny_frames() -> pl.DataFrame:
    """Three short episodes with the DESK motion columns and a few 3-D points."""
    rng = np.random.default_rng(0)
    n = 12
    keys = {"episode": np.repeat([0, 1, 2], 4), "frame": np.tile(np.arange(4), 3),
            "label": np.tile([0, 0, 1, 1], 3), "split": ["train"] * 8 + ["test"] * 4}
    names = ["arm_distance", "left_gripper", "right_gripper", "x", "y", "z", "g"]
    return artifacts.frames_table(keys, {name: rng.normal(size=n) * 50 for name in names})


def check_spec_text(text: str, frames: pl.DataFrame) -> None:
    """Load a spec's text, then binarize with it: results, or a one-line BadInput naming the spec file."""
    try:
        spec = binarize.parse_spec(text, SPEC_PATH)
    except BadInput as error:
        assert_one_line(error, str(SPEC_PATH))
        return
    try:
        predicates = binarize.binarize(frames, spec)
    except BadInput as error:
        assert_one_line(error, str(SPEC_PATH))
        return
    for columns in spec.columns().values():  # each predicate is one-hot on every frame
        assert predicates.select(pl.sum_horizontal(columns) == 1).to_series().all()


@FAST
@given(text=st.text(st.sampled_from(list('[]=" .,\n#abcdeiklnoprstv_0123456789-+{}')), max_size=120))
@example(text='[[predicate]]\nname = "g"\nkind = "bins"\nchannel = "g"\nedges = [1e400]\nvalues = ["a", "b"]\n')
@example(text="predicate = 3\n")
@example(text="[predicate]\nname = 1\n")
@example(text='[[predicate]]\n[[predicate]]\nname = "g"\n')
def test_random_spec_text_loads_or_gives_one_line(text, tiny_frames):
    check_spec_text(text, tiny_frames)


@FAST
@given(sections=DOCUMENTS)
def test_structured_specs_load_or_give_one_line(sections, tiny_frames):
    check_spec_text(toml_document(sections), tiny_frames)


@pytest.mark.parametrize("path", SPEC_FILES, ids=lambda p: p.name)
@FAST
@given(data=st.data())
def test_mutated_example_specs_load_or_give_one_line(path, data, tiny_frames):
    check_spec_text(mutate(path.read_text(), data), tiny_frames)


def test_a_spec_that_is_not_utf8_is_one_line(tmp_path):
    path = tmp_path / "latin1.binarize.toml"
    path.write_bytes('[[predicate]]\nname = "über"\n'.encode("latin-1"))
    with pytest.raises(BadInput) as caught:
        binarize.load_spec(path)
    assert_one_line(caught.value, f"cannot read spec {path}", with_line=False)


# ---- the same through the CLI ------------------------------------------------------------------------

runner = CliRunner()


@pytest.fixture
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


BROKEN_MLN = [
    ("typo.mln", "Has(word, page)\nTopic(class, page)\n0.0 Has(+w, p) => Topc(+c, p)\n", ":3"),
    ("unbalanced.mln", "0.0 (Has(+w, p) => Topic(+c, p)\n", ":1:"),
    ("noweight.mln", "// rules\nHas(+w, p) => Topic(+c, p)\n", ":2:"),
    ("deep.mln", "1.0 " + "(" * 2000 + "Has(w, p)" + ")" * 2000 + "\n", ":1:"),
    ("binary.mln", "\x00\xff garbage", ":1:"),
]
BROKEN_SPECS = [
    ("toml.binarize.toml", '[[predicate]]\nname = "g"\nkind = "bins\n', ":3"),
    ("kind.binarize.toml", '[[predicate]]\nname = "g"\nkind = "fuzzy"\n', ":3"),
    ("edges.binarize.toml", '[[predicate]]\nname = "g"\nkind = "bins"\nchannel = "arm_distance"\n'
                            'edges = [2, 1]\nvalues = ["a", "b", "c"]\n', ":5"),
    ("channel.binarize.toml", '\n[[predicate]]\nname = "g"\nkind = "change"\nchannel = "elbow"\nthreshold = 1\n', ":5"),
    ("empty.binarize.toml", "", ":1"),
]


def assert_refused_in_one_line(command: str, spec, where: str, workdir, output: str) -> None:
    """`mlnseq COMMAND --spec SPEC` exits 2 with one error line naming SPEC and WHERE, writing nothing."""
    result = runner.invoke(app, [command, "--spec", str(spec), "-w", str(workdir)])
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {spec}{where}"), result.stderr
    assert "Traceback" not in result.output
    assert not (workdir / output).exists()


@pytest.mark.parametrize("name,text,where", BROKEN_MLN, ids=[c[0] for c in BROKEN_MLN])
def test_formulas_cli_refuses_a_broken_mln_in_one_line(name, text, where, desk_mln_workdir, tmp_path, quiet_errors):
    spec = tmp_path / name
    spec.write_text(text, encoding="utf-8", errors="surrogateescape")
    workdir = tmp_path / "w"
    workdir.mkdir()
    (workdir / artifacts.PREDICATES).write_bytes((desk_mln_workdir / artifacts.PREDICATES).read_bytes())
    assert_refused_in_one_line("formulas", spec, where, workdir, artifacts.FORMULAS)


@pytest.mark.parametrize("name,text,where", BROKEN_SPECS, ids=[c[0] for c in BROKEN_SPECS])
def test_binarize_cli_refuses_a_broken_spec_in_one_line(name, text, where, desk_frames_workdir, tmp_path, quiet_errors):
    spec = tmp_path / name
    spec.write_text(text)
    workdir = tmp_path / "w"
    workdir.mkdir()
    (workdir / artifacts.FRAMES).write_bytes((desk_frames_workdir / artifacts.FRAMES).read_bytes())
    assert_refused_in_one_line("binarize", spec, where, workdir, artifacts.PREDICATES)
