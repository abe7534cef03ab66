"""The recordings under review, each decided on its own as `explain` decides it, so that a click on a frame shows the
terms `mlnseq explain --json` prints for it; with a fit's workdir, each with its labels as fit trained on them (and
where they came from) and the phases fit proposes to correct; with a model that audits, each recording's audit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mlnseq.auditing import verdicts
from mlnseq.auditing.profile import model_profile
from mlnseq.explaining.explainer import Keys
from mlnseq.recognition.reading import Reading
from mlnseq.reviewing import fitted, views
from mlnseq.reviewing.site import Reviewed


def audited(read: Reading, where: Path) -> dict[str, dict] | None:
    """Each recording's audit, as `mlnseq audit` gives it (its verdict, score, rank and reasons with their frames),
    by episode id; None where the model file holds no audit profile."""
    profile = model_profile(read.model, where)
    if profile is None:
        return None
    features = read.frames.select(read.model.features).to_numpy()
    _, recordings = verdicts.audited(read.model, profile, features, read.frames["episode"].to_numpy(), read.names,
                                     np.asarray(read.times, dtype=np.float64))
    return {row["episode"]: {"verdict": row["verdict"], "score": row["score"], "rank": row["rank"],
                             "reasons": json.loads(row["reasons"])}
            for row in verdicts.table(profile, recordings).iter_rows(named=True)}


def decide(read: Reading, workdir: fitted.Workdir | None, audits: dict[str, dict] | None = None) -> list[Reviewed]:
    """Each recording decided on its own, as `explain` decides it; its labels as read, or, from a fit's workdir, as
    fit trained on them (and where they came from) with the phases fit proposes to correct; its audit, given."""
    found = []
    model, frames, classes = read.model, read.frames, list(read.model.classes)
    for index, name in enumerate(read.names):
        rows = read.episode(index)
        features = frames[rows].select(model.features).to_numpy()
        keys = Keys([name] * len(rows), frames["frame"].to_numpy()[rows], np.asarray(read.times, dtype=float)[rows])
        scores = model.scored(features, None, read.decode)
        labels, origin, proposal = frames["label"].to_numpy()[rows].astype(np.int64), None, None
        if workdir is not None:
            labels, origin = _as_fit_trained(workdir, str(name), labels, classes)
            proposal = workdir.proposal(str(name), len(rows), classes)
        decided = views.Decided(str(name), keys.time, features, np.asarray(scores.path, dtype=np.int64),
                                np.asarray(scores.probabilities), labels if (labels >= 0).any() else None, origin,
                                proposal, None if audits is None else audits.get(str(name)))
        found.append(Reviewed(decided, keys, scores))
    return found


def _as_fit_trained(workdir: fitted.Workdir, name: str, labels: np.ndarray,
                    classes: list[str]) -> tuple[np.ndarray, str | None]:
    """A recording's labels as its fit trained on them, and where they came from (as read where the workdir's frames
    of it are not these: the recordings changed since)."""
    given = workdir.labels.get(name)
    if given is None or len(given.names) != len(labels):  # none fit trained on, or not these frames: as read
        return labels, None
    return np.array([-1 if k is None else classes.index(k) for k in given.names], dtype=np.int64), given.origin.value
