"""metrics: the segment-fraction index, edit score and F1@k by hand, and every metric of a method."""

import numpy as np
import pytest

from stages import metrics as stage


@pytest.mark.parametrize(("length", "fraction", "frame"), [
    (1, 0.5, 0), (2, 0.5, 0), (3, 0.5, 0), (10, 0.5, 4),
    (1, 1.0, 0), (2, 1.0, 1), (3, 1.0, 2), (10, 1.0, 9), (10, 0.1, 0), (3, 0.7, 1),
])
def test_segment_frame_is_max_of_int_len_times_fraction_minus_one_and_zero(length, fraction, frame):
    assert stage.segment_frame(length, fraction) == frame


def test_edit_score_on_known_sequences():
    truth = np.array([0, 0, 1, 1, 2])
    assert stage.edit_score(np.array([0, 1, 1, 2, 2]), truth) == 100.0
    assert stage.edit_score(np.array([0, 0, 0, 2, 2]), truth) == pytest.approx(100 * (1 - 1 / 3))
    assert stage.edit_score(np.array([0, 0, 1, 0, 1, 1, 1, 1]), np.array([0] * 4 + [1] * 4)) == 50.0


def test_segmental_f1_on_known_sequences():
    truth = np.array([0] * 4 + [1] * 4)
    shifted = np.array([0] * 2 + [1] * 6)  # IoU 2/4 and 4/6
    assert stage.overlap_counts(shifted, truth, 0.5) == (2, 0, 0)
    assert stage.overlap_counts(shifted, truth, 0.6) == (1, 1, 1)
    assert stage.f1(1, 1, 1) == 50.0
    split = np.array([0, 0, 1, 0, 1, 1, 1, 1])  # (0: IoU .5), (1: IoU 0), (0: true 0 already hit), (1: IoU 1)
    for overlap in (0.1, 0.25, 0.5):
        assert stage.overlap_counts(split, truth, overlap) == (2, 2, 0)
    assert stage.f1(2, 2, 0) == pytest.approx(100 * 2 / 3)


def test_scores_of_a_method_on_hand_made_predictions():
    labels = np.array([0, 0, 0, 0, 1, 1, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2])
    predictions = np.array([1, 0, 0, 0, 1, 1, 2, 2, 2, 2, 0, 0, 0, 0, 0, 0])
    episodes = np.zeros_like(labels)
    result = stage.score_method(predictions, labels, episodes, 3, 0.5, segmental=True)
    # frames recognised: segment 0 at frame 1 (0 ok), segment 1 at frame 4 (1 ok), segment 2 at frame 10 (0 wrong)
    assert result["segment_accuracy"] == pytest.approx(2 / 3)
    assert result["per_class"] == {0: 1.0, 1: 1.0, 2: 0.0}
    assert result["frame_accuracy"] == pytest.approx(9 / 16)
    assert result["early"][0.1] == pytest.approx(2 / 3)  # frames 0 (wrong), 4, 6
    assert result["confusion"][2] == [1, 0, 0]
    assert "edit" in result and "f1@50" in result

