"""LeRobot datasets read with polars alone: v2.x (``data/chunk-*/episode_*.parquet``, ``meta/episodes.jsonl``)
and v3 (``data/chunk-*/file-*.parquet``, ``meta/episodes/``), as ``meta/info.json`` describes them.

Episodes come from ``episode_index``, frames from ``frame_index``, a frame's time from ``timestamp``
(seconds). Every numeric feature of ``info.json`` is read (a vector column as one feature per element,
named ``COLUMN/NAME`` from its ``names``, else ``COLUMN/0``, ``COLUMN/1``...), or those ``--features`` names;
image and video features are skipped with a note, and language columns and columns mlnseq wrote are never
features. A column named by ``--label-column`` labels the frames, if the data has it; ``--labels subtask``
labels them from the dataset's own subtask annotations (``mlnseq.sources.lerobot_language``).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import polars as pl

from mlnseq.catalog.errors import BadInput
from mlnseq.sources import lerobot_language as language
from mlnseq.sources.table import check_features
from mlnseq.sources.recording import Labels, Recording, TableColumns

VERSIONS = ("v2.0", "v2.1", "v3.0")
KEYS = ("timestamp", "frame_index", "episode_index", "index", "task_index")
NUMERIC = ("float16", "float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "bool")


def info_of(source: Path) -> dict[str, Any]:
    path = source / "meta" / "info.json"
    if not path.is_file():
        raise BadInput(f"--source {source}: no meta/info.json; point it at a LeRobot dataset folder")
    try:
        info = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise BadInput(f"{path}: cannot read it as JSON ({error})") from error
    except RecursionError:
        raise BadInput(f"{path}: cannot read it as JSON (nested too deep)") from None
    if not isinstance(info, dict):
        raise BadInput(f"{path}: expected a JSON object (LeRobot's meta/info.json)")
    version = str(info.get("codebase_version"))
    if version not in VERSIONS:
        raise BadInput(f"{path}: codebase_version {version!r} is not supported; mlnseq reads {', '.join(VERSIONS)}")
    if not isinstance(info.get("features"), dict):
        raise BadInput(f"{path}: no 'features' table")
    for name, spec in info["features"].items():
        shape = (spec.get("shape") or [1]) if isinstance(spec, dict) else None
        if not isinstance(spec, dict) or not isinstance(shape, list) or not all(
                isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape):
            raise BadInput(f"{path}: feature {name!r} is {json.dumps(spec)[:80]}; a feature is an object with "
                           "a 'dtype' and a 'shape' of whole numbers")
    return info


def element_names(column: str, spec: dict[str, Any]) -> list[str]:
    """One name per element of a feature: from ``names`` (a list, or a dict of one list as v2.0 writes it)."""
    shape = list(spec.get("shape") or [1])
    size = 1
    for n in shape:
        size *= int(n)
    names = spec.get("names")
    if isinstance(names, dict) and len(names) == 1:
        names = next(iter(names.values()))
    if isinstance(names, list) and len(names) == size and all(isinstance(n, str) for n in names):
        return [f"{column}/{n}" for n in names] if size > 1 or shape != [1] else [column]
    return [column] if size == 1 else [f"{column}/{k}" for k in range(size)]


def requested_features(requested: tuple[str, ...], features: dict[str, Any],
                       source: Path) -> tuple[list[str], list[str]]:
    """The info.json features to read for ``requested`` names, each a feature or one element of a vector
    feature as collect names it (``observation.state/panda_joint1``, as a model remembers it); and the
    element names to keep, in order."""
    owner = {element: name for name, spec in features.items() if isinstance(spec, dict)
             for element in element_names(name, spec)}
    chosen, wanted = [], []
    for name in requested:
        why = language.not_a_feature(owner.get(name, name), features.get(owner.get(name, name)))
        if why:
            raise BadInput(f"--features {name}: {why}")
        if name in features:
            chosen.append(name)
            wanted += element_names(name, features[name])
        elif name in owner:
            chosen.append(owner[name])
            wanted.append(name)
        else:
            raise BadInput(f"{source}/meta/info.json: no feature {name!r}; its features are {', '.join(features)}")
    return list(dict.fromkeys(chosen)), wanted


def data_files(source: Path, info: dict[str, Any]) -> list[Path]:
    """The dataset's data files in name order, as its ``codebase_version`` lays them out."""
    pattern = "episode_*.parquet" if info["codebase_version"].startswith("v2") else "file-*.parquet"
    files = sorted((source / "data").glob(f"chunk-*/{pattern}"))
    if not files:
        raise BadInput(f"{source}/data holds no chunk-*/{pattern} ({info['codebase_version']} layout)")
    return files


def read(source: Path, columns: TableColumns, options: Any = None, label: Labels = Labels.REQUIRED) -> list[Recording]:
    source = Path(source)
    info = info_of(source)
    features = info["features"]
    style = getattr(options, "annotations", None) if label is not Labels.NONE else None
    if style is None and label is not Labels.NONE and language.is_language(columns.label, features.get(columns.label)):
        raise BadInput(f"--label-column {columns.label}: {language.not_a_feature(columns.label, None)}")
    chosen = [name for name, spec in features.items() if name not in KEYS and name != columns.label
              and spec.get("dtype") in NUMERIC and not language.not_a_feature(name, spec)]
    skipped = [name for name, spec in features.items() if spec.get("dtype") in ("image", "video")]
    wanted = None  # the features to keep, by the names collect gives (one per element of a vector feature)
    if columns.features:
        chosen, wanted = requested_features(columns.features, features, source)
    if not chosen:
        raise BadInput(f"{source}/meta/info.json: no numeric feature ({', '.join(features)})")
    recordings, subtasks = [], []
    for path in data_files(source, info):
        try:
            table = pl.read_parquet(path)
        except Exception as error:  # polars raises many types for unreadable files
            raise BadInput(f"{path}: cannot read it as parquet ({str(error).strip().splitlines()[0][:120]})") from error
        missing = [n for n in ("episode_index", "frame_index", *chosen) if n not in table.columns]
        if missing:
            raise BadInput(f"{path}: no column {missing[0]!r}; columns are {', '.join(table.columns)}")
        table = table.sort("episode_index", "frame_index", maintain_order=True)  # rows in any order: as documented
        flat = _flat(table, chosen, features, path)
        if wanted is not None:
            flat = {name: flat[name] for name in wanted}
        time = (table["timestamp"] if "timestamp" in table.columns
                else table["frame_index"] / float(info.get("fps") or 1))
        labelled = style is None and label is not Labels.NONE and columns.label in table.columns
        resolved = {"skipped_features": skipped}
        if style is None and label in (Labels.REQUIRED, Labels.SOME) and not labelled \
                and language.PERSISTENT in table.columns and language.annotated_episodes(table):
            resolved["unlabelled"] = (f"{path}: no label column {columns.label!r}; the dataset's own subtask "
                                      "annotations label its frames with --labels subtask (or name a column with "
                                      "--label-column)")  # no labels asked for, the dataset's own subtasks there
            if label is Labels.REQUIRED:
                raise BadInput(resolved["unlabelled"])
        recordings.append(Recording(
            path=path, features=check_features(pl.DataFrame(flat), path), episode=table["episode_index"].cast(pl.Int64),
            time=time, label=table[columns.label] if labelled else None, resolved=resolved))
        if style is not None:
            subtasks.append(_active(table, time, style, path))
    if style is not None:
        return _with_annotations(recordings, subtasks, style, label, getattr(options, "unlabelled", None), source)
    return recordings


def _active(table: pl.DataFrame, time: pl.Series, style: str, path: Path) -> tuple[pl.Series, pl.Series] | None:
    """Per row the ``style`` annotation active at its time and whether its episode has any; None without the
    column."""
    if language.PERSISTENT not in table.columns:
        return None
    kind = table.schema[language.PERSISTENT]
    rows = kind.inner if isinstance(kind, pl.List) else None
    fields = {f.name for f in rows.fields} if isinstance(rows, pl.Struct) else set()
    if not {"content", "style", "timestamp"} <= fields:
        raise BadInput(f"{path}: column {language.PERSISTENT} is {kind}, not LeRobot's list of rows (role, content, "
                       "style, timestamp, ...)")
    return language.active(table, time, style, str(path))


def _with_annotations(recordings: list[Recording], subtasks: list, style: str, label: Labels, unlabelled: str | None,
                      source: Path) -> list[Recording]:
    """Recordings labelled by their ``style`` annotations. For predict (labels optional) an episode is labelled where
    every frame of it is. Else episodes without annotations read unlabelled (``Labels.SOME``, collect) or left out,
    frames before an episode's first annotation left out (or labelled ``unlabelled``), each with a note."""
    if label is Labels.OPTIONAL:  # labelled where every frame of an episode is
        return [part for r, found in zip(recordings, subtasks) for part in _whole_episodes(r, found, unlabelled)]
    if all(found is None for found in subtasks):
        raise BadInput(f"{source}: no {language.PERSISTENT} column, so no {style} annotations to label frames with; "
                       "annotate episodes with LeRobot's tools, or give label intervals with --labels FILE")
    kept, bare, left_out, early = [], [], set(), 0
    for recording, found in zip(recordings, subtasks):
        n = recording.features.height
        labels, annotated = found or (pl.Series([None] * n, dtype=pl.String), pl.Series([False] * n))
        left_out |= set(recording.episode.filter(~annotated).to_list())
        early += int((annotated & labels.is_null()).sum()) if unlabelled is None else 0
        keep = annotated & (labels.is_not_null() | (unlabelled is not None))
        if keep.any():
            kept.append(dataclasses.replace(
                recording, features=recording.features.filter(keep), episode=recording.episode.filter(keep),
                time=recording.time.filter(keep), label=_filled(labels, unlabelled).filter(keep),
                row=pl.int_range(n, eager=True).filter(keep)))
        if not annotated.all() and label is Labels.SOME:  # episodes without annotations: read unlabelled
            bare.append(dataclasses.replace(
                recording, features=recording.features.filter(~annotated), episode=recording.episode.filter(~annotated),
                time=recording.time.filter(~annotated), label=None, row=pl.int_range(n, eager=True).filter(~annotated)))
    if not kept:
        raise BadInput(f"{source}: no episode has {style} annotations ({language.PERSISTENT} rows of style {style}); "
                       "annotate some with LeRobot's tools, or give label intervals with --labels FILE")
    total = len({e for r in recordings for e in r.episode.unique().to_list()})
    notes = [f"{len(left_out)} of {total} episodes have no {style} annotations: left out of training (predict "
             "recognises them)"] if left_out and label is Labels.REQUIRED else []  # SOME: collect says them
    if early:
        notes.append(f"{early:,} frames before their episode's first {style} left out (--unlabelled CLASS keeps them)")
    return [dataclasses.replace(r, resolved={**r.resolved, "notes": notes}) for r in kept + bare]


def _flat(table: pl.DataFrame, chosen: list[str], features: dict[str, Any], path: Path) -> dict[str, pl.Series]:
    """The chosen columns as one series per feature element, each checked against info.json's shape."""
    flat = {}
    for name in chosen:
        names = element_names(name, features[name])
        column = table[name]
        if isinstance(column.dtype, (pl.List, pl.Array)):
            lengths = column.list.len() if isinstance(column.dtype, pl.List) else None
            if lengths is None and column.dtype.size != len(names):
                raise BadInput(f"{path}: column {name!r} holds {column.dtype.size} values a frame, info.json's "
                               f"shape {len(names)}")
            if lengths is not None and (lengths != len(names)).any():
                row = int((lengths != len(names)).arg_true()[0])
                raise BadInput(f"{path} row {row}: column {name!r} holds {lengths[row]} values, info.json's "
                               f"shape {len(names)}")
            elements = column.list if lengths is not None else column.arr
            for k, feature in enumerate(names):
                flat[feature] = elements.get(k)
        else:
            flat[names[0]] = column
    return flat


def _whole_episodes(recording: Recording, found: tuple[pl.Series, pl.Series] | None,
                    unlabelled: str | None) -> list[Recording]:
    """A file's recording for predict: its episodes annotated on every frame labelled, the others not (two parts
    where it holds both)."""
    if found is None:
        return [recording]
    labels, annotated = found
    whole = (annotated & (labels.is_not_null() | (unlabelled is not None))).to_frame("whole").with_columns(
        pl.col("whole").all().over(recording.episode.alias("episode")))["whole"]
    parts = []
    for mask, label in ((whole, _filled(labels, unlabelled)), (~whole, None)):
        if mask.all():
            return [dataclasses.replace(recording, label=label)]
        if mask.any():
            parts.append(dataclasses.replace(
                recording, features=recording.features.filter(mask), episode=recording.episode.filter(mask),
                time=recording.time.filter(mask), label=None if label is None else label.filter(mask),
                row=pl.int_range(len(mask), eager=True).filter(mask)))
    return parts


def _filled(labels: pl.Series, unlabelled: str | None) -> pl.Series:
    return labels if unlabelled is None else labels.fill_null(unlabelled)
