"""metrics: the segment-fraction index, edit score and F1@k by hand, and every metric of a method."""

import numpy as np
import polars as pl
import pytest

from mlnseq.timeline import metrics as stage


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


def reference_edit_score(predicted: np.ndarray, truth: np.ndarray) -> float:
    """The Levenshtein table filled cell by cell, as the definition reads."""
    p = [r[0] for r in stage.label_runs(predicted)]
    t = [r[0] for r in stage.label_runs(truth)]
    if not p and not t:
        return 100.0
    d = np.zeros((len(p) + 1, len(t) + 1))
    d[:, 0], d[0, :] = np.arange(len(p) + 1), np.arange(len(t) + 1)
    for i in range(1, len(p) + 1):
        for j in range(1, len(t) + 1):
            d[i, j] = min(d[i - 1, j] + 1, d[i, j - 1] + 1, d[i - 1, j - 1] + (p[i - 1] != t[j - 1]))
    return float(100 * (1 - d[-1, -1] / max(len(p), len(t))))


def reference_overlap_counts(predicted: np.ndarray, truth: np.ndarray, overlap: float) -> tuple[int, int, int]:
    """MS-TCN's f_score loop: each predicted segment against each true one in turn."""
    p, t = stage.label_runs(predicted), stage.label_runs(truth)
    matched = np.zeros(len(t), dtype=bool)
    tp = fp = 0
    for label, start, stop in p:
        best, best_iou = -1, -1.0
        for j, (t_label, t_start, t_stop) in enumerate(t):
            if t_label == label:
                iou = max(min(stop, t_stop) - max(start, t_start), 0) / (max(stop, t_stop) - min(start, t_start))
                if iou > best_iou:
                    best, best_iou = j, iou
        if best >= 0 and best_iou >= overlap and not matched[best]:
            tp, matched[best] = tp + 1, True
        else:
            fp += 1
    return tp, fp, int((~matched).sum())


def test_edit_score_and_f1_counts_equal_the_cell_by_cell_definitions(desk_full_workdir):
    rng = np.random.default_rng(0)
    cases = [(rng.integers(0, k, n), rng.integers(0, k, n)) for k, n in ((2, 1), (3, 7), (4, 60), (7, 300))]
    cases += [(np.repeat(rng.integers(0, 4, 30), rng.integers(1, 9, 30)),) * 2]  # identical runs
    predictions = pl.read_parquet(desk_full_workdir / "predictions.parquet")  # real, flickering predictions
    test = predictions.filter(pl.col("split") == "test")
    cases.append((test["mln_pred"].to_numpy()[:3000], test["label"].to_numpy()[:3000]))
    for predicted, truth in cases:
        assert stage.edit_score(predicted, truth) == reference_edit_score(predicted, truth)
        for overlap in stage.OVERLAPS:
            assert stage.overlap_counts(predicted, truth, overlap) == reference_overlap_counts(predicted, truth, overlap)
    assert stage.overlap_counts(np.array([], dtype=np.int64), np.array([1, 1]), 0.5) == (0, 0, 1)


def quadratic_overlap_counts(predicted: np.ndarray, truth: np.ndarray, overlap: float) -> tuple[int, int, int]:
    """overlap_counts as it was before the matching became n log n: every predicted segment against every true one
    (IoU, -1 where the classes differ), the first maximum."""
    p = np.array(stage.label_runs(predicted), dtype=np.int64).reshape(-1, 3)
    t = np.array(stage.label_runs(truth), dtype=np.int64).reshape(-1, 3)
    matched = np.zeros(len(t), dtype=bool)
    if not len(t):
        return 0, len(p), 0
    intersection = np.minimum(p[:, None, 2], t[None, :, 2]) - np.maximum(p[:, None, 1], t[None, :, 1])
    union = np.maximum(p[:, None, 2], t[None, :, 2]) - np.minimum(p[:, None, 1], t[None, :, 1])
    iou = np.where(p[:, None, 0] == t[None, :, 0], np.maximum(intersection, 0) / union, -1.0)
    best = iou.argmax(axis=1)
    best_iou = iou[np.arange(len(p)), best]
    tp = fp = 0
    for j, hit in zip(best.tolist(), (best_iou >= overlap).tolist()):
        if hit and not matched[j]:
            tp += 1
            matched[j] = True
        else:
            fp += 1
    return tp, fp, int((~matched).sum())


def _label_sequences():
    from hypothesis import strategies as st

    def runs(draw_classes: int):
        # runs of random lengths: short flickers and long segments, as predictions and labels have
        return st.lists(st.tuples(st.integers(0, draw_classes - 1), st.integers(1, 12)), max_size=40).map(
            lambda pairs: np.repeat(np.array([c for c, _ in pairs], dtype=np.int64),
                                    [n for _, n in pairs]) if pairs else np.zeros(0, dtype=np.int64))

    return st.integers(1, 5).flatmap(lambda k: st.tuples(runs(k), runs(k)))


def test_overlap_counts_equal_the_quadratic_matching_on_random_label_sequences():
    """The n log n matching gives the quadratic version's tp, fp, fn (ties: the first maximum) on random sequences of
    equal length (a recording), of unequal length and empty, at the reported overlaps and at 0, 1/3 and 1; the
    bit-parallel edit score the cell-by-cell table's."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    overlaps = (*stage.OVERLAPS, 0.0, 1 / 3, 1.0)

    @settings(max_examples=400, deadline=None, derandomize=True, database=None)
    @given(_label_sequences(), st.booleans())
    def check(pair, same_length):
        predicted, truth = pair
        if same_length:
            n = min(len(predicted), len(truth))
            predicted, truth = predicted[:n], truth[:n]
        counts = stage.overlap_counts_all(predicted, truth, overlaps)
        for overlap in overlaps:
            assert counts[overlap] == quadratic_overlap_counts(predicted, truth, overlap)
        assert stage.edit_score(predicted, truth) == reference_edit_score(predicted, truth)  # bit-parallel = table

    check()


def test_overlap_counts_over_episodes_in_one_pass_are_the_sums_over_each_episode():
    """score_method's F1@k: one pass over every episode gives the per-episode counts' sums (random episodes)."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    @settings(max_examples=200, deadline=None, derandomize=True, database=None)
    @given(_label_sequences(), st.lists(st.integers(1, 15), min_size=1, max_size=8))
    def check(pair, lengths):
        predicted, truth = pair
        n = min(len(predicted), len(truth))
        predicted, truth = predicted[:n], truth[:n]
        episodes = np.resize(np.repeat(np.arange(len(lengths)) % 3, lengths), n)  # an id may come back later
        together = stage.overlap_counts_all(predicted, truth, stage.OVERLAPS, episodes)
        for overlap in stage.OVERLAPS:
            summed = np.zeros(3, dtype=np.int64)
            for block in stage.sequences.runs(episodes):
                summed += quadratic_overlap_counts(predicted[block], truth[block], overlap)
            assert together[overlap] == tuple(summed.tolist())

    check()
    with pytest.raises(ValueError):
        stage.overlap_counts_all(np.zeros(3, int), np.zeros(3, int), (0.0,), np.zeros(3, int))


def test_edit_scores_over_episodes_in_one_pass_are_each_episodes_edit_score():
    """score_method's edit: the runs of every episode found at once give each episode's own edit score, and each
    segment's recognising frame taken at once is segment_frame's (random episodes, an id may come back later)."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    @settings(max_examples=200, deadline=None, derandomize=True, database=None)
    @given(_label_sequences(), st.lists(st.integers(1, 15), min_size=1, max_size=8),
           st.sampled_from(stage.EARLY_FRACTIONS + (0.5, 1.0)))
    def check(pair, lengths, fraction):
        predicted, truth = pair
        n = min(len(predicted), len(truth))
        predicted, truth = predicted[:n], truth[:n]
        episodes = np.resize(np.repeat(np.arange(len(lengths)) % 3, lengths), n)
        blocks = stage.sequences.runs(episodes)
        assert stage.edit_scores(predicted, truth, episodes) == [stage.edit_score(predicted[b], truth[b])
                                                                 for b in blocks]
        spans = stage.sequences.segments(episodes, np.zeros_like(episodes), truth)
        starts = np.array([s.start for s in spans], dtype=np.int64)
        lengths_ = np.array([s.stop - s.start for s in spans], dtype=np.int64)
        at = [predicted[s.start + stage.segment_frame(s.stop - s.start, fraction)] for s in spans]
        assert stage.segment_predictions(starts, lengths_, predicted, fraction).tolist() == at

    check()
