"""Recordings audited in one go and their verdicts as rows: every recording decoded by the model's chain over the
whole recording (Viterbi; the argmax where the model does not decode), scored against the profile (scoring.py), and
ranked, the most suspect first, one row each: ``episode``, ``rank``, ``verdict``, ``score``, ``reason`` (the first, in
words), ``phase`` (where it happens), ``where`` (seconds and frames), ``reasons`` (all, in order, as JSON) and
``frames``."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np
import polars as pl

from mlnseq.auditing import chains, scoring
from mlnseq.auditing.profile import Profile
from mlnseq.auditing.scoring import Audited, Reason
from mlnseq.timeline import sequences

OK, SUSPECT = "ok", "suspect"


@dataclass(frozen=True)
class Recording:
    """One recording audited: its name, frames (their times in seconds, or None), and its verdict."""

    name: Any
    start: int  # its first row in the frames audited
    frames: int
    times: np.ndarray | None  # seconds from its start, per frame (None: by the profile's rate)
    audited: Audited


def decode_of(recognizer: Any) -> str:
    """How an audit decodes a model's recordings: Viterbi over the model's chain, or none where it has none."""
    return "viterbi" if recognizer.decode != "none" else "none"


def audit_all(profile: Profile, scores: Any, episodes: np.ndarray, names: list[Any],
              times: np.ndarray | None = None) -> list[Recording]:
    """Every recording a Recognizer scored (``scores``: its ``scored`` over frames grouped by ``episodes``, an index
    into ``names``, decoded by ``decode_of``) judged against ``profile``."""
    decoded = scores.factors is not None
    out = []
    for span in sequences.runs(episodes):
        evidence = None if scores.evidence is None or not profile.rules else scores.evidence[span]
        if decoded:
            found = chains.decoded(chains.piece(scores.factors, span), evidence, scores.path[span])
        else:
            found = chains.Decoded(scores.path[span], evidence)
        out.append(Recording(names[int(episodes[span.start])], span.start, span.stop - span.start,
                             None if times is None else np.asarray(times)[span], scoring.audit(profile, found)))
    return out


def audited(recognizer: Any, profile: Profile, features: np.ndarray, episodes: np.ndarray, names: list[Any],
            times: np.ndarray | None = None) -> tuple[Any, list[Recording]]:
    """A Recognizer's scores of ``features`` (grouped by ``episodes``, decoded by ``decode_of``) and every recording
    judged against ``profile``."""
    scores = recognizer.scored(features, episodes, decode_of(recognizer))
    return scores, audit_all(profile, scores, episodes, names, times)


def explained(recognizer: Any, scores: Any, recordings: list[Recording], count: int) -> dict[tuple[int, int], list]:
    """The ``count`` largest terms behind each reason, as `explain` gives them for the decision at its first frame:
    (recording, reason) -> terms as JSON-ready dicts."""
    from mlnseq.explaining.explainer import Explainer
    from mlnseq.explaining.frames import explain, scoring_of
    from mlnseq.explaining.terms import brief
    from mlnseq.fusion.fuse import EPSILON

    wanted = [(k, j, recording.start + reason.start) for k, recording in enumerate(recordings)
              for j, reason in enumerate(recording.audited.reasons)]
    if not wanted:
        return {}
    explainer = Explainer(scoring_of(recognizer, scores.decode, EPSILON))
    found = explain(explainer, scores, [row for _, _, row in wanted])
    return {(k, j): brief(explanation.largest(count)) for (k, j, _), explanation in zip(wanted, found)}


def where(profile: Profile, recording: Recording, reason: Reason) -> str:
    """Where a reason happens: seconds from the recording's start (its own times, or by the rate) and frames."""
    last = max(reason.stop - 1, reason.start)
    frames = f"frames {reason.start}-{last}"
    if recording.times is not None and len(recording.times):
        first, end = recording.times[min(reason.start, len(recording.times) - 1)], recording.times[last]
        return f"{first:.2f}-{end:.2f} s ({frames})"
    if profile.timed:
        return f"{reason.start / profile.rate:.2f}-{last / profile.rate:.2f} s ({frames})"
    return frames


def reason_record(profile: Profile, recording: Recording, reason: Reason) -> dict[str, Any]:
    return {"reason": reason.text, "kind": reason.kind.value, "phase": profile.classes[reason.phase],
            "start": reason.start, "stop": reason.stop, "where": where(profile, recording, reason),
            "severity": round(reason.severity, 3)}


def table(profile: Profile, recordings: list[Recording], terms: dict[tuple[int, int], list] | None = None
          ) -> pl.DataFrame:
    """The verdicts, ranked (1: the most suspect; ties by the recordings' order); ``terms``: each reason's terms
    (``explained``), in its record's ``terms``."""
    order = sorted(range(len(recordings)), key=lambda k: (-recordings[k].audited.score, k))
    rows = []
    for rank, k in enumerate(order, start=1):
        recording = recordings[k]
        audited = recording.audited
        first = audited.reasons[0] if audited.reasons else None
        rows.append({"episode": str(recording.name), "rank": rank, "verdict": SUSPECT if audited.suspect else OK,
                     "score": round(audited.score, 4), "reason": first.text if first else "",
                     "phase": profile.classes[first.phase] if first else "",
                     "where": where(profile, recording, first) if first else "",
                     "reasons": json.dumps([reason_record(profile, recording, r)
                                            | ({"terms": terms[k, j]} if terms is not None else {})
                                            for j, r in enumerate(audited.reasons)]),
                     "frames": recording.frames})
    schema = {"episode": pl.String, "rank": pl.Int64, "verdict": pl.String, "score": pl.Float64, "reason": pl.String,
              "phase": pl.String, "where": pl.String, "reasons": pl.String, "frames": pl.Int64}
    return pl.DataFrame(rows, schema=schema)
