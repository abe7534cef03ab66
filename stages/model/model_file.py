"""The model file (``.mlnseq``): a zip of ``manifest.json``, the predicate spec ``binarize.toml``, the MLN's
``weights.parquet`` and the network's ``network.npz``; how it is written, and read without trusting it:
every member bounded before it is read and checked against what the manifest declares (docs/model-file.md)."""

from __future__ import annotations

import hashlib
import io
import json
import math
import struct
import zipfile
import zlib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq import networks
from mlnseq.catalog.errors import BadInput
from mlnseq.model.manifest import AGAIN, AUDIT, MANIFEST, MODEL_FORMAT, NETWORK, SPEC, WEIGHTS, Manifest
from mlnseq.networks.network import Network

if TYPE_CHECKING:
    from mlnseq.predicates.spec import PredicateSpec

MODEL_SUFFIX = ".mlnseq"
MEMBERS = (MANIFEST, SPEC, WEIGHTS, NETWORK, AUDIT)

KIB, MIB = 1024, 1024 * 1024
MANIFEST_LIMIT = SPEC_LIMIT = AUDIT_LIMIT = 1 * MIB  # a DESK model's manifest and spec are 2 KB each
MEMBER_CEILING = 64 * MIB  # no member may be larger, whatever the manifest declares
TABLE_OVERHEAD = 64 * KIB  # weights.parquet's footer, schema and metadata
FORMULA_BYTES = 1 * KIB  # one formula's row of weights.parquet (DESK's: 27 bytes on disk, formulas <= 49 chars)
ARRAY_OVERHEAD = 1 * KIB  # one array's npy header and zip entry in network.npz
ITEM_BYTES = 8  # float64, the widest dtype an array may have
ARRAY_DTYPES = (np.dtype("<f8"), np.dtype("<f4"))
WEIGHT_COLUMNS = {"formula": pl.String, "class": pl.String, "weight": pl.Float64, "hard": pl.Boolean}
READ_ERRORS = (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, KeyError, IndexError,
               NotImplementedError, RuntimeError, struct.error, OverflowError, RecursionError)
EOCD = struct.Struct("<4s4H2LH")  # the zip's end-of-central-directory record


CORRUPTED = ("Bad CRC-32", "Bad magic number", "Error -3 while decompressing")  # zip's checks of a member's bytes


def _foreign(where: Any, reason: Any) -> BadInput:
    if isinstance(reason, zlib.error) or any(mark in str(reason) for mark in CORRUPTED):
        return BadInput(f"{where} is corrupted: a member fails the zip's own check ({reason}), its bytes changed "
                        "since it was written (or it is no file mlnseq wrote); copy it again, or write it again with "
                        "`mlnseq export`")
    return BadInput(f"{where} is not an mlnseq model file (truncated or foreign: {reason}); "
                    "write one with `mlnseq export`")


def model_entries(manifest: Manifest, spec_text: str | None, weights: pl.DataFrame | None,
                  network: Network | None, audit: bytes | None = None) -> dict[str, bytes]:
    """The files of a model file, by name: the manifest, the predicate spec, the MLN weights, the network's
    arrays (its state dict's names, and its standardisation ``mean`` and ``std``), and the audit profile (JSON)."""
    members = {}
    if spec_text is not None:
        members[SPEC] = spec_text.encode()
    if weights is not None:
        buffer = io.BytesIO()
        weights.write_parquet(buffer, compression="zstd")
        members[WEIGHTS] = buffer.getvalue()
    if network is not None:
        buffer = io.BytesIO()
        np.savez(buffer, mean=network.mean, std=network.std, **network.weights)
        members[NETWORK] = buffer.getvalue()
    if audit is not None:
        members[AUDIT] = audit
    return seal(replace(manifest, formulas=0 if weights is None else weights.height).to_dict(), members)


def seal(manifest: dict[str, Any], members: dict[str, bytes]) -> dict[str, bytes]:
    """The manifest (with the format version and each member's size and SHA-256) and the members."""
    declared = {name: {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
                for name, data in members.items()}
    text = json.dumps({"format": MODEL_FORMAT, **manifest, "members": declared}, indent=1, sort_keys=True)
    return {MANIFEST: text.encode(), **members}


def write_model(path: Path, entries: dict[str, bytes]) -> Path:
    """Write a model file (a zip) atomically; its entries carry a fixed time, so a rewrite is byte-identical."""
    with artifacts.atomic_path(path) as tmp:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
            for name, data in entries.items():
                archive.writestr(zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0)), data)
    return path


def parse_manifest(data: bytes, where: Any) -> Manifest:
    """The manifest, checked: its format, then every field (stages/model/manifest.py)."""
    try:
        values = json.loads(data)
    except (ValueError, RecursionError) as error:
        raise _foreign(where, f"{MANIFEST} is not JSON: {error}") from None
    if not isinstance(values, dict) or values.get("format") != MODEL_FORMAT:
        found = values.get("format") if isinstance(values, dict) else None
        version = values.get("mlnseq_version", "?") if isinstance(values, dict) else "?"
        raise BadInput(f"{where} is model-file format {found} from mlnseq {version}; this mlnseq "
                       f"({artifacts.package_version()}) reads format {MODEL_FORMAT}: {AGAIN}")
    return Manifest.read(values, where)


def network_shapes(config: dict[str, Any]) -> dict[str, tuple[int, ...]]:
    """The arrays of network.npz and their shapes, from the network's configuration (its type's state dict and
    the standardisation)."""
    return networks.state_shapes(config) | {"mean": (config["n_features"],), "std": (config["n_features"],)}


def member_limits(manifest: Manifest | dict[str, Any], where: Any) -> dict[str, int]:
    """The most bytes each member may hold: fixed for the manifest and the spec, derived from the manifest's
    formulas and network for the others (``manifest``, or its JSON object: checked first); a manifest declaring
    more than MEMBER_CEILING is refused."""
    if isinstance(manifest, dict):
        manifest = Manifest.read(manifest, where)
    limits = {MANIFEST: MANIFEST_LIMIT, SPEC: SPEC_LIMIT, WEIGHTS: TABLE_OVERHEAD + FORMULA_BYTES * manifest.formulas,
              AUDIT: AUDIT_LIMIT}
    if manifest.network is not None:
        shapes = network_shapes(manifest.network.model)
        limits[NETWORK] = sum(ARRAY_OVERHEAD + ITEM_BYTES * math.prod(shape) for shape in shapes.values())
    for name, limit in limits.items():
        if limit > MEMBER_CEILING:
            raise BadInput(f"{where}: its manifest declares a {name} of up to {limit:,} bytes, over the "
                           f"{MEMBER_CEILING:,} bytes a member may hold: not a model this mlnseq loads")
    return limits


def _check_members(names: set[str], manifest: Manifest, where: Any) -> None:
    """The file holds exactly the members its manifest declares, and they fit the model it describes."""
    declared = set(manifest.members)
    for name in sorted(names - {MANIFEST} - declared):
        raise BadInput(f"{where} holds {name}, which its manifest does not declare: {AGAIN}")
    for name in sorted(declared - names):
        raise BadInput(f"{where} lacks {name}, which its manifest declares: {AGAIN}")
    if (NETWORK in declared) != (manifest.network is not None):
        raise BadInput(f"{where}: its manifest's network and its {NETWORK} member disagree: {AGAIN}")
    if (SPEC in declared) != (WEIGHTS in declared) or (WEIGHTS not in declared and manifest.formulas):
        raise BadInput(f"{where}: an MLN needs both {SPEC} and {WEIGHTS}, and the manifest's formula count: {AGAIN}")


def read_model(path: Path) -> dict[str, bytes]:
    """A model file's members, each read within its bound; a file that is not one is one clear line."""
    path = Path(path)
    if not path.is_file():
        raise BadInput(f"model file {path} not found: write one with `mlnseq export`")
    try:
        with open(path, "rb") as handle:
            _check_directory(handle, path)
            with zipfile.ZipFile(handle) as archive:
                infos = _infos(archive, path)
                if MANIFEST not in infos:
                    raise _foreign(path, f"no {MANIFEST}")
                entries = {MANIFEST: _read(archive, infos[MANIFEST], MANIFEST_LIMIT, path)}
                manifest = parse_manifest(entries[MANIFEST], path)
                _check_members(set(infos), manifest, path)
                limits = member_limits(manifest, path)
                for name in manifest.members:
                    entries[name] = _read(archive, infos[name], limits[name], path)
    except BadInput:
        raise
    except READ_ERRORS as error:
        raise _foreign(path, error) from None
    return entries


def _check_directory(handle: Any, where: Any) -> None:
    """Refuse a zip whose directory holds more entries than a model file has, before zipfile parses it."""
    handle.seek(max(0, handle.seek(0, io.SEEK_END) - EOCD.size - 0xFFFF))  # the record and a comment of up to 64 KiB
    tail = handle.read()
    end = len(tail) - EOCD.size  # where zipfile looks first, then at the last signature before
    at = end if tail[end:].startswith(b"PK\x05\x06") else tail.rfind(b"PK\x05\x06")
    if at < 0 or at > end or at + EOCD.size + EOCD.unpack_from(tail, at)[-1] != len(tail):
        raise _foreign(where, "no zip directory at its end")
    _, disk, _, entries, total, directory, _, _ = EOCD.unpack_from(tail, at)
    if total > len(MEMBERS):
        raise BadInput(f"{where}: its zip directory declares {total:,} members; a model file holds at most "
                       f"{len(MEMBERS)} ({', '.join(MEMBERS)}): {AGAIN}")
    if (disk or entries != total or tail[max(0, at - 20) : at].startswith(b"PK\x06\x07")
            or directory > len(MEMBERS) * (46 + 64 * KIB)):  # an entry: 46 bytes, its name and extra field
        raise _foreign(where, "a zip64, multi-disk or oversized zip directory")
    handle.seek(0)


def _infos(archive: zipfile.ZipFile, where: Any) -> dict[str, zipfile.ZipInfo]:
    """The archive's members by name: known names, once each, stored or deflated, not encrypted."""
    infos: dict[str, zipfile.ZipInfo] = {}
    for info in archive.infolist():
        if info.filename not in MEMBERS:
            raise BadInput(f"{where} holds {info.filename!r}, which is not a model file's member "
                           f"({', '.join(MEMBERS)}): {AGAIN}")
        if info.filename in infos:
            raise BadInput(f"{where} holds {info.filename} twice: {AGAIN}")
        infos[info.filename] = info
    return infos


def _read(archive: zipfile.ZipFile, info: zipfile.ZipInfo, limit: int, where: Any) -> bytes:
    """One member's bytes, never more than ``limit`` whatever its header claims."""
    name = info.filename
    if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED) or info.flag_bits & 0x1:
        raise BadInput(f"{where}: {name} is encrypted or compressed with method {info.compress_type}; a model file's "
                       f"members are stored or deflated: {AGAIN}")
    if info.file_size > limit or info.compress_size > limit + limit // 100 + KIB:
        raise BadInput(f"{where}: {name} declares {info.file_size:,} bytes ({info.compress_size:,} compressed), "
                       f"over its limit of {limit:,} bytes: {AGAIN}")
    with archive.open(info) as member:
        data = member.read(limit + 1)
    if len(data) > limit:
        raise BadInput(f"{where}: {name} holds more than its limit of {limit:,} bytes: {AGAIN}")
    return data


@dataclass(frozen=True)
class ModelFile:
    """A model file's members, decoded and checked against its manifest."""

    manifest: Manifest
    spec: PredicateSpec | None
    weights: pl.DataFrame | None
    network: Network | None
    audit: bytes | None = None  # the audit profile's JSON (stages/auditing/profile.py reads it)


def parse_model(entries: dict[str, bytes], where: str) -> ModelFile:
    """Decode and check every member: sizes and digests as the manifest declares, the spec's predicate
    columns, the weights' formula count, classes and numbers, the network's shapes and numbers."""
    manifest = parse_manifest(entries[MANIFEST], where)
    _check_members(set(entries), manifest, where)
    limits = member_limits(manifest, where)
    for name, data in entries.items():
        if len(data) > limits[name]:
            raise BadInput(f"{where}: {name} is {len(data):,} bytes, over its limit of {limits[name]:,} bytes: {AGAIN}")
        declared = manifest.members.get(name)
        if declared and (len(data) != declared["bytes"] or hashlib.sha256(data).hexdigest() != declared["sha256"]):
            raise BadInput(f"{where}: {name} is not the one its manifest declares (its size or SHA-256 differs): "
                           f"the file was altered or assembled from two models; {AGAIN}")
    spec = weights = network = None
    if SPEC in entries:
        spec = read_spec(entries[SPEC], manifest, where)
        weights = read_weights(entries[WEIGHTS], manifest, where)
    if NETWORK in entries:
        network = read_network(entries[NETWORK], manifest.network.model, where)
    return ModelFile(manifest, spec, weights, network, entries.get(AUDIT))


def read_spec(data: bytes, manifest: Manifest, where: str) -> PredicateSpec:
    """The predicate spec, whose columns must be the manifest's predicates."""
    from mlnseq.predicates.spec import parse_spec

    try:
        text = data.decode()
    except UnicodeDecodeError as error:
        raise BadInput(f"{where}: {SPEC} is not UTF-8 text ({error}): {AGAIN}") from None
    try:
        spec = parse_spec(text, Path(where) / SPEC)
    except RecursionError:  # tomllib recurses once per nested array or table
        raise BadInput(f"{where}: {SPEC} nests too deeply to be a predicate spec: {AGAIN}") from None
    columns = [c for group in spec.columns().values() for c in group]
    if sorted(columns) != sorted(manifest.predicates):
        raise BadInput(f"{where}: {SPEC} makes predicate columns {columns[:3]}... ({len(columns)}), the manifest "
                       f"declares {manifest.predicates[:3]}... ({len(manifest.predicates)}): {AGAIN}")
    return spec


def read_weights(data: bytes, manifest: Manifest, where: str) -> pl.DataFrame:
    """The MLN's weights: as many formulas as declared, within the bound uncompressed too, classes of the
    model, finite weights."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from mlnseq.mln.grounding import class_constant

    limit = TABLE_OVERHEAD + FORMULA_BYTES * manifest.formulas
    try:
        meta = pq.ParquetFile(io.BytesIO(data)).metadata
        unpacked = sum(meta.row_group(g).column(c).total_uncompressed_size
                       for g in range(meta.num_row_groups) for c in range(meta.num_columns))
        if meta.num_rows != manifest.formulas or unpacked > limit:
            raise BadInput(f"{where}: {WEIGHTS} holds {meta.num_rows:,} formulas in {unpacked:,} bytes "
                           f"uncompressed; its manifest declares {manifest.formulas:,} formulas, at most "
                           f"{limit:,} bytes: {AGAIN}")
        weights = pl.read_parquet(io.BytesIO(data))
    except (pa.ArrowException, OSError, ValueError, pl.exceptions.PolarsError, pl.exceptions.PanicException) as error:
        raise BadInput(f"{where}: its {WEIGHTS} cannot be read ({error}): {AGAIN}") from None
    wrong = [f"{c} ({weights.schema.get(c)})" for c, kind in WEIGHT_COLUMNS.items() if weights.schema.get(c) != kind]
    if wrong:
        raise BadInput(f"{where}: {WEIGHTS} lacks or mistypes the columns {', '.join(wrong)}: {AGAIN}")
    classes = {*manifest.classes, *(class_constant(k) for k in range(len(manifest.classes)))}
    foreign = weights.filter(pl.col("class").is_not_null() & ~pl.col("class").is_in(sorted(classes)))
    if foreign.height:
        raise BadInput(f"{where}: {WEIGHTS} has a formula of class {foreign['class'][0]!r}, which is not one of the "
                       f"manifest's {len(manifest.classes)} classes: {AGAIN}")
    bad = weights.filter(pl.col("formula").is_null() | pl.col("hard").is_null()
                         | (~pl.col("hard") & (pl.col("weight").is_null() | ~pl.col("weight").is_finite())))
    if bad.height:
        raise BadInput(f"{where}: {WEIGHTS} formula {bad['formula'][0]} has weight {bad['weight'][0]} and hard "
                       f"{bad['hard'][0]}; a formula is hard or has a finite weight: {AGAIN}")
    return weights


def read_network(data: bytes, config: dict[str, Any], where: str) -> Network:
    """A network from a model file's arrays: each of the shape its configuration makes, float, finite."""
    shapes = network_shapes(config)
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            names = [info.filename for info in archive.infolist()]
            if sorted(names) != sorted(f"{name}.npy" for name in shapes):
                raise BadInput(f"{where}: its {NETWORK} holds {', '.join(sorted(names))}; a {config['cell']} network "
                               f"{'with' if config['prior_layer'] else 'without'} PriorLayer holds "
                               f"{', '.join(sorted(f'{n}.npy' for n in shapes))}: {AGAIN}")
            arrays = {}
            for info in archive.infolist():
                name = info.filename.removesuffix(".npy")
                limit = ARRAY_OVERHEAD + ITEM_BYTES * math.prod(shapes[name])
                arrays[name] = _array(_read(archive, info, limit, f"{where}: {NETWORK}"), name, shapes[name], where)
    except BadInput:
        raise
    except READ_ERRORS as error:
        raise BadInput(f"{where}: its network cannot be read ({error}): {AGAIN}") from None
    if not (arrays["std"] > 0).all():
        raise BadInput(f"{where}: its network's standardisation has a std that is not positive: {AGAIN}")
    return Network.from_state(config, {k: v for k, v in arrays.items() if k not in ("mean", "std")},
                              arrays["mean"], arrays["std"])


def _array(data: bytes, name: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    """One .npy array, its header checked before its data is read: float, the expected shape, finite."""
    stream = io.BytesIO(data)
    major, _ = np.lib.format.read_magic(stream)
    header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
    found, fortran, dtype = header(stream)
    if dtype not in ARRAY_DTYPES or tuple(found) != shape or fortran:
        raise BadInput(f"{where}: its network's {name} is {dtype} of shape {tuple(found)}; its manifest's network "
                       f"makes float of shape {shape}: {AGAIN}")
    array = np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)
    if not np.isfinite(array).all():
        raise BadInput(f"{where}: its network's {name} holds NaN or infinity: {AGAIN}")
    return array
