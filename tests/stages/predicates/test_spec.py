"""The predicate spec's parser (predicates/spec.py): every error names the file, the line and the key."""

from __future__ import annotations

import pytest

from mlnseq.catalog.errors import BadInput
from mlnseq.predicates.spec import load_spec

VALID = '[[predicate]]\nname = "g"\nkind = "change"\nchannel = "left_gripper"\nthreshold = 0.05\n'


@pytest.mark.parametrize(
    ("text", "line", "expected"),
    [
        (VALID.replace('"change"', '"wobble"'), 3, r"key 'kind'.*unknown predicate kind 'wobble'"),
        (VALID.replace("0.05", "-1"), 5, r"key 'threshold'.*at least 0, got -1"),
        (VALID.replace("0.05", '"high"'), 5, r"key 'threshold'.*finite number"),
        (VALID.replace('threshold = 0.05\n', ''), 1, r"missing key 'threshold'"),
        (VALID.replace("threshold", "treshold"), 5, r"key 'treshold'.*unknown key"),
        ("# spec\n" + VALID + VALID.replace('"g"', '"h"').replace('"change"', '"bins"').replace(
            "threshold = 0.05", "edges = [0.5, 0.2]\nvalues = ['a', 'b', 'c']"), 11, r"key 'edges'.*ascending"),
        (VALID + '[[predicate]]\nname = "both"\nkind = "pair"\nof = ["g", "nope"]\n', 9, r"key 'of'.*'nope'"),
        (VALID + VALID, 7, r"key 'name'.*defined twice"),
        (VALID.replace('"g"', '"Left"'), 2, r"key 'name'.*lowercase identifier"),
        (VALID + "[[predicate]\n", 6, r"invalid TOML"),
        ("# nothing\n", 1, r"no \[\[predicate\]\]"),
    ],
)
def test_spec_errors_name_the_key_and_the_line(tmp_path, text, line, expected):
    path = tmp_path / "my.binarize.toml"
    path.write_text(text)
    with pytest.raises(BadInput, match=rf"^{path}:{line}: .*{expected}"):
        load_spec(path)
