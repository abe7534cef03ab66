"""Output a newcomer reads at 80 columns (issue 55, item 5): every command's --help shows its option names whole,
and eval's tables never cut a number, even at the widest figures with the longest method names conflate makes."""

from __future__ import annotations

import dataclasses
import shutil

import pytest
from typer.testing import CliRunner

from mlnseq_cli import eval as eval_command
from mlnseq_cli.console import console
from mlnseq_cli.main import COMMANDS, _load, app
from mlnseq import eval as stage

runner = CliRunner()
NARROW = 80


@pytest.mark.parametrize("name", [name for name in COMMANDS if name != "config"])
def test_help_at_80_columns_shows_every_option_name_whole(name, monkeypatch):
    monkeypatch.setenv("COLUMNS", str(NARROW))
    shown = runner.invoke(app, [name, "--help"])
    assert shown.exit_code == 0, shown.output
    assert "…" not in shown.output
    for param in _load(name).params:
        for option in (*param.opts, *param.secondary_opts):
            if option.startswith("--") and not param.hidden:
                assert option in shown.output, option


@pytest.fixture(scope="module")
def decoded_everywhere(tmp_path_factory, desk_stream_workdir):
    """desk_stream_workdir conflated with every decoder at every lag, evaluated: eval's longest method names."""
    from mlnseq import conflate

    workdir = tmp_path_factory.mktemp("all-decoders")
    for path in desk_stream_workdir.iterdir():
        (shutil.copytree if path.is_dir() else shutil.copy)(path, workdir / path.name)
    conflate.run(workdir, conflate.ConflateOptions(decode=conflate.parse_decode("all")))
    return stage.run(workdir, stage.EvalOptions(method="all"))


def drawn(result, monkeypatch) -> str:
    monkeypatch.setattr(console, "width", NARROW)
    with console.capture() as captured:
        eval_command.print_tables(result, 0.5)
    return captured.get()


def test_eval_all_fits_80_columns_as_measured(decoded_everywhere, monkeypatch):
    text = drawn(decoded_everywhere, monkeypatch)
    assert "conflation+lagviterbi-legal@25" in text
    assert "…" not in text and max(map(len, text.splitlines())) <= NARROW


def test_eval_at_its_widest_figures_drops_the_mode_column_with_a_note(decoded_everywhere, monkeypatch):
    """Every figure at 100 % (the widest a cell gets): the numbers are whole, the mode column goes, a note says so."""
    widest = {k: 100.0 for k in ("edit", "f1@10", "f1@25", "f1@50")} | {
        k: 1.0 for k in ("segment_accuracy", "frame_accuracy", "macro_f1")}
    results = {m: {**r, **widest, "per_class": {k: 1.0 for k in r["per_class"]}, "early": {f: 1.0 for f in r["early"]}}
               for m, r in decoded_everywhere.results.items()}
    text = drawn(dataclasses.replace(decoded_everywhere, results=results), monkeypatch)
    assert "…" not in text and max(map(len, text.splitlines())) <= NARROW
    rows = [line.split() for line in text.splitlines() if line.startswith("conflation+lagviterbi-legal@25 ")]
    assert rows[0][1:] == ["100.0%", "100.0%", "1.000", "100.0", "100.0", "100.0", "100.0"]
    assert "(mode, " in text and "left out at 80 columns; --json shows it)" in text


def test_eval_s_per_class_table_fits_with_long_class_names(decoded_everywhere, monkeypatch):
    """Seven classes whose first words take 7 letters (`lifting the part`, ...): beside the longest method names
    they do not fit, so the headings are c0, c1 ... with a legend."""
    long = [f"{word} the part" for word in ("lifting", "placing", "holding", "turning", "pushing", "pouring",
                                            "waiting")]
    assert len(long) == len(decoded_everywhere.classes)
    text = drawn(dataclasses.replace(decoded_everywhere, classes=long), monkeypatch)
    assert "…" not in text and max(map(len, text.splitlines())) <= NARROW
    assert "c0 = lifting the part" in text
