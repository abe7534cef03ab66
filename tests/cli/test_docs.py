"""The user pages agree with the code: docs/predicates.md names every kind and key the spec parser knows, and
its examples parse and binarize real frames as the page says."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq import binarize
from mlnseq.predicates import spec as predicate_spec

PAGE = Path(__file__).resolve().parents[2] / "docs" / "predicates.md"


def sections() -> dict[str, str]:
    """Each `### `kind`` section's text, by kind."""
    parts = re.split(r"^### `([a-z_]+)`\s*$", PAGE.read_text(encoding="utf-8"), flags=re.MULTILINE)
    return dict(zip(parts[1::2], parts[2::2]))


def examples() -> list[tuple[str, str]]:
    """(kind, TOML text) of every example in the page."""
    return [(kind, block) for kind, text in sections().items()
            for block in re.findall(r"```toml\n(.*?)```", text, flags=re.DOTALL)]


def test_every_kind_the_parser_knows_has_a_section_listing_its_keys():
    known = {**predicate_spec.KIND_KEYS, **predicate_spec.CHANNEL_KEYS}
    found = sections()
    assert set(found) == set(known)
    for kind, keys in known.items():
        rows = {row.split("|")[1].strip().strip("`") for row in found[kind].splitlines() if row.startswith("| `")}
        assert rows == keys, kind
    text = PAGE.read_text(encoding="utf-8")
    for key in ("name", "kind", "hint"):
        assert f"| `{key}` |" in text


def test_every_kind_has_an_example_and_each_parses(tmp_path):
    found = examples()
    assert {kind for kind, _ in found} == set(predicate_spec.KIND_KEYS) | set(predicate_spec.CHANNEL_KEYS)
    for kind, text in found:
        spec = binarize.parse_spec(text, tmp_path / f"{kind}.binarize.toml")
        kinds = {type(p).__name__.lower() for p in spec.predicates} | {"distance" for _ in spec.channels}
        assert kind in kinds


def test_the_examples_columns_are_the_pages(tmp_path):
    specs = {kind: binarize.parse_spec(text, tmp_path / "spec.toml") for kind, text in examples()}
    assert specs["distance"].columns()["gripper_to_object"] == [
        "gripper_to_object_at", "gripper_to_object_near", "gripper_to_object_far"]
    grippers = specs["pair"].columns()["grippers"]
    assert len(grippers) == 25 and grippers[0] == "grippers_open_open" and grippers[-1] == "grippers_static_static"


@pytest.mark.parametrize("kind", ["bins", "change", "gripper", "pair"])
def test_the_desk_examples_binarize_real_frames_one_hot(kind, desk_frames_workdir, tmp_path):
    frames = pl.read_parquet(desk_frames_workdir / "frames.parquet")
    [text] = [text for k, text in examples() if k == kind]
    spec = binarize.parse_spec(text, tmp_path / "spec.toml")
    predicates = binarize.binarize(frames, spec)
    for name, columns in spec.columns().items():
        assert (predicates.select(columns).to_numpy().sum(axis=1) == 1).all(), name
    if kind == "bins":  # the page's rule: closed below 0.35, open from 0.90 on
        x = frames.sort("episode", "frame")["left_gripper"].to_numpy()
        assert 0 < (x < 0.35).mean() < 1 and 0 < (x >= 0.90).mean() < 1
        np.testing.assert_array_equal(predicates["left_open_closed"].to_numpy(), x < 0.35)
        np.testing.assert_array_equal(predicates["left_open_open"].to_numpy(), x >= 0.90)
