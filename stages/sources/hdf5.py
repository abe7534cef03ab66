"""robomimic-style HDF5 demonstrations read with h5py: ``data/demo_N/obs/*`` and ``data/demo_N/actions``,
one episode a demo in number order.

``--features`` names datasets by their path in a demo (``obs/robot0_eef_pos``, ``actions``); by default
every numeric dataset under ``obs/`` with one value or one vector a frame, then ``actions`` (images and
other higher-dimensional datasets are left out). A vector dataset gives one feature per element,
``PATH/0``, ``PATH/1``...; a frame's time is its index. A dataset named by ``--label-column`` in a demo
labels its frames.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog.errors import BadInput
from mlnseq.sources.table import check_features
from mlnseq.sources.recording import Labels, Recording, TableColumns


def _datasets(group, prefix: str = "") -> list[str]:
    import h5py

    found = []
    for name, item in group.items():
        path = f"{prefix}{name}"
        if isinstance(item, h5py.Dataset):
            found.append(path)
        else:
            found += _datasets(item, f"{path}/")
    return found


def _datasets_of(requested: list[str], present: list[str]) -> tuple[list[str], list[str] | None]:
    """The datasets to read for ``requested`` names, each a dataset or one element ``PATH/K`` of a vector
    dataset as collect names it (as a model remembers it); and the feature names to keep (None: all)."""
    if all(name in present for name in requested):
        return requested, None
    chosen = []
    for name in requested:
        parent, _, index = name.rpartition("/")
        chosen.append(parent if name not in present and index.isdigit() and parent in present else name)
    return list(dict.fromkeys(chosen)), list(requested)


def _kept(flat: dict[str, np.ndarray], wanted: list[str] | None, where: str) -> dict[str, np.ndarray]:
    """The features asked for by name (None: all), in the order asked."""
    absent = [name for name in wanted or () if name not in flat]
    if absent:
        raise BadInput(f"{where}: no feature {absent[0]!r}; the demo gives {', '.join(flat)}")
    return flat if wanted is None else {name: flat[name] for name in wanted}


def _labels(group, name: str, where: str, length: int) -> pl.Series:
    """A demo's label dataset: one UTF-8 text or number per frame."""
    raw = np.asarray(group[name])
    if raw.ndim != 1 or len(raw) != length:
        raise BadInput(f"{where}/{name}: {raw.shape[0] if raw.ndim else 0} labels of shape {raw.shape} for {length} "
                       "frames; give one label a frame")
    values = raw.tolist()
    for k, value in enumerate(values):
        if isinstance(value, bytes):
            try:
                values[k] = value.decode()
            except UnicodeDecodeError:
                raise BadInput(f"{where}/{name} frame {k}: label {value[:40]!r} is not UTF-8 text") from None
    return pl.Series("label", values)


def read(source: Path, columns: TableColumns, options: Any = None, label: Labels = Labels.REQUIRED) -> list[Recording]:
    try:
        import h5py
    except ImportError as error:
        from mlnseq.sources import missing_extra

        raise missing_extra("h5py", error) from error
    source = Path(source)
    if not source.is_file():
        raise BadInput(f"--source {source}: expected an HDF5 file (robomimic layout: data/demo_N/obs, actions)")
    try:
        handle = h5py.File(source, "r")
    except OSError as error:
        raise BadInput(f"{source}: cannot read it as HDF5 ({error})") from error
    with handle:
        if "data" not in handle or not len(handle["data"]):
            raise BadInput(f"{source}: no data/demo_N groups (robomimic layout)")
        demos = sorted(handle["data"], key=lambda n: [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", n)])
        recordings = []
        chosen: list[str] | None = list(columns.features) or None
        for demo in demos:
            group = handle["data"][demo]
            where = f"{source}:/data/{demo}"
            if not isinstance(group, h5py.Group):
                raise BadInput(f"{where} is a dataset, not a demo group (robomimic layout: data/demo_N/obs, actions)")
            present = _datasets(group)
            if chosen is None:
                chosen = [p for p in present if p.startswith("obs/") and group[p].dtype.kind in "biuf"
                          and 1 <= group[p].ndim <= 2] + (["actions"] if "actions" in present else [])
                if not chosen:
                    raise BadInput(f"{where}: no numeric obs/ dataset or actions; its datasets are "
                                   f"{', '.join(present)}")
            datasets, wanted = _datasets_of(chosen, present)
            missing = [p for p in datasets if p not in present]
            if missing:
                raise BadInput(f"{where}: no dataset {missing[0]!r}; the demo's datasets are {', '.join(present)}")
            flat: dict[str, np.ndarray] = {}
            length = None
            for path in datasets:
                values = np.asarray(group[path])
                if not 1 <= values.ndim <= 2 or values.dtype.kind not in "biuf":
                    raise BadInput(f"{where}/{path}: {values.dtype} of shape {values.shape} is not one value or "
                                   "one vector a frame")
                if length is not None and len(values) != length:
                    raise BadInput(f"{where}/{path}: {len(values)} frames, where {datasets[0]} has {length}")
                length = len(values)
                if values.ndim == 1:
                    flat[path] = values
                else:
                    flat.update({f"{path}/{k}": values[:, k] for k in range(values.shape[1])})
            flat = _kept(flat, wanted, where)
            labels = None
            if label is not Labels.NONE and columns.label in present:
                labels = _labels(group, columns.label, where, length)
            recordings.append(Recording(
                path=source, features=check_features(pl.DataFrame(flat), Path(where), "{file} frame {row}"),
                episode=pl.Series([demo] * length), time=pl.int_range(length, eager=True), label=labels,
                where=f"{where} frame {{row}}"))
    return recordings
