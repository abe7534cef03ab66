"""The workdir's file names, the Parquet schemas, self-describing metadata and atomic write/read.

Every stage reads its inputs from and writes its outputs to one workdir, by the fixed names below. Each Parquet
artifact carries a JSON metadata entry (key ``mlnseq``): the schema version, the options used, the class and feature
names, and a digest of every input, so a reader refuses an unknown version and names the stage to rerun when an
input changed since.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import json
import os
import re
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from mlnseq.catalog.errors import BadInput, MissingArtifact, StaleArtifact
from mlnseq.catalog.parts import Part, label_mismatch, labelled  # noqa: F401 (labelled: the stages read it here)

SCHEMA_VERSION = 1
META_KEY = b"mlnseq"
DEFAULT_WORKDIR = Path("mlnseq-work")

FRAMES = "frames.parquet"
PREDICATES = "predicates.parquet"
FOLD_PREDICATES = "predicates.folds.parquet"  # learned predicates learned again without each fold (column fold)
FORMULAS = "formulas.mln"
WEIGHTS = "weights.parquet"
FOLD_WEIGHTS = "weights.folds.parquet"  # each fold's MLN weights, learned without that fold (column fold)
LEARNED_MLN = "learned.mln"
LEARNED_SPEC = "learned.binarize.toml"  # the predicates binarize --suggest (and fit) learn, their formulas beside it
MODELS_DIR = "models"
PREDICTIONS = "predictions.parquet"
METRICS = "metrics.parquet"
LABEL_NEXT = "label_next.csv"  # the unlabelled recordings ranked by what labelling each would teach (fit)
UNLABELLED_INTERVALS = "unlabelled.intervals.csv"  # their predicted phases, predict --intervals' form (fit)

# Which stage writes each artifact, so a missing or stale one names the command to run.
PRODUCED_BY = {
    FRAMES: "collect",
    PREDICATES: "binarize",
    FOLD_PREDICATES: "binarize --suggest",
    FORMULAS: "formulas",
    WEIGHTS: "learn-weights",
    FOLD_WEIGHTS: "learn-weights --folds K",
    LEARNED_MLN: "learn-weights",
    MODELS_DIR: "train",
    PREDICTIONS: "conflate",
    METRICS: "eval",
}

KEY_SCHEMA: dict[str, pl.DataType] = {"episode": pl.Int32(), "frame": pl.Int32(), "label": pl.Int16(),
                                      "split": pl.String()}
KEY_COLUMNS = tuple(KEY_SCHEMA)
SPLITS = ("train", "test")


def checkpoint_path(workdir: Path, method: str) -> Path:
    """The model checkpoint of one training method (lstm, priorlayer)."""
    return workdir / MODELS_DIR / f"{method}.pt"


def train_log_path(workdir: Path, method: str) -> Path:
    """The per-epoch training log (epoch, split, accuracy, loss) of one training method."""
    return workdir / MODELS_DIR / f"{method}.log.parquet"


def out_of_fold_path(workdir: Path, method: str) -> Path:
    """A network's out-of-fold class log-probabilities of every training frame (episode, frame, fold, lp0..):
    each fold's rows predicted by the fold network trained without it."""
    return workdir / MODELS_DIR / f"{method}.oof.parquet"


def log_probs_cache_path(checkpoint: Path) -> Path:
    """Where a checkpoint's class log-probabilities over its workdir's frames are cached: beside the file it links to
    (mlnseq.model.log_prob_cache), so every workdir linking it shares them."""
    real = Path(checkpoint).resolve()
    return real.with_name(f"{real.stem}.log-probs.npy")


def log_prob_columns(n_classes: int) -> list[str]:
    """The out-of-fold artifact's class log-probability columns."""
    return [f"lp{k}" for k in range(n_classes)]


def prob_columns(method: str, n_classes: int) -> list[str]:
    """predictions.parquet: a method's class probabilities, one column per class."""
    return [f"{method}_p{k}" for k in range(n_classes)]


def pred_column(method: str) -> str:
    """predictions.parquet: a method's predicted class index."""
    return f"{method}_pred"


def class_probability_column(class_name: str) -> str:
    """A `predict` output table: the probability of one class, by its name."""
    return f"p_{class_name}"


# weights.parquet: one row per expanded formula (class: the head's class, None for a formula without one;
# hard: no weight, a constraint; template: the index of the formula it was expanded from)
WEIGHTS_SCHEMA: dict[str, pl.DataType] = {
    "formula": pl.String(), "class": pl.String(), "weight": pl.Float64(), "fixed": pl.Boolean(),
    "hard": pl.Boolean(), "template": pl.Int32(), "temporal": pl.Boolean(),
}
# metrics.parquet: one row per (method, metric, item); item names the class, fraction or confusion cell
METRICS_SCHEMA: dict[str, pl.DataType] = {"method": pl.String(), "metric": pl.String(), "item": pl.String(),
                                          "value": pl.Float64()}


def producer_of(path: Path) -> str:
    """The stage command that writes this artifact."""
    return PRODUCED_BY.get(MODELS_DIR if path.parent.name == MODELS_DIR else path.name, "the stage that writes it")


def package_version() -> str:
    try:
        return importlib_metadata.version("mlnseq")
    except importlib_metadata.PackageNotFoundError:
        return "0+unknown"


_DIGESTS: dict[tuple[int, int, int, int], str] = {}  # file identity -> digest, kept for the process


def file_digest(path: Path) -> str:
    """Content digest of a file (sha256, first 16 hex digits). A process reads a file once while it stays the same
    file (device, inode, size and modification time): the report checks the same inputs of hundreds of artifacts."""
    status = os.stat(path)
    identity = (status.st_dev, status.st_ino, status.st_size, status.st_mtime_ns)
    if identity not in _DIGESTS:
        digest = hashlib.sha256()
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
        _DIGESTS[identity] = digest.hexdigest()[:16]
    return _DIGESTS[identity]


def _input_key(artifact: Path, source: Path) -> str:
    """An input's name as recorded: relative to the artifact's folder when inside it or its workdir
    (``../frames.parquet`` from ``models/``), so a moved or copied workdir still checks its inputs."""
    folder, source = artifact.parent.resolve(), source.resolve()
    workdir = folder.parent if folder.name == MODELS_DIR else folder
    if source.is_relative_to(workdir):
        return os.path.relpath(source, folder)
    return str(source)


def umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def writer_running(pid: int) -> bool:
    if os.name != "posix":  # no harmless probe of another process here: assume it still writes
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process
        return True
    return True


def remove_leftovers(path: Path) -> list[Path]:
    """Delete the hidden temporary files (``.NAME.PID.*.tmp``) that writes of ``path`` by processes no longer
    running (killed mid-write) left beside it; a write still in progress keeps its own. Returns the deleted."""
    leftover = re.compile(rf"\.+{re.escape(path.name)}\.(?:(\d+)\.)?.*\.tmp\Z")
    removed = []
    for candidate in path.parent.glob(".*.tmp"):
        found = leftover.match(candidate.name)
        if found and not (found.group(1) and writer_running(int(found.group(1)))):
            candidate.unlink(missing_ok=True)
            removed.append(candidate)
    return removed


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it over ``path`` only if the block succeeds.

    The temporary file's name holds the writer's process id; the leftovers of earlier writers that were
    killed are removed first."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_leftovers(path)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp", dir=path.parent)
    except OSError as error:
        raise BadInput(f"cannot write {path}: {error.strerror or error}; choose a writable --workdir") from error
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~umask())  # mkstemp makes 0600; an artifact gets the mode open() would give it
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as error:
        raise BadInput(f"cannot write {path}: {error.strerror or error}; choose a writable --workdir") from error
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: Path, text: str) -> Path:
    """Write a text artifact atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def created_time() -> str:
    """Now in UTC, or ``SOURCE_DATE_EPOCH`` when set (reproducible builds: byte-identical artifacts)."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    try:
        now = dt.datetime.fromtimestamp(int(epoch), dt.timezone.utc) if epoch else dt.datetime.now(dt.timezone.utc)
    except (ValueError, OverflowError, OSError):
        raise BadInput(f"SOURCE_DATE_EPOCH={epoch!r} is not a whole number of seconds since 1970") from None
    return now.isoformat(timespec="seconds")


ENVELOPE = ("schema_version", "kind", "mlnseq_version", "created", "inputs")  # what build_metadata adds to each


def own_metadata(meta: dict[str, Any]) -> dict[str, Any]:
    """An artifact's metadata without the envelope ``build_metadata`` adds: what a copy written anew keeps."""
    return {k: v for k, v in meta.items() if k not in ENVELOPE}


def build_metadata(path: Path, kind: str, meta: dict[str, Any], inputs: Iterable[Path] = ()) -> dict[str, Any]:
    """The metadata entry every artifact carries: version, kind, creation time, input digests, then ``meta``."""
    return {
        "schema_version": SCHEMA_VERSION,
        "kind": kind,
        "mlnseq_version": package_version(),
        "created": created_time(),
        "inputs": {_input_key(path, Path(p)): file_digest(Path(p)) for p in inputs},
        **meta,
    }


def write_table(
    frame: pl.DataFrame, path: Path, kind: str, meta: dict[str, Any], inputs: Iterable[Path] = ()
) -> Path:
    """Write a Parquet artifact atomically with its metadata (see module docstring)."""
    path = Path(path)
    full_meta = build_metadata(path, kind, meta, inputs)
    table = frame.to_arrow()
    table = table.replace_schema_metadata({META_KEY: json.dumps(full_meta, sort_keys=True).encode()})
    # floats (class probabilities) rarely repeat: dictionary-encoding them costs more time and bytes than it saves
    encoded = [field.name for field in table.schema if not pa.types.is_floating(field.type)]
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp, compression="zstd", use_dictionary=encoded)
    return path


def read_metadata(path: Path, kind: str | None = None) -> dict[str, Any]:
    """Read and check an artifact's metadata without loading its rows."""
    path = Path(path)
    _require(path)
    try:
        schema = pq.read_schema(path)
    except (OSError, pa.ArrowException) as error:
        raise BadInput(f"{path} is not a readable Parquet file ({error}); "
                       f"rerun `mlnseq {producer_of(path)}`") from error
    raw = (schema.metadata or {}).get(META_KEY)
    if raw is None:
        raise BadInput(f"{path} has no mlnseq metadata; rerun `mlnseq {producer_of(path)}` to make it")
    meta = json.loads(raw)
    version = meta.get("schema_version")
    if version != SCHEMA_VERSION:
        raise BadInput(
            f"{path} has schema version {version}, this mlnseq reads {SCHEMA_VERSION}; "
            f"rerun `mlnseq {producer_of(path)}`"
        )
    if kind is not None and meta.get("kind") != kind:
        raise BadInput(f"{path} holds {meta.get('kind')!r}, expected {kind!r}")
    check_fresh(path, meta)
    return meta


def read_table(path: Path, kind: str | None = None) -> tuple[pl.DataFrame, dict[str, Any]]:
    """Read a Parquet artifact and its metadata; missing, foreign, old or stale files are a clear error."""
    meta = read_metadata(path, kind)
    frame = read_rows(path)
    if kind == "frames":
        check_frames(frame, meta, path)
    return frame, meta


def read_rows(path: Path, columns: Sequence[str] | None = None) -> pl.DataFrame:
    """An artifact's rows (``columns``: only those), its metadata already read and checked (:func:`read_metadata`)."""
    try:
        return pl.read_parquet(path, columns=None if columns is None else list(columns))
    except Exception as error:  # polars raises several exception types for corrupt files
        raise BadInput(f"{path} is not a readable Parquet file ({error}); "
                       f"rerun `mlnseq {producer_of(path)}`") from error


def check_fresh(path: Path, meta: dict[str, Any]) -> None:
    """Refuse an artifact whose recorded inputs have changed since it was written."""
    for name, digest in meta.get("inputs", {}).items():
        source = Path(name) if Path(name).is_absolute() else path.parent / name
        try:
            changed = source.exists() and file_digest(source) != digest
        except OSError as error:
            raise BadInput(f"cannot read {source}, an input of {path}: {error.strerror or error}") from error
        if changed:
            from mlnseq.catalog.rerun import command

            remake = command(producer_of(path).replace(" --folds K", ""), meta.get("options"))  # with its options
            raise StaleArtifact(f"{path} was made from an older {source.name}; rerun `{remake}`")


def _require(path: Path) -> None:
    if not path.exists():
        raise MissingArtifact(f"{path} not found: run `mlnseq {producer_of(path)}` first")


def feature_columns(frames: pl.DataFrame) -> list[str]:
    """Every column after the keys: the features of frames.parquet, the predicate values of predicates.parquet."""
    return [c for c in frames.columns if c not in KEY_SCHEMA]


def frames_table(keys: dict[str, Any], features: dict[str, Any]) -> pl.DataFrame:
    """Assemble a frames.parquet table in its schema: keys first, then float32 features in order."""
    columns = {name: pl.Series(name, keys[name], dtype=dtype) for name, dtype in KEY_SCHEMA.items()}
    columns.update({name: pl.Series(name, values, dtype=pl.Float32) for name, values in features.items()})
    return pl.DataFrame(columns)


def check_frames(frames: pl.DataFrame, meta: dict[str, Any], path: Path) -> None:
    """Refuse frames no stage can use, naming the first bad row: missing or mistyped key columns,
    non-float or non-finite features, no rows, splits other than train/test (or unlabelled: no label), labels
    outside the classes, a single class, or frames that do not rise strictly within each episode."""
    fix = f"repair it or rerun `mlnseq {producer_of(path)}`"

    def at(mask: pl.Series) -> str:
        row = int(mask.arg_true()[0])
        return f"row {row} (episode {frames['episode'][row]}, frame {frames['frame'][row]})"

    for name, dtype in KEY_SCHEMA.items():
        if name not in frames.columns:
            raise BadInput(f"{path} has no column {name!r}; {fix}")
        if frames[name].dtype != dtype:
            raise BadInput(f"{path} column {name!r} is {frames[name].dtype}, expected {dtype}; {fix}")
    features = feature_columns(frames)
    if not features:
        raise BadInput(f"{path} has no feature column after {', '.join(KEY_COLUMNS)}; {fix}")
    if "features" in meta and list(meta["features"]) != features:
        raise BadInput(f"{path} has feature columns {features}, but its metadata lists {meta['features']}; {fix}")
    for name in features:
        if not frames[name].dtype.is_float():
            raise BadInput(f"{path} feature column {name!r} is {frames[name].dtype}, expected Float32; {fix}")
    if frames.height == 0:
        raise BadInput(f"{path} holds no frames; {fix}")
    for name in KEY_COLUMNS:
        bad, what = label_mismatch(frames) if name == "label" else (frames[name].is_null(), "empty")
        if bad.any():
            raise BadInput(f"{path} column {name!r} is {what} at row {int(bad.arg_true()[0])}; {fix}")
    for name in features:
        bad = frames[name].is_null() | ~frames[name].is_finite()
        if bad.any():
            raise BadInput(f"{path} column {name!r} is empty, NaN or infinite at {at(bad)}; {fix}")
    if (bad := ~frames["split"].is_in([*SPLITS, Part.UNLABELLED])).any():
        raise BadInput(f"{path} has split {frames['split'].filter(bad)[0]!r} at {at(bad)}; "
                       f"splits are {', '.join(SPLITS)} (and {Part.UNLABELLED}); {fix}")
    classes = meta.get("classes") or []
    if classes:
        bad = (frames["label"] < 0) | (frames["label"] >= len(classes))
        if bad.any():
            raise BadInput(f"{path} has label {frames['label'].filter(bad)[0]} at {at(bad)}, outside its "
                           f"{len(classes)} classes 0..{len(classes) - 1}; {fix}")
    if (given := frames["label"].drop_nulls()).n_unique() < 2:
        raise BadInput(f"{path} holds a single class (label {given[0]}); mlnseq needs two or more")
    episode, frame = frames["episode"], frames["frame"]
    same = (episode == episode.shift(1)).fill_null(False)
    bad = same & (frame <= frame.shift(1)).fill_null(False)
    if bad.any():
        row = int(bad.arg_true()[0])
        what = "repeats the previous frame index" if frame[row] == frame[row - 1] else "goes back in time"
        raise BadInput(f"{path} {at(bad)} {what}; frames must rise strictly within each episode; {fix}")
    starts = frames.filter(~same)["episode"]
    if starts.n_unique() != starts.len():
        repeated = starts.filter(starts.is_duplicated())[0]
        raise BadInput(f"{path} episode {repeated} is split into separate runs of rows; "
                       f"each episode's frames must be consecutive rows; {fix}")
