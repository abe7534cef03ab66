"""``audit --write-lerobot``: a copy of a LeRobot v3.0 dataset with per-episode columns added to its episodes'
metadata (``meta/episodes/chunk-*/file-*.parquet``), which LeRobot 0.6.1's ``LeRobotDataset(..., episode_filter=lambda
ep: ...)`` reads for each episode. Every other file is copied byte for byte; a metadata file keeps its columns,
values, row groups and compression, the new columns after them. The source is only read."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from mlnseq.catalog.errors import BadInput
from mlnseq.sources import lerobot
from mlnseq.sources.lerobot_writer import CODECS, VERSION, copy_dataset


def episode_files(source: Path) -> list[Path]:
    """The dataset's episode metadata files, in order."""
    return sorted((Path(source) / "meta" / "episodes").glob("chunk-*/file-*.parquet"))


def write(folder: Path, source: Path, columns: dict[str, dict[int, Any]]) -> int:
    """Fill ``folder`` (an empty staging folder) with ``source`` and ``columns`` (name -> episode_index -> value: a
    string, a number or a list of strings) in its episodes' metadata; how many episodes got them. An episode of the
    dataset missing from a column, or a column of an episode the dataset lacks, is refused."""
    source = Path(source)
    info = lerobot.info_of(source)
    if info["codebase_version"] != VERSION:
        raise BadInput(f"--write-lerobot: {source} is a {info['codebase_version']} dataset; LeRobot 0.6.1 filters "
                       f"episodes of {VERSION} ones: convert it with LeRobot's convert_dataset_v21_to_v30 first")
    files = episode_files(source)
    if not files:
        raise BadInput(f"--write-lerobot: {source} has no meta/episodes/chunk-*/file-*.parquet to add columns to")
    copy_dataset(source, folder, set(files))
    seen: set[int] = set()
    for path in files:
        seen |= _rewrite(path, folder / path.relative_to(source), columns)
    wanted = set().union(*(set(values) for values in columns.values()))
    if wanted - seen:
        raise BadInput(f"--write-lerobot: episode {sorted(wanted - seen)[0]} was audited but is in no episodes file "
                       f"of {source}")
    return len(seen)


def _rewrite(path: Path, target: Path, columns: dict[str, dict[int, Any]]) -> set[int]:
    """One episodes file with ``columns`` appended, row group by row group; the episodes it holds."""
    parquet = pq.ParquetFile(path)
    if "episode_index" not in parquet.schema_arrow.names:
        raise BadInput(f"{path}: no column 'episode_index'; LeRobot's episodes metadata names each episode by it")
    clash = [name for name in columns if name in parquet.schema_arrow.names]
    if clash:
        raise BadInput(f"{path} has a column {clash[0]!r} already; audit the dataset it was copied from")
    codec = parquet.metadata.row_group(0).column(0).compression.lower() if parquet.metadata.num_row_groups else "snappy"
    seen: set[int] = set()
    writer = None
    try:
        for index in range(parquet.metadata.num_row_groups):
            group = parquet.read_row_group(index)
            episodes = [int(e) for e in group.column("episode_index").to_pylist()]
            for episode in episodes:
                if any(episode not in values for values in columns.values()):
                    raise BadInput(f"{path}: episode {episode} was not audited (every episode needs a verdict): "
                                   "audit the whole dataset")
            seen.update(episodes)
            for name, values in columns.items():
                group = group.append_column(name, pa.array([values[e] for e in episodes]))
            writer = writer or pq.ParquetWriter(target, group.schema, compression=CODECS.get(codec, codec))
            writer.write_table(group)
    finally:
        if writer is not None:
            writer.close()
    if writer is None:
        shutil.copyfile(path, target)
    return seen
