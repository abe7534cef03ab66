"""`mlnseq review`'s site, served by the guarded server (stages/serving/guarded.py): the page's files, the recordings'
table and one recording's view (views.py), a frame's explanation as `explain --json` writes it, and the save into the
labels file (corrections.py), each save and refusal said to the terminal too."""

from __future__ import annotations

import importlib.resources
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from http import HTTPStatus
from pathlib import Path
from typing import Any

import numpy as np

from mlnseq.catalog import folders
from mlnseq.catalog.errors import BadInput
from mlnseq.explaining.explainer import Explainer, Keys, Scores
from mlnseq.explaining.frames import explain, scoring_of
from mlnseq.fusion.fuse import EPSILON
from mlnseq.reviewing import corrections, views
from mlnseq.serving.guarded import Reply

TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8"}


@dataclass
class Reviewed:
    """A recording under review: as decided, and what explaining its frames needs."""

    decided: views.Decided
    keys: Keys
    scores: Scores
    explainer: Explainer | None = None


def page_files() -> dict[str, tuple[str, bytes]]:
    """The page's files by URL path (content type, bytes): the package's page/ folder, read once at the start."""
    folder = importlib.resources.files("mlnseq.reviewing") / "page"
    found = {}
    for item in folder.iterdir():
        suffix = Path(item.name).suffix
        if item.is_file() and suffix in TYPES:
            found["/" + item.name] = (TYPES[suffix], item.read_bytes())
    found["/"] = found["/index.html"]
    return found


class Review:
    """The page's site: its files, the recordings' table and views, a frame's explanation and the save. ``said``
    hears a line for the terminal at each save or refused save."""

    def __init__(self, model: Any, recordings: list[Reviewed], labels: corrections.LabelsFile,
                 ranks: dict[str, tuple[int, str]], decode: str | None, lerobot: tuple[Path, Path] | None = None,
                 said: Callable[[str], None] = lambda line: None):
        self.model, self.recordings, self.labels, self.ranks = model, recordings, labels, ranks
        self.decode, self.lerobot, self.said = decode, lerobot, said  # lerobot: (the source, its annotated copy)
        self.classes = list(model.classes)
        self.files = page_files()
        self.routes: dict[str, Callable[[Mapping[str, list[str]]], Reply]] = {
            "/api/recordings": self.table, "/api/recording": self.view, "/api/explain": self.explained}

    def get(self, path: str, query: Mapping[str, list[str]]) -> Reply | None:
        if path in self.files:
            return Reply(HTTPStatus.OK, *self.files[path])
        route = self.routes.get(path)
        return None if route is None else route(query)

    def post(self, path: str, body: Any) -> Reply | None:
        return self.saved(body) if path == "/api/save" else None

    def _recording(self, query: Mapping[str, list[str]]) -> Reviewed:
        text = (query.get("index") or [""])[0]
        if not text.isdigit() or int(text) >= len(self.recordings):
            raise BadInput(f"index {text!r}: choose a recording 0-{len(self.recordings) - 1}")
        return self.recordings[int(text)]

    def table(self, query: Mapping[str, list[str]]) -> Reply:
        rows = views.table([r.decided for r in self.recordings], self.ranks, self.labels.episodes)
        return Reply.json({"model": self.model.method, "decoder": self.decode or self.model.decoding.name,
                           "classes": self.classes, "features": list(self.model.features),
                           "save": str(self.labels.path), "unit": self.labels.unit, "recordings": rows})

    def view(self, query: Mapping[str, list[str]]) -> Reply:
        recording = self._recording(query)
        decided = recording.decided
        saved = self.labels.saved(decided.id, decided.time, self.classes)
        return Reply.json(views.view(decided, list(self.model.features), self.classes, saved))

    def explained(self, query: Mapping[str, list[str]]) -> Reply:
        """The frame's explanation, as `explain --json` writes it."""
        recording = self._recording(query)
        text = (query.get("frame") or [""])[0]
        rows = np.flatnonzero(recording.keys.frame == int(text)) if text.isdigit() else []
        if not len(rows):
            raise BadInput(f"frame {text!r}: the recording's frames are 0-{len(recording.keys.frame) - 1}")
        if recording.explainer is None:
            recording.explainer = Explainer(scoring_of(self.model, recording.scores.decode, EPSILON))
        explanation = explain(recording.explainer, recording.scores, [int(rows[0])], None, recording.keys)[0]
        return Reply.json(explanation.record())

    def saved(self, body: Any) -> Reply:
        """Write the recording's labels ({index, segments: [[first, last, class], ...]}) into the labels file."""
        if not isinstance(body, dict) or type(body.get("index")) is not int:
            raise BadInput("a save is {\"index\": RECORDING, \"segments\": [[first, last, class], ...]}")
        recording = self._recording({"index": [str(body["index"])]})
        decided = recording.decided
        names = corrections.labels_of(body.get("segments"), len(decided.time), self.classes)
        count = self.labels.put(decided.id, decided.time, names)
        try:
            path = self.labels.write()
            written = {} if self.lerobot is None else {"lerobot": str(self.annotated_copy())}
        except BadInput as error:
            self.said(f"review: {decided.id} not saved: {error}")
            raise
        self.said(f"review: saved {decided.id} ({count} intervals) to {path}")
        return Reply.json({"saved": str(path), "episode": decided.id, "rows": count, **written})

    def annotated_copy(self) -> Path:
        """The LeRobot source copied with the saved labels as the saved episodes' subtask annotations (over their
        own), the model's phases as the others' (their own kept), as `predict --write-lerobot` writes them."""
        from mlnseq.sources import lerobot_writer

        source, out = self.lerobot
        episodes, names, replaced = [], [], set()
        classes = np.asarray(self.classes, dtype=object)
        for recording in self.recordings:
            decided, episode = recording.decided, recording.keys.episode[0]
            saved = self.labels.saved(decided.id, decided.time, self.classes)
            whole = saved is not None and bool((saved >= 0).all())
            replaced |= {episode} if whole else set()
            names.append(classes[saved if whole else decided.path])
            episodes.append(np.full(len(decided.path), episode))
        predicted = lerobot_writer.Predicted(np.concatenate(episodes), np.concatenate(names), None,
                                             tuple(self.classes))
        with folders.atomic_folder(out) as staging:
            lerobot_writer.write(staging, source, predicted, replace=frozenset(replaced))
        return out
