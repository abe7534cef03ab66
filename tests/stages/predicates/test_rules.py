"""The per-frame rules (predicates/rules.py) one frame at a time: a channel the model lacks is named. (That they give
the batch binarizer's values frame by frame, on real frames, is tests/stages/test_binarize.py's.)"""

from __future__ import annotations

import pytest

from mlnseq.catalog.errors import BadInput
from mlnseq.predicates.rules import StreamingBinarizer
from mlnseq.predicates.spec import default_spec_path, load_spec


def test_streaming_binarizer_names_a_channel_the_model_lacks():
    spec = load_spec(default_spec_path("desk"))
    with pytest.raises(BadInput, match="channel 'right_gripper' is not in the model's features"):
        StreamingBinarizer(spec, ["arm_distance", "left_gripper"])
