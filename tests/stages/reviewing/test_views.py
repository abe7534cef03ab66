"""What review's page shows (reviewing/views.py): a long channel decimated keeps its spikes, ends and shape within a
bound of points; a recording's classes as runs; the recordings' ranks."""

from __future__ import annotations

import numpy as np

from mlnseq.reviewing import views


def test_a_long_channel_keeps_each_buckets_extremes_its_ends_and_at_most_two_points_a_bucket():
    rng = np.random.default_rng(0)
    values = np.cumsum(rng.normal(size=60_000))
    values[12_345] = 1e6  # a spike one frame wide
    values[40_000] = -1e6
    values[100:130] = np.nan  # a channel not yet heard
    rows = views.decimated(values, 1000)
    assert len(rows) <= 2 * 1000 + 2 and rows[0] == 0 and rows[-1] == len(values) - 1
    assert {12_345, 40_000} <= set(rows.tolist()) and np.all(np.diff(rows) > 0)
    assert not np.isnan(values[rows]).any()
    size = 60  # frames a bucket: every bucket's min and max are kept
    for start in range(0, 60_000, size * 117):  # bucket starts
        block = values[start:start + size]
        if np.isfinite(block).all():
            assert start + int(np.argmax(block)) in rows and start + int(np.argmin(block)) in rows
    assert views.decimated(values[:1500], 1000).tolist() == list(range(1500))


def test_runs_and_ranks():
    assert views.runs(np.array([0, 0, 2, 2, 2, -1, 1])) == [[0, 1, 0], [2, 4, 2], [5, 5, -1], [6, 6, 1]]
    assert views.runs(np.array([], dtype=int)) == []

    def decided(name: str, sure: float) -> views.Decided:
        probabilities = np.tile([sure, 1 - sure], (10, 1))
        return views.Decided(name, np.arange(10) / 10, np.zeros((10, 1)), np.zeros(10, dtype=int), probabilities, None)

    recordings = [decided("a", 0.9), decided("b", 0.6), decided("c", 0.7), decided("d", 0.8)]
    rows = views.table(recordings, {}, set())
    assert [(r["id"], r["rank"]) for r in rows] == [("b", 1), ("c", 2), ("d", 3), ("a", 4)]
    rows = views.table(recordings, {"d": (1, "new"), "a": (2, "rare")}, {"a"})
    assert [(r["id"], r["rank"], r["saved"]) for r in rows] == [("d", 1, False), ("a", 2, True), ("b", 3, False),
                                                                 ("c", 4, False)]
    # a model that audits: the recordings no ranking names, the most suspect first (the audit's rank), each row
    # with its verdict, score and first reason; label_next.csv's ranking still comes first
    audits = {"a": (1, "suspect", 2.5), "b": (3, "ok", 0.0), "c": (4, "ok", 0.0), "d": (2, "ok", 0.7)}
    reason = {"reason": "grasp again after transport", "where": "1.00-2.00 s (frames 10-20)"}
    audited = [views.Decided(r.id, r.time, r.features, r.path, r.probabilities, None, audit={
        "rank": audits[r.id][0], "verdict": audits[r.id][1], "score": audits[r.id][2],
        "reasons": [reason] if r.id == "a" else []}) for r in recordings]
    rows = views.table(audited, {}, set())
    assert [(r["id"], r["rank"], r["verdict"]) for r in rows] == [("a", 1, "suspect"), ("d", 2, "ok"), ("b", 3, "ok"),
                                                                  ("c", 4, "ok")]
    assert rows[0]["why"] == "grasp again after transport (1.00-2.00 s (frames 10-20))" and rows[1]["why"] is None
    assert rows[0]["reason"] == "ranked by the audit (the most suspect first)"
    rows = views.table(audited, {"c": (1, "new")}, set())
    assert [r["id"] for r in rows] == ["c", "a", "d", "b"]
