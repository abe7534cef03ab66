"""The labels a review saves (reviewing/corrections.py): a save's segments checked; the labels file written in the
unit its source reads, read back by `collect --labels`' own reader, the recordings saved before kept; a fit's labels
file carried; a save path inside the source refused."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog.errors import BadInput
from mlnseq.reviewing import corrections
from mlnseq.sources import intervals

CLASSES = ["reach", "grasp", "lift"]


@pytest.mark.parametrize(("segments", "says"), [
    ([], "needs segments"),
    ([[0, 4, "reach"], [6, 9, "lift"]], "do not follow on from frame 5"),
    ([[0, 4, "reach"], [5, 12, "lift"]], "the recording has 10 frames"),
    ([[0, 4, "reach"], [5, 9, "dance"]], "one of reach, grasp, lift"),
    ([[0, 4, "reach"]], "cover 5 of the recording's 10 frames"),
    ([[0, "4", "reach"], [5, 9, "lift"]], "segment 0"),
    ("all", "needs segments"),
])
def test_a_saves_segments_must_cover_the_recording_in_order_with_its_classes(segments, says):
    with pytest.raises(BadInput, match=says):
        corrections.labels_of(segments, 10, CLASSES)


def test_the_labels_file_in_seconds_reads_back_and_keeps_the_recordings_saved_before(tmp_path):
    path = tmp_path / "labels.csv"
    path.write_text("episode,start,end,label\nold,0.0,1.0,reach\n")  # an earlier review's recording
    labels = corrections.LabelsFile(path, "seconds")
    time = np.round(np.arange(10) * 0.1 + 3.0, 6)
    assert labels.saved("old", np.arange(0, 1, 0.1), CLASSES).tolist() == [0] * 10
    assert labels.saved("mine", time, CLASSES) is None
    names = corrections.labels_of([[0, 3, "reach"], [4, 6, "grasp"], [7, 9, "lift"]], 10, CLASSES)
    assert labels.put("mine", time, names) == 3
    labels.write()
    read = intervals.read(path, "seconds")  # the unit it says: the same as --labels-unit seconds, or none given
    assert read == intervals.read(path) and pl.read_csv(path)["unit"].to_list() == ["seconds"] * 4
    assert list(read) == ["old", "mine"]
    assert [(i.start, i.end, i.label) for i in read["mine"]] == [(3.0, 3.4, "reach"), (3.4, 3.7, "grasp"),
                                                                 (3.7, 4.0, "lift")]
    again = corrections.LabelsFile(path, "seconds")  # the next review starts from what was saved
    assert again.saved("mine", time, CLASSES).tolist() == [0, 0, 0, 0, 1, 1, 1, 2, 2, 2]


def test_the_labels_file_in_frames_and_a_label_the_model_lacks(tmp_path):
    path = tmp_path / "labels.csv"
    labels = corrections.LabelsFile(path, "frames")
    labels.put("7", np.arange(6) * 0.5, ["reach", "reach", "lift", "lift", "lift", "grasp"])
    labels.write()
    assert pl.read_csv(path).rows() == [(7, 0, 1, "reach", "frames"), (7, 2, 4, "lift", "frames"),
                                        (7, 5, 5, "grasp", "frames")]  # the file says its unit
    path.write_text("episode,start,end,label\n7,0,5,dance\n")
    with pytest.raises(BadInput, match="labels.csv:2: label 'dance' is not a class of the model"):
        corrections.LabelsFile(path, "frames").saved("7", np.arange(6), CLASSES)


def test_a_save_path_inside_the_source_or_an_input_is_refused(tmp_path):
    source = tmp_path / "bags"
    source.mkdir()
    for save, says in ((source / "labels.csv", "inside the source"), (source / "a" / "b.csv", "inside the source"),
                       (source, "inside the source"), (tmp_path / "model.mlnseq", "an input of this review")):
        with pytest.raises(BadInput, match=says):
            corrections.check_path(save, source, [tmp_path / "model.mlnseq"])
    corrections.check_path(tmp_path / "bags.labels.csv", source, [tmp_path / "model.mlnseq"])


def test_a_fits_labels_file_is_carried_into_the_saves_clicks_and_intervals_each_with_its_unit(tmp_path):
    """review -w of a fit given --labels: the saved file starts with that file's rows (clicks too), so that `fit
    --labels SAVED` has every label the fit had, plus the saves; each row says its unit."""
    given = tmp_path / "given.csv"
    given.write_text("episode,start,end,frame,label\na,,,3,reach\na,,,12,grasp\nb,0,4,,reach\nb,5,9,,lift\n")
    carried = intervals.read(given)
    labels = corrections.LabelsFile(tmp_path / "saved.csv", "frames", carried)
    assert labels.episodes == set() and labels.saved("a", np.arange(20), CLASSES) is None  # nothing saved yet
    labels.put("c", np.arange(10) * 0.1, ["reach"] * 4 + ["lift"] * 6)
    labels.write()
    back = intervals.read(tmp_path / "saved.csv")
    assert list(back) == ["a", "b", "c"] and [i.click for i in back["a"]] == [True, True]
    assert [(i.start, i.end, i.label, i.unit) for i in back["b"]] == [(0, 4, "reach", "frames"), (5, 9, "lift", "frames")]
    assert [(i.start, i.end, i.label) for i in back["c"]] == [(0, 3, "reach"), (4, 9, "lift")]
    assert {i.unit for found in back.values() for i in found} == {"frames"}
    again = corrections.LabelsFile(tmp_path / "saved.csv", "frames", carried)  # the file exists: read, not carried
    assert again.episodes == {"b", "c"} and again.saved("a", np.arange(20), CLASSES) is None  # clicks: not whole
