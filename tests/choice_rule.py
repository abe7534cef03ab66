"""The choice of docs/choosing.md written out again, independently of mlnseq.choosing.latency, for the tests to
hold export --method auto, fit and conflate's ranking to: among the candidates at or above the network alone's
cross-validated frame accuracy, those within one standard error (of the per-fold differences) of the best frame
accuracy, the best mean of segment accuracy, frame accuracy and edit."""

from __future__ import annotations

import numpy as np


def mean_of_three(figures: dict[str, float]) -> float:
    return (figures["segment_accuracy"] + figures["frame_accuracy"] + figures["edit"]) / 3


def expected_choice(figures: dict[str, dict[str, float]], fold_frames: dict[str, list[float]]) -> str:
    """The name the rule chooses among ``figures`` (method name -> cross-validated figures)."""
    names = list(figures)
    frames = {n: figures[n]["frame_accuracy"] for n in names}
    floor = frames["lstm"] if "lstm" in figures else -np.inf
    kept = [n for n in names if frames[n] >= floor] or names
    top = max(kept, key=frames.get)
    near = []
    for name in kept:
        difference = np.array(fold_frames[name]) - np.array(fold_frames[top])
        if frames[name] >= frames[top] - difference.std(ddof=1) / np.sqrt(len(difference)):
            near.append(name)
    return max(near, key=lambda n: (mean_of_three(figures[n]), figures[n].get("log_likelihood", -np.inf)))
