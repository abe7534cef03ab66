"""Import a user's own recordings (CSV or Parquet, one file or a folder of them) as frames.

Columns named by the options are keys (label, episode, time); every other numeric column is a feature
unless ``features`` lists them. A folder holds one episode per file, in name order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import csv

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from stages import artifacts
from stages.errors import BadInput

TABLE_SUFFIXES = (".csv", ".parquet")
DEFAULT_TRAIN_SHARE = 0.7
FLOAT32_MAX = float(np.finfo(np.float32).max)  # features are stored as float32: a larger value would be inf


@dataclass(frozen=True)
class TableColumns:
    """Which columns of the user's table are keys and which are features."""

    label: str = "label"
    episode: str | None = None  # default: a column named "episode" if present, else one episode per file
    time: str | None = None  # default: a column named "frame" if present, else file order
    features: tuple[str, ...] = ()  # default: every other numeric column
    classes: tuple[str, ...] = ()  # class names in label order; default: from the labels


def table_files(source: Path) -> list[Path]:
    """The files to import: ``source`` itself, or the CSV/Parquet files of a folder in name order."""
    if source.is_dir():
        files = sorted(p for p in source.iterdir() if p.suffix.lower() in TABLE_SUFFIXES)
        if not files:
            raise BadInput(f"--source {source} holds no .csv or .parquet file")
        return files
    if not source.exists():
        raise BadInput(f"--source {source} not found")
    if source.suffix.lower() not in TABLE_SUFFIXES:
        raise BadInput(f"--source {source}: expected a .csv or .parquet file, or a folder of them")
    return [source]


def column_names(path: Path) -> list[str]:
    """The header as written: polars would rename a repeated name (``x_duplicated_0``) or refuse it."""
    try:
        if path.suffix.lower() == ".csv":
            with open(path, newline="", encoding="utf-8") as handle:
                return next(csv.reader(handle), [])
        return pq.read_schema(path).names
    except (OSError, UnicodeDecodeError, csv.Error, pa.ArrowException):
        return []  # unreadable: read_one names the problem


def read_one(path: Path) -> pl.DataFrame:
    names = column_names(path)
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise BadInput(f"{path}: column {repeated[0]!r} appears more than once in the header; "
                       "give every column its own name")
    try:
        if path.suffix.lower() == ".csv":
            table = pl.read_csv(path, infer_schema_length=10_000)
        else:
            table = pl.read_parquet(path)
    except Exception as error:  # polars raises many types for unreadable files
        first_line = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise BadInput(f"{path}: cannot read it as {path.suffix[1:]} ({first_line})") from error
    if table.height == 0:
        raise BadInput(f"{path} has no rows")
    return table


def _row_error(path: Path, mask: pl.Series, what: str, csv_header: bool) -> BadInput:
    row = int(np.flatnonzero(mask.to_numpy())[0])
    where = f"{path}:{row + 2}" if csv_header else f"{path} row {row}"
    return BadInput(f"{where}: {what}")


def _refuse_numbers_with_typos(table: pl.DataFrame, path: Path, keys: set[str], csv_header: bool) -> None:
    """A text column whose values are mostly numbers is a feature with a bad cell, not a column to drop."""
    for name in table.columns:
        if name in keys or table[name].dtype != pl.String:
            continue
        text = table[name].str.strip_chars()
        numbers = text.cast(pl.Float64, strict=False)
        bad = numbers.is_null() | ~numbers.is_finite()
        if bad.any() and bad.sum() * 2 < table.height:
            value = table[name].filter(bad)[0]
            raise _row_error(path, bad, f"column {name!r} is numeric but holds {value!r} here; repair the value, "
                                        "or name the feature columns with --features", csv_header)


def import_table(source: Path, columns: TableColumns, for_prediction: bool = False) -> tuple[pl.DataFrame, dict]:
    """Read, check and assemble the frames and their metadata.

    ``for_prediction`` (new recordings for a trained model): the label column is optional (absent: every
    label is -1 and the metadata says ``labelled: false``), one class is enough, and every frame is test.
    """
    files = table_files(Path(source))
    labelled = True
    parts = []
    feature_names: list[str] | None = None
    for file_number, path in enumerate(files):
        table = read_one(path)
        is_csv = path.suffix.lower() == ".csv"
        episode_col = columns.episode or ("episode" if "episode" in table.columns else None)
        time_col = columns.time or ("frame" if "frame" in table.columns else None)
        if for_prediction and file_number == 0:
            labelled = columns.label in table.columns
        label_col = columns.label if labelled else None
        missing = [n for n in (label_col, episode_col, time_col, *columns.features)
                   if n is not None and n not in table.columns]
        if missing:
            raise BadInput(f"{path}: no column {', '.join(map(repr, missing))}; columns are {', '.join(table.columns)}")
        keys = {columns.label, episode_col, time_col, "split"} - {None}  # never a feature, even when absent
        names = list(columns.features) or [
            c for c in table.columns if c not in keys and table[c].dtype.is_numeric()
        ]
        if not columns.features:
            _refuse_numbers_with_typos(table, path, keys, is_csv)
        if not names:
            raise BadInput(f"{path}: no numeric feature column; name them with --features")
        if feature_names is None:
            feature_names = names
        elif names != feature_names:
            raise BadInput(f"{path}: feature columns {names} differ from {files[0]}'s {feature_names}")
        for name in names:
            if not table[name].dtype.is_numeric():
                raise BadInput(f"{path}: feature column {name!r} is not numeric ({table[name].dtype})")
            values = table[name].cast(pl.Float64)
            bad = values.is_null() | ~values.is_finite()
            if bad.any():
                raise _row_error(path, bad, f"column {name!r} is empty, NaN or infinite", is_csv)
            bad = values.abs() > FLOAT32_MAX
            if bad.any():
                raise _row_error(path, bad, f"column {name!r} holds {values.filter(bad)[0]:g}, beyond the "
                                            f"float32 range (±{FLOAT32_MAX:.4g}) features are stored in", is_csv)
        episode = (
            table[episode_col] if episode_col else pl.Series([file_number] * table.height)
        ).alias("episode")
        if episode.dtype.is_numeric() and episode.is_null().any():
            raise _row_error(path, episode.is_null(), "episode is empty", is_csv)
        part = table.select(names).with_columns(
            episode=episode.cast(pl.String) if len(files) == 1 else pl.lit(f"{file_number}:") + episode.cast(pl.String),
            label=table[label_col] if label_col else pl.lit(-1),
            time=table[time_col] if time_col else pl.int_range(pl.len()),
            split=table["split"].cast(pl.String) if "split" in table.columns else pl.lit(None, pl.String),
            file=pl.lit(str(path)),
            row=pl.int_range(pl.len()) + (2 if is_csv else 0),
        )
        parts.append(part)
    frames = pl.concat(parts, how="vertical_relaxed")
    _check_time(frames)
    if labelled:
        labels, classes = _label_indices(frames, columns.classes, min_classes=1 if for_prediction else 2)
    else:
        labels, classes = np.full(frames.height, -1, dtype=np.int16), list(columns.classes)
    names = list(dict.fromkeys(frames["episode"].to_list()))
    order = {name: i for i, name in enumerate(names)}
    episode_index = np.array([order[e] for e in frames["episode"].to_list()], dtype=np.int32)
    within = frames.with_columns(frame=pl.int_range(pl.len()).over("episode"))["frame"].to_numpy()
    split = np.full(frames.height, "test") if for_prediction else _split(frames, episode_index)
    keys = {"episode": episode_index, "frame": within, "label": labels, "split": split}
    table = artifacts.frames_table(keys, {n: frames[n].cast(pl.Float64).to_numpy() for n in feature_names})
    table = table.sort(["episode", "frame"], maintain_order=True)
    meta = {"source": "table", "source_files": [str(p.resolve()) for p in files],
            "classes": classes, "features": list(feature_names), "labelled": labelled, "episode_names": names}
    return table, meta


def _split(frames: pl.DataFrame, episode_index: np.ndarray) -> np.ndarray:
    """A ``split`` column of the source if it has one, else the first 70 % of episodes train.

    With a single episode, the first 70 % of its frames train.
    """
    given = frames["split"]
    if given.is_null().any() and given.is_not_null().any():
        first = frames.filter(given.is_null()).row(0, named=True)
        raise BadInput(f"{first['file']}:{first['row']}: empty split; give every row train or test, or drop the column")
    if given.is_not_null().all():
        bad = ~given.is_in(list(artifacts.SPLITS))
        if bad.any():
            first = frames.filter(bad).row(0, named=True)
            raise BadInput(f"{first['file']}:{first['row']}: split {first['split']!r} is neither train nor test")
        return given.to_numpy()
    n_episodes = int(episode_index.max()) + 1
    if n_episodes == 1:
        position = np.arange(len(episode_index)) < round(DEFAULT_TRAIN_SHARE * len(episode_index))
    else:
        position = episode_index < max(1, round(DEFAULT_TRAIN_SHARE * n_episodes))
    return np.where(position, "train", "test")


def _check_time(frames: pl.DataFrame) -> None:
    """Time must rise strictly within each episode, in file order."""
    step = frames.select(
        pl.col("time").diff().over("episode").alias("step"), "file", "row"
    )
    bad = step.filter(pl.col("step").is_not_null() & (pl.col("step") <= 0))
    if bad.height:
        first = bad.row(0, named=True)
        what = "repeats the previous frame index" if first["step"] == 0 else "goes back in time"
        raise BadInput(f"{first['file']}:{first['row']}: time {what}; each episode's frames must rise strictly")


def _label_indices(frames: pl.DataFrame, classes: tuple[str, ...], min_classes: int = 2) -> tuple[np.ndarray, list[str]]:
    labels = frames["label"]
    if labels.is_null().any():
        first = frames.filter(labels.is_null()).row(0, named=True)
        raise BadInput(f"{first['file']}:{first['row']}: empty label")
    if labels.dtype.is_numeric():
        values = labels.cast(pl.Float64).to_numpy()
        if not np.all(values == np.round(values)) or values.min() < 0:
            bad = frames.row(int(np.flatnonzero((values != np.round(values)) | (values < 0))[0]), named=True)
            raise BadInput(f"{bad['file']}:{bad['row']}: label {bad['label']} is not a class index 0, 1, ...")
        indices = values.astype(np.int64)
        names = list(classes) or [str(k) for k in range(int(indices.max()) + 1)]
        if indices.max() >= len(names):
            bad = frames.row(int(np.flatnonzero(indices >= len(names))[0]), named=True)
            raise BadInput(
                f"{bad['file']}:{bad['row']}: label {bad['label']} is outside the {len(names)} classes of --classes"
            )
    else:
        text = labels.cast(pl.String).to_list()
        names = list(classes) or sorted(set(text))
        lookup = {name: i for i, name in enumerate(names)}
        unknown = [i for i, t in enumerate(text) if t not in lookup]
        if unknown:
            bad = frames.row(unknown[0], named=True)
            raise BadInput(f"{bad['file']}:{bad['row']}: label {bad['label']!r} is not one of --classes")
        indices = np.array([lookup[t] for t in text], dtype=np.int64)
    if len(set(indices.tolist())) < min_classes:
        raise BadInput(f"the labels hold a single class ({names[int(indices[0])]!r}); mlnseq needs two or more")
    return indices.astype(np.int16), names
