"""``predict --write-lerobot``: a copy of a LeRobot v3.0 dataset with the predicted phases as LeRobot 0.6.1's own
subtask annotations (``mlnseq.sources.lerobot_language``).

Each episode gets one ``language_persistent`` row of style ``subtask`` per predicted segment, at its first frame's
timestamp (the data's own float32), on every frame of the episode; ``language_events`` stays as the source has it
(empty lists where it has none); both are declared in ``meta/info.json``. Episodes that carry subtask annotations
keep them unless asked to replace them; rows of other styles are kept. A data file keeps its columns, values, row
groups, compression and metadata; every other file (videos, stats, episodes, tasks) is copied byte for byte. The
source is only read.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import lerobot
from mlnseq.sources import lerobot_language as language

VERSION = "v3.0"  # the layout LeRobot 0.6.1 reads annotations from
CODECS = {"uncompressed": "none", "lz4_raw": "lz4"}  # parquet's codec names that pyarrow's writer spells otherwise


@dataclass(frozen=True)
class Predicted:
    """Per frame of a prediction, in episode and frame order: the classes, and each class's probability."""

    episodes: np.ndarray  # the dataset's episode_index per frame
    classes: np.ndarray  # class name per frame
    probabilities: np.ndarray | None  # [frames, classes] float32, written when not None
    names: tuple[str, ...]  # the classes, in the probabilities' order

    @classmethod
    def of(cls, table: pl.DataFrame, names: list[str], probabilities: bool) -> Predicted:
        """From predict's table: episode, frame, class and ``p_CLASS`` columns."""
        columns = [artifacts.class_probability_column(name) for name in names]
        return cls(table["episode"].to_numpy(), table["class"].to_numpy().astype(object),
                   table.select(columns).to_numpy().astype(np.float32) if probabilities else None, tuple(names))


@dataclass(frozen=True)
class Written:
    predicted: int  # episodes written with their predicted subtasks
    kept: int  # episodes that kept their own subtask annotations


def check_target(source: Path, out: Path, force: bool, others: dict[str, Any]) -> None:
    """Refuse an OUT that is the source, inside it or holding it, an existing one without ``force``, and any of
    ``others`` (what names it -> a path: outputs and inputs) inside OUT."""
    flag, here, there = f"--write-lerobot {out}", Path(source).resolve(), Path(out).resolve()
    if there == here:
        raise BadInput(f"{flag} is the source dataset; predict never writes into its source: name a new folder")
    if there.is_relative_to(here):
        raise BadInput(f"{flag} is inside the source dataset {source}; name a folder outside it")
    if here.is_relative_to(there):
        raise BadInput(f"{flag} holds the source dataset {source}; name a folder outside it")
    if Path(out).exists() and not Path(out).is_dir():
        raise BadInput(f"{flag} is a file; name a folder")
    if Path(out).exists() and not force:
        raise BadInput(f"{flag} exists; pass --force to replace it, or name another folder")
    if Path(out).is_dir() and any(Path(out).iterdir()) and not (Path(out) / "meta" / "info.json").is_file():
        raise BadInput(f"{flag} is a folder but not a LeRobot dataset (no meta/info.json); --force replaces only "
                       "a dataset: name a new folder")
    for what, path in others.items():
        if path is not None and Path(path).resolve().is_relative_to(there):
            raise BadInput(f"{what} {path} is inside {flag}, which is written whole; put it outside")


def write(folder: Path, source: Path, predicted: Predicted, replace: bool | frozenset = False) -> Written:
    """Fill ``folder`` (an empty staging folder) with ``source`` and ``predicted`` as its subtask annotations;
    ``replace``: over the episodes' own annotations too (True: every episode's; a set: those episodes')."""
    source = Path(source)
    info = lerobot.info_of(source)
    if info["codebase_version"] != VERSION:
        raise BadInput(f"--write-lerobot: {source} is a {info['codebase_version']} dataset and LeRobot 0.6.1 reads "
                       f"subtask annotations from {VERSION} ones: convert it with LeRobot's "
                       "convert_dataset_v21_to_v30 first")
    files = lerobot.data_files(source, info)
    copy_dataset(source, folder, {source / "meta" / "info.json", *files})
    spans = _spans(predicted.episodes)
    seen: set = set()
    kept = 0
    for path in files:
        kept += _rewrite(path, folder / path.relative_to(source), predicted, spans, replace, seen)
    missing = set(spans) - seen
    if missing:
        raise BadInput(f"--write-lerobot: episode {sorted(missing)[0]} was predicted but is in no data file of "
                       f"{source}")
    _write_info(info, source / "meta" / "info.json", folder / "meta" / "info.json", predicted)
    return Written(predicted=len(spans) - kept, kept=kept)


def copy_dataset(source: Path, folder: Path, skipped: set[Path]) -> None:
    """Every file of ``source`` but ``skipped`` copied into ``folder``, its bytes only (a read-only source gives a
    copy its user may change); links followed."""
    for where, _, names in os.walk(source, followlinks=True):
        into = folder / Path(where).relative_to(source)
        into.mkdir(exist_ok=True)
        for name in names:
            if Path(where) / name not in skipped:
                shutil.copyfile(Path(where) / name, into / name)


def _spans(episodes: np.ndarray) -> dict[Any, tuple[int, int]]:
    """Each episode's first row and row count in the predictions."""
    ids = pl.Series(episodes).to_frame("episode").with_row_index("row")
    runs = ids.group_by("episode", maintain_order=True).agg(pl.col("row").min().alias("first"), pl.len())
    return {episode: (first, n) for episode, first, n in runs.iter_rows()}


def _rewrite(path: Path, target: Path, predicted: Predicted, spans: dict, replace: bool | frozenset,
             seen: set) -> int:
    """One data file with the language columns (and probabilities) put in, row group by row group; returns how many
    of its episodes kept their own subtask annotations."""
    parquet = pq.ParquetFile(path)
    keys = pl.from_arrow(parquet.read(columns=[c for c in ("episode_index", "frame_index", "timestamp",
                                                           language.PERSISTENT) if c in parquet.schema_arrow.names]))
    rows, lists, kept = _episode_rows(keys, predicted, spans, replace, path)
    seen.update(lists)
    if parquet.metadata.num_row_groups == 0:
        shutil.copyfile(path, target)
        return len(kept)
    codec = parquet.metadata.row_group(0).column(0).compression.lower()
    offset, writer = 0, None
    try:
        for index in range(parquet.metadata.num_row_groups):
            group = parquet.read_row_group(index)
            part = slice(offset, offset + group.num_rows)
            offset += group.num_rows
            group = _annotated(group, keys["episode_index"].to_numpy()[part], rows[part], lists, kept, predicted)
            writer = writer or pq.ParquetWriter(target, group.schema, compression=CODECS.get(codec, codec))
            writer.write_table(group)
    finally:
        if writer is not None:
            writer.close()
    return len(kept)


def _episode_rows(keys: pl.DataFrame, predicted: Predicted, spans: dict, replace: bool | frozenset,
                  path: Path) -> tuple[np.ndarray, dict, set]:
    """For a data file's rows: each row's frame in the predictions; each episode's persistent rows with the
    predicted subtasks; the episodes keeping their own."""
    missing = [c for c in ("episode_index", "frame_index", "timestamp") if c not in keys.columns]
    if missing:
        raise BadInput(f"{path}: no column {missing[0]!r}; LeRobot places its subtask rows by episode, frame and time")
    position = keys.select((pl.col("frame_index").rank("ordinal").over("episode_index") - 1).alias("p"))["p"]
    position, stamps = position.to_numpy(), keys["timestamp"].to_numpy()
    own = (set() if replace is True or language.PERSISTENT not in keys.columns
           else language.annotated_episodes(keys) - set(replace or ()))
    rows = np.zeros(keys.height, dtype=np.int64)
    lists = {}
    groups = keys.with_row_index("_row").group_by("episode_index", maintain_order=True).agg("_row")
    for episode, mine in groups.iter_rows():
        mine = np.asarray(mine, dtype=np.int64)
        first, n = spans.get(episode, (0, -1))
        if n != len(mine):
            raise BadInput(f"{path}: episode {episode} has {len(mine)} frames, {max(n, 0)} of them predicted; "
                           "--write-lerobot needs every frame: predict without --labels, or with --unlabelled CLASS")
        order = position[mine]
        rows[mine] = first + order
        times = np.empty(n)
        times[order] = stamps[mine]
        before = keys[language.PERSISTENT][int(mine[np.argmin(order)])] if language.PERSISTENT in keys.columns else None
        subtasks = language.rows_of(list(predicted.classes[first:first + n]), times)
        lists[episode] = language.merged(None if before is None else before.to_list(), subtasks)
    return rows, lists, own


def _annotated(group: pa.Table, episodes: np.ndarray, rows: np.ndarray, lists: dict, kept: set,
               predicted: Predicted) -> pa.Table:
    """A row group with its episodes' persistent rows (its own where kept), events and probabilities."""
    names = group.schema.names
    kind = group.schema.field(language.PERSISTENT).type if language.PERSISTENT in names else language.PERSISTENT_TYPE
    order = list(lists)
    choices = pa.array([lists[episode] for episode in order], type=kind)
    pick = pl.Series(episodes).replace_strict(order, list(range(len(order))), return_dtype=pl.Int64).to_numpy()
    if kept:
        own = np.isin(episodes, list(kept))
        choices = pa.concat_arrays([choices, group.column(language.PERSISTENT).combine_chunks()])
        pick = np.where(own, len(order) + np.arange(len(episodes)), pick)
    group = _put(group, language.PERSISTENT, choices.take(pa.array(pick)))
    if language.EVENTS not in names:
        group = _put(group, language.EVENTS, pa.array([[]] * group.num_rows, type=language.EVENTS_TYPE))
    if predicted.probabilities is not None:
        values = predicted.probabilities[rows]
        group = _put(group, language.PROBABILITIES, pa.FixedSizeListArray.from_arrays(
            pa.array(values.ravel(), type=pa.float32()), values.shape[1]))
    return group


def _put(table: pa.Table, name: str, values: pa.Array) -> pa.Table:
    """``values`` as column ``name``: in its place if the table has it, else appended."""
    if name in table.schema.names:
        index = table.schema.get_field_index(name)
        return table.set_column(index, table.schema.field(name).with_type(values.type), values)
    return table.append_column(name, values)


def _write_info(info: dict[str, Any], source: Path, target: Path, predicted: Predicted) -> None:
    """info.json with both language columns declared (and the probabilities), as LeRobot writes it; unchanged bytes
    when it declares them already."""
    features = info["features"]
    added = {name: dict(language.DECLARATION) for name in (language.PERSISTENT, language.EVENTS)
             if name not in features}
    if predicted.probabilities is not None:
        added[language.PROBABILITIES] = {"dtype": "float32", "shape": [len(predicted.names)],
                                         "names": list(predicted.names)}
    if not added:
        shutil.copyfile(source, target)
        return
    features.update(added)
    target.write_text(json.dumps(info, indent=4, ensure_ascii=False), encoding="utf-8")
