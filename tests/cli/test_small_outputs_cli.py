"""Issue 55's smaller output items, on the real DESK data: binarize --table never offers a value true in none of a
class's frames as its marker."""

from __future__ import annotations

import polars as pl

from mlnseq_cli import binarize as binarize_command
from mlnseq_cli.console import console
from mlnseq.catalog import artifacts


def test_a_class_no_value_marks_is_said_so_not_offered_a_zero_share(desk_mln_workdir, monkeypatch):
    predicates, meta = artifacts.read_table(desk_mln_workdir / artifacts.PREDICATES, "predicates")
    classes = meta["classes"]
    never = {"right_gripper": ["right_gripper_opening", "right_gripper_static"]}  # true in no training frame
    assert all(predicates.filter(pl.col("split") == "train")[c].sum() == 0 for c in never["right_gripper"])
    monkeypatch.setattr(console, "width", 200)
    with console.capture() as captured:
        binarize_command.print_class_table(predicates, never, classes)
    marks = captured.get().split("marks each class")[1].splitlines()[1:]
    assert len(marks) == len(classes)
    assert all(": none: no value is true in more of its frames" in line for line in marks), marks
    with console.capture() as captured:
        binarize_command.print_class_table(predicates, meta["predicates"], classes)
    marks = captured.get().split("marks each class")[1].splitlines()[1:]
    assert all("none" not in line and "(0%" not in line for line in marks), marks
