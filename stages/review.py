"""review: a model's phases over the robot's signals in the browser; any moment explained; corrections saved as labels.

The recordings are read as `predict` reads them (as the model's own were read; or, with a fit's workdir, the
recordings it was fitted on, as fit read them, its labels file too) and each is decided as `explain` decides it, so
a click on a frame shows exactly the terms `mlnseq explain --json` prints for it; a fit's workdir also gives each
recording's labels as fit trained on them and the phases fit proposes to correct (stages/reviewing/fitted.py,
stages/reviewing/decisions.py). The
page (stages/reviewing/page/, its site stages/reviewing/site.py) is served on 127.0.0.1 by a guarded
standard-library server (stages/serving/guarded.py); a save writes the recording's labels into the one labels file
given at the start (stages/reviewing/corrections.py), in the form `collect --labels` reads.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from mlnseq.catalog.errors import BadInput
from mlnseq.recognition import reading
from mlnseq.recognition.reading import ReadOptions
from mlnseq.reviewing import corrections, decisions, fitted
from mlnseq.reviewing.site import Review
from mlnseq.serving.guarded import BODY_LIMIT, GuardedServer, reachable_from, serve
from mlnseq.sources import intervals


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


@dataclass(frozen=True)
class Started:
    """What `run` tells before it serves: where, and what it read."""

    url: str
    recordings: int
    frames: int
    save: Path
    reached_from: str | None = None  # who else can open the page (--host other than this machine's own): None


def prepare(options: ReviewOptions, said: Callable[[str], None] = lambda line: None) -> tuple[Review, GuardedServer]:
    """Read the model and the recordings, decide them, check the labels file and open the port (nothing served
    yet): every refusal comes here, before the address is printed. ``said`` hears each save."""
    options.validate()
    workdir = fitted.read(options.workdir) if options.workdir is not None else None
    source = Path(options.source) if options.source is not None else workdir.source
    read_as = options.reading
    if workdir is not None and source.resolve() == workdir.source.resolve():  # fit's own: read as fit read them
        read_as = replace(read_as, overrides=workdir.reading(read_as.overrides))
    save = options.save_path()
    given = read_as.overrides.get("labels")
    corrections.check_path(save, source, [Path(options.model), *([Path(given)] if given is not None else [])])
    read = reading.read(options.model, source, read_as)
    if options.save_lerobot is not None:
        _check_lerobot(options, read.env, source, save)
    for path in read.meta["source_files"]:
        corrections.check_path(save, Path(path), [])
    carried = None
    if workdir is not None and workdir.labels_file is not None and given == workdir.labels_file:
        carried = intervals.read(workdir.labels_file, workdir.labels_unit)  # the fit's labels, kept in each save
    labels = corrections.LabelsFile(save, read.source.unit(read.env), carried)
    decided = decisions.decide(read, workdir, decisions.audited(read, Path(options.model)))
    for recording in decided:  # a labels file that does not fit the recordings is refused now, not at a click
        labels.saved(recording.decided.id, recording.decided.time, list(read.model.classes))
    lerobot = None if options.save_lerobot is None else (source, Path(options.save_lerobot))
    site = Review(read.model, decided, labels, workdir.ranks if workdir else {}, read.decode, lerobot, said)
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


def run(options: ReviewOptions, started: Callable[[Started], None] | None = None,
        said: Callable[[str], None] = lambda line: None) -> str:
    """Serve the review until SIGINT or SIGTERM; ``started`` is told where first, ``said`` each save. Returns the
    signal's name."""
    site, server = prepare(options, said)
    if started is not None:
        started(Started(server.url(options.host), len(site.recordings),
                        sum(len(r.decided.time) for r in site.recordings), site.labels.path,
                        reachable_from(options.host)))
    return serve(server)
