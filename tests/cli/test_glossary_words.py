"""docs/glossary.md has the words the commands print (issue 55): the commands run on the docs' DESK examples
(explain with a decoded model, predict --explain, binarize --suggest and the spec it writes, export, eval, and
sequential-logic.md's steps: learn-weights and train with folds, conflate --decode all, export --method auto), their
output collected, and every word of mlnseq's vocabulary found there, every acronym and every hyphenated term of it,
found among the glossary's entries. The live commands' words (ticks, DDS, QoS, exit 143) are read from the
messages their source prints."""

from __future__ import annotations

import ast
import re
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app

runner = CliRunner()
REPO = Path(__file__).resolve().parents[2]

# mlnseq's vocabulary: the words a newcomer cannot know from plain English (the issue's list among them)
VOCABULARY = ("margin", "runner-up", "log-ratio", "nats", "forward message", "backward message", "sum-product",
              "max-product", "information gain", "out-of-fold", "dead band", "marker", "tick", "stale", "DDS", "QoS",
              "exit 143", "spread", "criterion", "network factor weight", "folds", "edit", "F1@50", "lag", "mln-mode",
              "decoder", "chain restart", "uniform transitions", "kept epoch", "segment accuracy", "frame accuracy",
              "candidates", "cross-validated", "start distribution", "paper floor", "why", "term", "pll", "cll",
              "template", "provenance", "digest", "MLN", "PriorLayer", "conflation", "segment mode", "stream mode")
# acronyms and hyphenated words the commands print that are plain (file formats, column names, English)
PLAIN = {"CSV", "JSON", "TOML", "ROS", "MCAP", "OK", "SHA", "SIGINT", "SIGTERM", "HDF", "LSTM", "GRU", "TCN", "FILE",
         "desk-test", "mlnseq-learned",  # the recording's name, the learned spec's digest line
         "per-frame", "per-class", "half-open", "one-hot", "x-axis", "re-run", "so-called", "well-known",
         "hand-written", "by-hand", "non-zero", "read-only", "left-gripper", "right-gripper"}
ISSUE_WORDS = ("margin", "log-ratio", "forward message", "information gain", "nats", "dead band", "spread", "DDS",
               "QoS", "tick", "exit 143")


def glossary_entries() -> set[str]:
    """Every term the glossary defines: its bold words, lower-cased."""
    text = (REPO / "docs" / "glossary.md").read_text()
    return {entry.strip("` ").lower() for bold in re.findall(r"\*\*(.+?)\*\*", text)
            for entry in re.split(r",\s*|\s*/\s*", bold)}


def in_glossary(word: str, entries: set[str]) -> bool:
    word = word.lower()
    return any(word == entry or re.search(rf"(?<![\w-]){re.escape(word)}(?![\w-])", entry) for entry in entries)


def found_in(text: str, word: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(word)}(?![\w-])", text, re.IGNORECASE) is not None


def run(*args) -> str:
    done = runner.invoke(app, [str(a) for a in args])
    assert done.exit_code == 0, done.output
    return done.output


@pytest.fixture(scope="module")
def printed(tmp_path_factory, desk_stream_workdir, desk_frames_workdir, desk_test_recording) -> str:
    """What the commands print on the docs' DESK examples, and the learned spec binarize --suggest writes."""
    folder = tmp_path_factory.mktemp("glossary")
    stream = shutil.copytree(desk_stream_workdir, folder / "stream")  # eval writes metrics.parquet into its workdir
    model = folder / "combined+viterbi.mlnseq"
    said = [run("export", "--method", "combined+viterbi", "-o", model, "-w", stream),
            run("info", model),
            run("explain", model, "--source", desk_test_recording, "--frame", 5000),
            run("explain", model, "--source", desk_test_recording, "--segment", 3),
            run("predict", model, "--source", desk_test_recording, "--explain", 2, "-o", folder / "p.parquet"),
            run("eval", "-w", stream)]
    suggest = folder / "suggest"
    suggest.mkdir()
    shutil.copy(desk_frames_workdir / "frames.parquet", suggest / "frames.parquet")
    said += [run("binarize", "--suggest", "-w", suggest), (suggest / "learned.binarize.toml").read_text(),
             run("binarize", "--table", "-w", suggest)]
    pipeline = folder / "pipeline"  # sequential-logic.md's steps, small: folds, fold networks, every decoder
    said += [run("collect", "--env", "desk", "--source", REPO.parent / "shared" / "data" / "desk-taurus", "-w", pipeline),
             run("binarize", "-w", pipeline),
             run("formulas", "--spec", REPO / "examples" / "temporal.mln", "-w", pipeline),
             run("learn-weights", "--folds", 3, "-w", pipeline),
             run("train", "--mode", "stream", "--epochs", 1, "--folds", 3, "-w", pipeline),
             run("conflate", "--decode", "all", "-w", pipeline),
             run("export", "--method", "auto", "-o", folder / "auto.mlnseq", "-w", pipeline)]
    return "\n".join(said)


def test_every_word_of_the_vocabulary_the_commands_print_is_in_the_glossary(printed):
    entries = glossary_entries()
    seen = [word for word in VOCABULARY if found_in(printed, word)]
    assert {"margin", "log-ratio", "information gain", "nats", "dead band", "max-product"} <= set(seen)
    assert [word for word in seen if not in_glossary(word, entries)] == []


def test_every_acronym_and_hyphenated_term_printed_is_in_the_glossary_or_plain(printed):
    from mlnseq_cli.main import COMMANDS

    prose = re.sub(r'"[^"\n]*"|\S*[/\\.=_]\S*|--\S+', " ", printed)  # names, paths, options and quoted text
    words = set(re.findall(r"(?<![\w@-])([A-Z]{2,}|[a-z]+(?:-[a-z]+)+)(?![\w@-])", prose))
    entries = glossary_entries()
    missing = sorted(w for w in words if w not in PLAIN | set(COMMANDS) and not in_glossary(w, entries))
    assert missing == [], missing


def source_messages() -> str:
    """Every string the live commands' code can print (f-strings and literals, docstrings left out)."""
    texts = []
    for path in [*(REPO / "stages").rglob("*.py"), *(REPO / "mlnseq_cli").glob("*.py")]:
        tree = ast.parse(path.read_text())
        docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                      if isinstance(node, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef))
                      and node.body and isinstance(node.body[0], ast.Expr)}
        texts += [node.value for node in ast.walk(tree) if isinstance(node, ast.Constant)
                  and isinstance(node.value, str) and id(node) not in docstrings]
    return "\n".join(texts)


def test_the_issues_words_are_in_the_glossary_and_the_live_ones_are_printed():
    entries = glossary_entries()
    assert [word for word in ISSUE_WORDS if not in_glossary(word, entries)] == []
    messages = source_messages()
    for word in ("tick", "DDS", "QoS", "spread", "dead band"):
        assert found_in(messages, word), word
