"""Recordings as frames: a user's CSV/Parquet tables, and the one assembly every recording source goes through.

A source (this module's table reader, or one in ``mlnseq.sources``) turns its files into ``Recording``s:
per file its features and, per row, the user's episode id, time and label. ``collect_frames`` (for
``collect``) and ``prediction_frames`` (for ``predict``) check and assemble them into frames.parquet's
schema with one core: time rising within an episode, labels to class indices, the split, the metadata.

A table's columns named by the options are keys (label, episode, time); every other numeric column is a
feature unless ``features`` lists them. A folder holds one episode per file, in name order.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.parts import Part
from mlnseq.sources.recording import Labels, Recording, TableColumns, given
from mlnseq.sources.splits import Holdout, split_of

TABLE_SUFFIXES = (".csv", ".parquet")
MAX_CLASSES = int(np.iinfo(np.int16).max) + 1  # frames.parquet keeps a label as Int16: 0 .. 32,767
FLOAT32_MAX = float(np.finfo(np.float32).max)  # features are stored as float32: a larger value would be inf


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


def _check_utf8(path: Path) -> None:
    """polars replaces bytes that are not UTF-8 without a word (a Latin-1 header becomes mojibake): refuse them."""
    import codecs

    decoder, line, chunk = codecs.getincrementaldecoder("utf-8")(), 1, b""
    try:
        with open(path, "rb") as handle:
            while chunk := handle.read(1 << 20):
                decoder.decode(chunk)
                line += chunk.count(b"\n")
            decoder.decode(b"", final=True)
    except UnicodeDecodeError as error:
        line += error.object[:error.start].count(b"\n")
        raise BadInput(f"{path}:{line}: not UTF-8 text (byte {error.object[error.start]:#x}); save the file as "
                       "UTF-8, e.g. iconv -f latin1 -t utf-8") from None
    except OSError:
        return  # unreadable: read_one names the problem


def read_one(path: Path) -> pl.DataFrame:
    if path.suffix.lower() == ".csv":
        _check_utf8(path)
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


def check_features(features: pl.DataFrame, path: Path, where: str = "{file} row {row}",
                   rows: pl.Series | None = None) -> pl.DataFrame:
    """Every feature numeric and finite within float32's range, else the first bad row and column named."""
    def error(name: str, mask: pl.Series, what: str) -> BadInput:
        index = int(np.flatnonzero(mask.to_numpy())[0])
        row = int(rows[index]) if rows is not None else index
        return BadInput(f"{where.format(file=path, row=row)}: column {name!r} {what}")

    checked = {}
    for name in features.columns:
        column = features[name]
        if column.dtype == pl.String:
            numbers = column.str.strip_chars().cast(pl.Float64, strict=False)
            bad = numbers.is_null() & column.is_not_null()
            if bad.any():
                raise error(name, bad, f"is not numeric: it holds {column.filter(bad)[0]!r} here")
            column = numbers
        elif not column.dtype.is_numeric():
            raise error(name, pl.Series([True] * features.height), f"is not numeric ({column.dtype})")
        values = column.cast(pl.Float64)
        bad = values.is_null() | ~values.is_finite()
        if bad.any():
            raise error(name, bad, "is empty, NaN or infinite")
        bad = values.abs() > FLOAT32_MAX
        if bad.any():
            raise error(name, bad, f"holds {values.filter(bad)[0]:g}, beyond the float32 range "
                                   f"(±{FLOAT32_MAX:.4g}) features are stored in")
        checked[name] = values
    return pl.DataFrame(checked)


def read(source: Path, columns: TableColumns, options: Any = None, label: Labels = Labels.REQUIRED) -> list[Recording]:
    """A user's CSV/Parquet file or folder as recordings; with ``Labels.OPTIONAL`` the label column is read from each
    file that has it."""
    files = table_files(Path(source))
    recordings = []
    for path in files:
        table = read_one(path)
        is_csv = path.suffix.lower() == ".csv"
        episode_col = columns.episode or ("episode" if "episode" in table.columns else None)
        time_col = columns.time or ("frame" if "frame" in table.columns else None)
        labelled = label in (Labels.REQUIRED, Labels.SOME) or (label is Labels.OPTIONAL
                                                               and columns.label in table.columns)
        label_col = columns.label if labelled else None
        missing = [n for n in (label_col, episode_col, time_col, *columns.features)
                   if n is not None and n not in table.columns]
        why = None
        if missing and label is Labels.SOME and missing[0] == columns.label:  # a file without labels: unlabelled
            why = f"{path}: no column {columns.label!r}; columns are {', '.join(table.columns)}"
            label_col, missing = None, missing[1:]
        if missing:
            raise BadInput(f"{path}: no column {', '.join(map(repr, missing))}; columns are {', '.join(table.columns)}"
                           + _without_hint(missing, episode_col, time_col))
        keys = {columns.label, episode_col, time_col, "split"} - {None}  # never a feature, even when absent
        names = list(columns.features) or [
            c for c in table.columns if c not in keys and table[c].dtype.is_numeric()
        ]
        if not columns.features:
            _refuse_numbers_with_typos(table, path, keys, is_csv)
        if not names:
            raise BadInput(f"{path}: no numeric feature column; name them with --features")
        where = "{file}:{row}" if is_csv else "{file} row {row}"
        rows = pl.int_range(table.height, eager=True) + (2 if is_csv else 0)
        if episode_col is None:
            episode = pl.Series([path.stem] * table.height)
        else:
            episode = table[episode_col]
            if episode.is_null().any():
                raise _row_error(path, episode.is_null(), f"episode column {episode_col!r} is empty", is_csv)
            if len(files) > 1:
                episode = pl.Series([f"{path.stem}/"] * table.height) + episode.cast(pl.String)
            elif not episode.dtype.is_integer():
                episode = episode.cast(pl.String)
        recordings.append(Recording(
            path=path, features=check_features(table.select(names), path, where, rows),
            episode=episode.alias("episode"),
            time=table[time_col] if time_col else pl.int_range(table.height, eager=True),
            label=table[label_col] if label_col else None,
            split=table["split"].cast(pl.String) if "split" in table.columns else None,
            row=rows, where=where,
            resolved={"empty_columns": [c for c in table.columns if c not in keys and c not in names
                                        and table[c].null_count() == table.height],
                      **({"unlabelled": why} if why else {})},
        ))
    return recordings


def _without_hint(missing: list[str], episode: str | None, time: str | None) -> str:
    """How to read a table without the episode or time column a model remembers (or an option named)."""
    flags = [flag for flag, name in (("--episode-column", episode), ("--time-column", time)) if name in missing]
    return f"; to read it without, pass {' '.join(f'{flag} ' + repr('') for flag in flags)}" if flags else ""


# ---- the one assembly --------------------------------------------------------------------------------------

def _splits(frames: pl.DataFrame, recordings: list[Recording], has_label: np.ndarray, episode_index: np.ndarray, at,
            holdout: Holdout) -> np.ndarray:
    """Each row's split: ``unlabelled`` without a label; ``train`` for a clicked recording without a split column
    (its labels between clicks are estimates, which a test split would score against); else ``split_of``'s."""
    by_clicks = np.concatenate([np.full(r.features.height, bool(r.resolved.get("clicks"))) for r in recordings])
    estimated = has_label & by_clicks & frames["split"].is_null().to_numpy()
    exact = has_label & ~estimated
    split = np.full(frames.height, Part.UNLABELLED.value, dtype=object)
    split[estimated] = Part.TRAIN.value
    if exact.any():
        split[exact] = split_of(frames.filter(pl.Series(exact)), episode_index[exact], at, holdout)
    return split


def collect_frames(recordings: list[Recording], classes: tuple[str, ...] = (),
                   holdout: Holdout = Holdout.SHARE) -> tuple[pl.DataFrame, dict]:
    """Frames for ``collect``: labelled recordings (two classes or more) with the split from the source or as
    ``holdout`` draws it, and recordings without labels in the split ``unlabelled`` with a null label."""
    table, meta, _ = _assemble(recordings, classes, Labels.REQUIRED, holdout)
    return table, meta


def prediction_frames(recordings: list[Recording], classes: tuple[str, ...]) -> tuple[pl.DataFrame, dict, np.ndarray]:
    """Frames for ``predict``: labels where a recording has them (label -1 where not; ``labelled``: any has), one
    class enough, every frame test; and each frame's time, row by row."""
    return _assemble(recordings, classes, Labels.OPTIONAL)


def _check_recordings(recordings: list[Recording], for_prediction: bool) -> None:
    """The same features everywhere; for collect labels on one recording at least."""
    if not recordings:
        raise BadInput("no recording to read")
    feature_names = recordings[0].features.columns
    for recording in recordings[1:]:
        if recording.features.columns != feature_names:
            raise BadInput(f"{recording.path}: feature columns {recording.features.columns} differ from "
                           f"{recordings[0].path}'s {feature_names}")
    if not for_prediction and all(r.label is None for r in recordings):
        why = recordings[0].resolved.get("unlabelled")  # the reader's own word: a missing column or topic
        if why:
            raise BadInput(why)
        how = ("name a std_msgs/String topic of phase names with --label-topic" if "rate" in recordings[0].resolved
               else "give a label column")  # a bag's reader resolves its clock
        raise BadInput(f"{recordings[0].path}: no labels; {how}, or label intervals with --labels")


def _assemble(recordings: list[Recording], classes: tuple[str, ...], labels_wanted: Labels,
              holdout: Holdout = Holdout.SHARE) -> tuple[pl.DataFrame, dict, np.ndarray]:
    """Labels.REQUIRED: frames to train on (labelled, two classes or more, the split from the source or as
    ``holdout`` draws it; recordings without labels unlabelled); Labels.OPTIONAL: frames to predict (one class
    enough, every frame test)."""
    for_prediction = labels_wanted is Labels.OPTIONAL
    _check_recordings(recordings, for_prediction)
    files = list(dict.fromkeys(str(f) for r in recordings for f in _files_of(r.path.resolve())))
    feature_names = recordings[0].features.columns
    with_labels = [r for r in recordings if r.label is not None]
    episode_ids = _common_dtype([r.episode for r in recordings])
    kind = _common_dtype([r.label for r in with_labels]).dtype if with_labels else pl.Int64
    has_label = np.concatenate([np.full(r.features.height, r.label is not None) for r in recordings])
    where = {str(r.path): r.where for r in recordings}
    frames = pl.DataFrame({
        "episode": episode_ids,
        "time": pl.concat([r.time.cast(pl.Float64) for r in recordings]),
        "label": (pl.concat([r.label.cast(kind) if r.label is not None else pl.Series([None] * r.features.height,
                                                                                      dtype=kind)
                             for r in recordings]) if with_labels else pl.Series([-1] * len(episode_ids))),
        "split": pl.concat([r.split.cast(pl.String) if r.split is not None else pl.Series([None] * r.features.height,
                                                                                          dtype=pl.String)
                            for r in recordings]),
        "file": pl.concat([pl.Series([str(r.path)] * r.features.height, dtype=pl.String) for r in recordings]),
        "row": pl.concat([(r.row if r.row is not None else pl.int_range(r.features.height, eager=True)).cast(pl.Int64)
                          for r in recordings]),
    })
    at = lambda row: where[row["file"]].format(file=row["file"], row=row["row"])  # noqa: E731
    _check_time(frames, at)
    indices, names = np.full(frames.height, -1, dtype=np.int16), list(classes)
    if with_labels:
        indices[has_label], names = _label_indices(frames.filter(pl.Series(has_label)), classes, at,
                                                   min_classes=1 if for_prediction else 2)
    ids = frames["episode"].unique(maintain_order=True)
    episode_index = frames["episode"].replace_strict(ids, pl.int_range(len(ids), eager=True),
                                                     return_dtype=pl.Int32).to_numpy()
    within = frames.with_columns(frame=pl.int_range(pl.len()).over("episode"))["frame"].to_numpy()
    split = np.full(frames.height, "test", dtype=object)
    if not for_prediction:
        split = _splits(frames, recordings, has_label, episode_index, at, holdout)
    features = pl.concat([r.features for r in recordings], how="vertical_relaxed")
    keys = {"episode": episode_index, "frame": within, "label": indices, "split": split.astype(str)}
    table = artifacts.frames_table(keys, {n: features[n].cast(pl.Float64).to_numpy() for n in feature_names})
    if not has_label.all() and not for_prediction:
        table = table.with_columns(label=pl.when(pl.Series(has_label)).then(pl.col("label")))
    order = np.lexsort((within, episode_index))
    table = table[order]
    meta = {"source": "table", "source_files": files, "classes": names, "features": list(feature_names),
            "labelled": bool(with_labels), "episode_names": ids.to_list()}
    unlabelled = ids.filter(ids.is_in(frames["episode"].filter(pl.Series(~has_label)).implode())).to_list()
    if unlabelled and not for_prediction:
        meta["unlabelled_episodes"] = unlabelled
    if not for_prediction:
        meta.update(given(recordings, table, order, ids.to_list()))
    return table, meta, frames["time"].to_numpy()[order]


def _files_of(path: Path) -> list[Path]:
    """The files a recording was read from: itself, or a bag folder's files."""
    return sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]


def _common_dtype(series: list[pl.Series]) -> pl.Series:
    """One series of them all: integers stay integers, anything else becomes text."""
    if all(s.dtype.is_integer() for s in series):
        return pl.concat([s.cast(pl.Int64) for s in series])
    if all(s.dtype.is_numeric() for s in series):
        return pl.concat([s.cast(pl.Float64) for s in series])
    return pl.concat([s.cast(pl.String) for s in series])


def _check_time(frames: pl.DataFrame, at) -> None:
    """Time must rise strictly within each episode, in file order."""
    if frames["time"].is_null().any() or not frames["time"].is_finite().all():
        bad = frames["time"].is_null() | ~frames["time"].is_finite().fill_null(False)
        first = frames.filter(bad).row(0, named=True)
        raise BadInput(f"{at(first)}: time is empty, NaN or infinite")
    step = frames.select(pl.col("time").diff().over("episode").alias("step"), "file", "row")
    bad = step.filter(pl.col("step").is_not_null() & (pl.col("step") <= 0))
    if bad.height:
        first = bad.row(0, named=True)
        what = "repeats the previous frame index" if first["step"] == 0 else "goes back in time"
        raise BadInput(f"{at(first)}: time {what}; each episode's frames must rise strictly")


def _check_class_count(frames: pl.DataFrame, values: np.ndarray, at) -> None:
    """A numeric label is a class index: refuse one past the classes mlnseq stores before naming them all."""
    bad = np.flatnonzero(values >= MAX_CLASSES)
    if bad.size:
        row = frames.row(int(bad[0]), named=True)
        raise BadInput(f"{at(row)}: label {row['label']} is not a class index below {MAX_CLASSES:,}, the most "
                       "classes mlnseq stores (labels are 16-bit); give the classes as text, or renumber them")


def _label_indices(frames: pl.DataFrame, classes: tuple[str, ...], at,
                   min_classes: int = 2) -> tuple[np.ndarray, list[str]]:
    labels = frames["label"]
    if labels.is_null().any():
        first = frames.filter(labels.is_null()).row(0, named=True)
        raise BadInput(f"{at(first)}: empty label")
    if labels.dtype.is_numeric():
        values = labels.cast(pl.Float64).to_numpy()
        if not np.all(values == np.round(values)) or values.min() < 0:
            bad = frames.row(int(np.flatnonzero((values != np.round(values)) | (values < 0))[0]), named=True)
            raise BadInput(f"{at(bad)}: label {bad['label']:g} is not a class index 0, 1, ...")
        _check_class_count(frames, values, at)
        indices = values.astype(np.int64)
        names = list(classes) or [str(k) for k in range(int(indices.max()) + 1)]
        if indices.max() >= len(names):
            bad = frames.row(int(np.flatnonzero(indices >= len(names))[0]), named=True)
            raise BadInput(f"{at(bad)}: label {bad['label']:g} is outside the {len(names)} classes of --classes")
    else:
        text = labels.cast(pl.String).to_list()
        names = list(classes) or sorted(set(text))
        if len(names) > MAX_CLASSES:
            raise BadInput(f"{at(frames.row(0, named=True))}: the labels hold {len(names):,} classes; mlnseq stores "
                           f"at most {MAX_CLASSES:,} (labels are 16-bit class indices)")
        lookup = {name: i for i, name in enumerate(names)}
        unknown = [i for i, t in enumerate(text) if t not in lookup]
        if unknown:
            bad = frames.row(unknown[0], named=True)
            raise BadInput(f"{at(bad)}: label {bad['label']!r} is not one of --classes ({', '.join(names)})")
        indices = np.array([lookup[t] for t in text], dtype=np.int64)
    if len(set(indices.tolist())) < min_classes:
        raise BadInput(f"the labels hold a single class ({names[int(indices[0])]!r}); mlnseq needs two or more")
    return indices.astype(np.int16), names
