"""audit: which recordings went wrong. Each recording of a source (read as predict reads it: as the model's own were
read) or of a fit's workdir is decoded by the model's chain over the whole recording and scored against what the
model learned of its labelled recordings at export (its ``audit.json``: the orders of its phases, their durations,
the rules that hold throughout a phase, the chain's likelihood, and the allowances cross-validation chose; a model
exported before audit existed learns them from its workdir now). One row per recording, ranked, the most suspect
first: its verdict (ok or suspect), score and reasons in words with where they happen (stages/auditing/)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.auditing import verdicts
from mlnseq.auditing.profile import Profile, model_profile
from mlnseq.catalog import artifacts, folders
from mlnseq.catalog.errors import BadInput
from mlnseq.recognition import reading
from mlnseq.recognition.reading import ReadOptions
from mlnseq.recognition.recognizer import Recognizer

SUFFIXES = (".csv", ".parquet")


@dataclass(frozen=True)
class AuditOptions:
    """Options of `mlnseq audit`: recordings from ``source`` (read as predict reads them) or a fit's ``workdir``."""

    model: Path
    source: Path | None = None
    workdir: Path | None = None  # a fit's workdir: its recordings (without a source), the profile of an older model
    output: Path | None = None  # CSV or Parquet; default: the source's (or workdir's) name + .audit.csv, here
    force: bool = False
    reading: ReadOptions = field(default_factory=ReadOptions)  # how --source is read (None: as the model's were)
    explain: int = 0  # N > 0: each reason's N largest terms in the reasons column
    write_lerobot: Path | None = None  # a copy of the LeRobot source with the verdicts as per-episode columns

    def validate(self) -> None:
        if self.source is None and self.workdir is None:
            raise BadInput("give the recordings to audit: --source DATASET, or -w WORKDIR for a fit's recordings")
        if self.explain < 0:
            raise BadInput(f"--explain {self.explain}: give how many terms each reason shows (0: none)")
        if self.reading.decode is not None:
            raise BadInput(f"--decode {self.reading.decode}: audit decodes each whole recording by the model's chain "
                           "(Viterbi); leave --decode out")
        self.reading.validate()
        path = self.output_path()
        if path.suffix not in SUFFIXES:
            raise BadInput(f"-o {path}: write the verdicts to a .csv or a .parquet file")
        if path.exists() and not self.force:
            raise BadInput(f"{path} exists; pass --force to overwrite it, or name another file")
        if self.write_lerobot is not None:
            from mlnseq.sources import lerobot_writer

            if self.source is None:
                raise BadInput("--write-lerobot copies a LeRobot --source: give --source DATASET")
            lerobot_writer.check_target(Path(self.source), Path(self.write_lerobot), self.force,
                                        {"-o": path, "the model": self.model})

    def output_path(self) -> Path:
        if self.output is not None:
            return Path(self.output)
        return Path(f"{Path(self.source if self.source is not None else self.workdir).name}.audit.csv")


@dataclass(frozen=True)
class Verdicts:
    path: Path
    table: pl.DataFrame
    profile: Profile
    notes: tuple[str, ...] = ()
    lerobot: Path | None = None


@dataclass(frozen=True)
class Frames:
    """The recordings to audit: features in the model's order, episode index per row, their names, each row's time
    (seconds from its recording's start, or None), the files read, and the env they were read with."""

    features: np.ndarray
    episodes: np.ndarray
    names: list[Any]
    times: np.ndarray | None
    inputs: list[Path]
    env: str


def audit(model: Recognizer, profile: Profile, frames: Frames, explain: int = 0) -> pl.DataFrame:
    """The verdict rows of ``frames``, ranked (stages/auditing/verdicts.py)."""
    scores, recordings = verdicts.audited(model, profile, frames.features, frames.episodes, frames.names, frames.times)
    terms = verdicts.explained(model, scores, recordings, explain) if explain else None
    return verdicts.table(profile, recordings, terms)


def run(options: AuditOptions) -> Verdicts:
    """Read the model and the recordings, audit them, write the verdicts (and the LeRobot copy): each to a temporary
    file or folder beside it, renamed at the end, or none."""
    options.validate()
    if options.source is not None:
        read = reading.read(options.model, Path(options.source), options.reading)
        model, frames = read.model, frames_of(read)
        profile, notes = profile_of(model, options)
    else:
        model = Recognizer.load(options.model)
        profile, notes = profile_of(model, options)  # an old model's profile, from the workdir: refused first
        frames = read_workdir(model, Path(options.workdir))
    _check_outputs(options, [Path(options.model), *frames.inputs])
    if options.write_lerobot is not None and frames.env != "lerobot":
        raise BadInput(f"--write-lerobot writes LeRobot datasets, but --source {options.source} is read as "
                       f"--env {frames.env}")
    table = audit(model, profile, frames, options.explain)
    path = options.output_path()
    with contextlib.ExitStack() as staged:
        tmp = staged.enter_context(artifacts.atomic_path(path))
        if path.suffix == ".csv":
            table.write_csv(tmp)
        else:
            table.write_parquet(tmp)
        if options.write_lerobot is not None:
            from mlnseq.sources import lerobot_episodes

            folder = staged.enter_context(folders.atomic_folder(Path(options.write_lerobot)))
            lerobot_episodes.write(folder, Path(options.source), lerobot_columns(table))
    return Verdicts(path, table, profile, tuple(notes), options.write_lerobot)


def lerobot_columns(table: pl.DataFrame) -> dict[str, dict[int, Any]]:
    """The per-episode columns a LeRobot copy gets: verdict, score, the first reason and all of them."""
    import json

    episodes = [int(e) for e in table["episode"]]
    reasons = [[r["reason"] + f" ({r['where']})" for r in json.loads(text)] for text in table["reasons"]]
    return {"mlnseq_verdict": dict(zip(episodes, table["verdict"])),
            "mlnseq_score": dict(zip(episodes, table["score"])),
            "mlnseq_reason": dict(zip(episodes, table["reason"])),
            "mlnseq_reasons": dict(zip(episodes, reasons))}


def profile_of(model: Recognizer, options: AuditOptions) -> tuple[Profile, list[str]]:
    """The model's audit profile; a model exported before audit existed: learned from its workdir now (``-w``, or
    the folder the model file is in where that is the workdir it was exported from), with a note."""
    profile = model_profile(model, options.model)
    if profile is not None:
        return profile, []
    workdir = own_workdir(model, options)
    from mlnseq.auditing.calibration import calibrated

    return calibrated(workdir, model), [f"{options.model} holds no audit profile (exported before `mlnseq audit`): "
                                        f"learned from {workdir} now; `{again(model, options, workdir)}` keeps it in "
                                        "the model"]


def own_workdir(model: Recognizer, options: AuditOptions) -> Path:
    """The workdir the model was exported from: ``-w`` (checked), else the model file's folder where its frames are
    the model's; else one line saying what to rerun."""
    expected = model.manifest.inputs.get(artifacts.FRAMES)
    for workdir in ([Path(options.workdir)] if options.workdir is not None else [Path(options.model).parent]):
        frames = workdir / artifacts.FRAMES
        if frames.is_file() and expected is not None and artifacts.file_digest(frames) == expected:
            return workdir
        if options.workdir is not None:
            raise BadInput(f"{frames} is not the frames {options.model} was exported from (its digest differs): "
                           f"give the model's own workdir with -w, or export it again from {workdir}")
    raise BadInput(f"{options.model} holds no audit profile (exported before `mlnseq audit`): give its workdir with "
                   f"-w WORKDIR, or export it again: {again(model, options, Path('WORKDIR'))}")


def again(model: Recognizer, options: AuditOptions, workdir: Path) -> str:
    """The export command that writes the model again, with its audit profile."""
    decoding = model.manifest.decoding
    lag = f" --lag {decoding.lag}" if decoding.decoder.lagged else ""
    return (f"mlnseq export -w {workdir} --method {model.method} --decode {decoding.decoder.value}{lag} "
            f"-o {options.model} --force")


def frames_of(read: reading.Reading) -> Frames:
    """The recordings read as predict reads them (recognition/reading.py), as audit takes them."""
    model = read.model
    return Frames(read.frames.select(model.features).to_numpy(), read.frames["episode"].to_numpy(), list(read.names),
                  np.asarray(read.times, dtype=np.float64), read.inputs(), read.env)


def read_workdir(model: Recognizer, workdir: Path) -> Frames:
    """The recordings of a fit's workdir (frames.parquet: every episode, labelled or not), their times by its rate."""
    from mlnseq.choosing.latency import rate_of

    frames, meta = artifacts.read_table(workdir / artifacts.FRAMES, "frames")
    missing = [name for name in model.features if name not in frames.columns]
    if missing:
        raise BadInput(f"{workdir / artifacts.FRAMES} lacks the model's feature {missing[0]!r}: audit the workdir the "
                       "model was fitted in, or give --source")
    episodes = frames["episode"].to_numpy()
    names = meta.get("episode_names") or [str(e) for e in range(int(episodes.max()) + 1 if len(episodes) else 0)]
    rate = rate_of(meta)
    times = None if rate is None else frames["frame"].to_numpy().astype(np.float64) / rate
    return Frames(frames.select(model.features).to_numpy(), episodes, list(names), times,
                  [workdir / artifacts.FRAMES], "workdir")


def _check_outputs(options: AuditOptions, inputs: list[Path]) -> None:
    """Refuse an output that is one of the inputs (even with --force)."""
    path = options.output_path().resolve()
    if path in {Path(p).resolve() for p in inputs}:
        raise BadInput(f"-o {options.output_path()} is an input of this audit (the model or a recording); name "
                       "another file")
