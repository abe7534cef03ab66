"""review: a model's phases over the robot's signals in the browser; any moment explained; corrections saved as labels.

The recordings are read as `predict` reads them (as the model's own were read; or, with a fit's workdir, the
recordings it was fitted on) and each is decided as `explain` decides it, so a click on a frame shows exactly the
terms `mlnseq explain --json` prints for it. The page (stages/reviewing/page/) is served on 127.0.0.1 by a
guarded standard-library server (stages/serving/guarded.py); a save writes the recording's labels into the one
labels file given at the start (stages/reviewing/corrections.py), in the form `collect --labels` reads.
"""

from __future__ import annotations

import csv
import importlib.resources
from dataclasses import dataclass, field
from http import HTTPStatus
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from mlnseq.catalog import artifacts, folders
from mlnseq.catalog.errors import BadInput
from mlnseq.explaining.explainer import Explainer, Keys, Scores
from mlnseq.explaining.frames import explain, scoring_of
from mlnseq.fusion.fuse import EPSILON
from mlnseq.recognition import reading
from mlnseq.recognition.reading import ReadOptions
from mlnseq.recognition.recognizer import Recognizer
from mlnseq.reviewing import corrections, views
from mlnseq.serving.guarded import BODY_LIMIT, GuardedServer, Reply, serve
from mlnseq.sources import RECORDING_ENVS

TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8"}


@dataclass(frozen=True)
class ReviewOptions:
    """Options of `mlnseq review`; the reading options None: as the model's recordings were read."""

    model: Path
    source: Path | None = None  # default: the recordings of ``workdir``'s fit
    workdir: Path | None = None  # a fit's workdir: its recordings, ranked by its label_next.csv
    save: Path | None = None  # the labels file; default: SOURCE's name + .labels.csv here, or beside WORKDIR
    save_lerobot: Path | None = None  # a LeRobot source: also a copy of it with the labels as subtask annotations
    host: str = "127.0.0.1"
    port: int = 8750  # 0: any free port
    reading: ReadOptions = field(default_factory=ReadOptions)  # the decoder and how the recordings are read
    body_limit: int = BODY_LIMIT

    def validate(self) -> None:
        if self.source is None and self.workdir is None:
            raise BadInput("give the recordings: --source RECORDINGS, or -w WORKDIR (a fit's workdir)")
        if not 0 <= self.port <= 65535:
            raise BadInput(f"--port {self.port}: choose 0-65535 (0: any free port)")
        self.reading.validate()

    def save_path(self) -> Path:
        if self.save is not None:
            return Path(self.save)
        if self.source is None:
            workdir = Path(self.workdir).resolve()
            return workdir.parent / f"{workdir.name}.labels.csv"
        return Path(f"{Path(self.source).stem}.labels.csv")


def workdir_source(workdir: Path) -> Path:
    """The recordings a fit's workdir was collected from (its frames.parquet remembers them)."""
    meta = artifacts.read_metadata(Path(workdir) / artifacts.FRAMES, "frames")
    source = (meta.get("options") or {}).get("source")
    if not source or meta.get("source") not in RECORDING_ENVS:
        raise BadInput(f"-w {workdir}: its frames were not collected from recordings; give --source")
    return Path(source)


def ranks_of(workdir: Path | None) -> dict[str, tuple[int, str]]:
    """WORKDIR/label_next.csv's ranks by episode (episode, rank, reason), if the workdir has one."""
    path = None if workdir is None else Path(workdir) / artifacts.LABEL_NEXT
    if path is None or not path.is_file():
        return {}
    found = {}
    with path.open(encoding="utf-8", newline="") as handle:
        for line, row in enumerate(csv.DictReader(handle), start=2):
            try:
                found[str(row["episode"])] = (int(row["rank"]), str(row.get("reason") or ""))
            except (KeyError, TypeError, ValueError):
                raise BadInput(f"{path}:{line}: expected episode,rank,reason with a whole-number rank") from None
    return found


@dataclass
class Reviewed:
    """A recording under review: as decided, and what explaining its frames needs."""

    decided: views.Decided
    keys: Keys
    scores: Scores
    explainer: Explainer | None = None


def decide(model: Recognizer, frames: Any, names: list, times: np.ndarray, decode: str | None) -> list[Reviewed]:
    """Each recording decided on its own, as `explain` decides it."""
    found = []
    episodes = frames["episode"].to_numpy()
    for index, name in enumerate(names):
        rows = np.flatnonzero(episodes == index)
        features = frames[rows].select(model.features).to_numpy()
        keys = Keys([name] * len(rows), frames["frame"].to_numpy()[rows], np.asarray(times, dtype=float)[rows])
        scores = model.scored(features, None, decode)
        labels = frames["label"].to_numpy()[rows].astype(np.int64)
        decided = views.Decided(str(name), keys.time, features, np.asarray(scores.path, dtype=np.int64),
                                np.asarray(scores.probabilities), labels if (labels >= 0).any() else None)
        found.append(Reviewed(decided, keys, scores))
    return found


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
    """The page's site: its files, the recordings' table and views, a frame's explanation and the save."""

    def __init__(self, model: Recognizer, recordings: list[Reviewed], labels: corrections.LabelsFile,
                 ranks: dict[str, tuple[int, str]], decode: str | None, lerobot: tuple[Path, Path] | None = None):
        self.model, self.recordings, self.labels, self.ranks = model, recordings, labels, ranks
        self.decode, self.lerobot = decode, lerobot  # lerobot: (the source dataset, its annotated copy)
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
        rows = views.table([r.decided for r in self.recordings], self.ranks, set(self.labels.rows))
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
        path = self.labels.write()
        written = {} if self.lerobot is None else {"lerobot": str(self.annotated_copy())}
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


@dataclass(frozen=True)
class Started:
    """What `run` tells before it serves: where, and what it read."""

    url: str
    recordings: int
    frames: int
    save: Path


def prepare(options: ReviewOptions) -> tuple[Review, GuardedServer]:
    """Read the model and the recordings, decide them, check the labels file and open the port (nothing served
    yet): every refusal comes here, before the address is printed."""
    options.validate()
    source = Path(options.source) if options.source is not None else workdir_source(options.workdir)
    save = options.save_path()
    given = options.reading.overrides.get("labels")
    corrections.check_path(save, source, [Path(options.model), *([Path(given)] if given is not None else [])])
    read = reading.read(options.model, source, options.reading)
    if options.save_lerobot is not None:
        _check_lerobot(options, read.env, source, save)
    for path in read.meta["source_files"]:
        corrections.check_path(save, Path(path), [])
    labels = corrections.LabelsFile(save, read.source.unit(read.env))
    decided = decide(read.model, read.frames, list(read.names), read.times, read.decode)
    for recording in decided:  # a labels file that does not fit the recordings is refused now, not at a click
        labels.saved(recording.decided.id, recording.decided.time, list(read.model.classes))
    lerobot = None if options.save_lerobot is None else (source, Path(options.save_lerobot))
    site = Review(read.model, decided, labels, ranks_of(options.workdir), read.decode, lerobot)
    return site, GuardedServer(options.host, options.port, site, options.body_limit)


def _check_lerobot(options: ReviewOptions, env: str, source: Path, save: Path) -> None:
    """--save-lerobot OUT: a LeRobot source, and OUT a folder of its own (an earlier review's copy is replaced)."""
    from mlnseq.sources import lerobot_writer

    if env != "lerobot":
        raise BadInput(f"--save-lerobot writes LeRobot datasets, but --source {source} is read as --env {env}")
    try:
        lerobot_writer.check_target(source, Path(options.save_lerobot), True, {"--save": save,
                                                                              "the model": options.model})
    except BadInput as error:
        raise BadInput(str(error).replace("--write-lerobot", "--save-lerobot")) from None


def run(options: ReviewOptions, started: Callable[[Started], None] | None = None) -> str:
    """Serve the review until SIGINT or SIGTERM; ``started`` is told where first. Returns the signal's name."""
    site, server = prepare(options)
    if started is not None:
        started(Started(server.url(options.host), len(site.recordings),
                        sum(len(r.decided.time) for r in site.recordings), site.labels.path))
    return serve(server)
