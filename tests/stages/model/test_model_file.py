"""Hostile model files: mutations of a real exported DESK model, each refused by `mlnseq info` in one line with
exit 2 and no traceback, before anything larger than its bound is read; the real model loads as before."""

from __future__ import annotations

import io
import json
import shutil
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq import export, train
from mlnseq.model import model_file
from mlnseq.model.model_file import AUDIT, MANIFEST, NETWORK, SPEC, WEIGHTS
from mlnseq.recognition.recognizer import Recognizer

runner = CliRunner()
BOMB_BYTES = 2 * 1024**3  # 2 GiB of spaces, deflated to about 2 MB


@pytest.fixture(scope="session")
def exported(tmp_path_factory, desk_mln_workdir) -> dict[str, Path]:
    """Real models of one small DESK workdir (lstm and priorlayer trained 1 epoch in stream mode): combined+filter
    (every member), lstm (manifest and network) and mln (manifest, spec and weights)."""
    workdir = tmp_path_factory.mktemp("hostile") / "work"
    shutil.copytree(desk_mln_workdir, workdir)
    for method in ("lstm", "priorlayer"):
        train.run(workdir, train.TrainOptions(method=method, mode="stream", epochs=1))
    models = {}
    for method, decode in (("combined", "filter"), ("lstm", "none"), ("mln", "none")):
        options = export.ExportOptions(method=method, decode=decode, output=workdir.parent / f"{method}.mlnseq")
        models[method] = export.run(workdir, options).path
    return models


def members(path: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(path) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


def manifest_of(path: Path) -> dict:
    return json.loads(members(path)[MANIFEST])


def write(path: Path, entries: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in entries.items():
            archive.writestr(name, data)
    return path


def resealed(path: Path, manifest: dict | None = None, **changed: bytes) -> dict[str, bytes]:
    """A model's members with some replaced, and its manifest (or ``manifest``) declaring them: right names and
    right digests, wrong contents."""
    entries = members(path)
    own = json.loads(entries.pop(MANIFEST))
    declared = own if manifest is None else manifest
    declared = {k: v for k, v in declared.items() if k not in ("format", "members")}
    entries |= {name.replace("_", "."): data for name, data in changed.items()}
    return model_file.seal(declared, entries)


def npz(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def network_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(members(path)[NETWORK])) as arrays:
        return {name: arrays[name] for name in arrays.files}


def parquet(table: pl.DataFrame) -> bytes:
    buffer = io.BytesIO()
    table.write_parquet(buffer)
    return buffer.getvalue()


def raw_zip(path: Path, stored: dict[str, bytes], deflated: dict[str, tuple[bytes, int, int]]) -> Path:
    """A zip written field by field: ``stored`` members as they are, ``deflated`` ones as (raw deflate stream,
    CRC-32, uncompressed size), so a member of any declared size can be written without compressing it here."""
    local, central = io.BytesIO(), io.BytesIO()
    items = [(n, d, crc, size, 8) for n, (d, crc, size) in deflated.items()]
    items += [(n, d, zlib.crc32(d), len(d), 0) for n, d in stored.items()]
    for name, data, crc, size, method in items:
        offset = local.tell()
        local.write(struct.pack("<4s5H3L2H", b"PK\x03\x04", 20, 0, method, 0, 33, crc, len(data), size,
                                len(name), 0) + name.encode() + data)
        central.write(struct.pack("<4s6H3L5H2L", b"PK\x01\x02", 20, 20, 0, method, 0, 33, crc, len(data), size,
                                  len(name), 0, 0, 0, 0, 0, offset) + name.encode())
    directory = central.getvalue()
    end = struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, len(items), len(items), len(directory), local.tell(), 0)
    path.write_bytes(local.getvalue() + directory + end)
    return path


@pytest.fixture(scope="module")
def spaces():
    """``spaces(n)``: n bytes of spaces (a multiple of 1 MiB) as one raw deflate stream, its CRC-32 and n. Every
    1 MiB block ends in a full flush, so each compresses to the same bytes and nothing is compressed twice."""
    block = b" " * 2**20
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)
    compressed = compressor.compress(block) + compressor.flush(zlib.Z_FULL_FLUSH)
    end = zlib.compressobj(9, zlib.DEFLATED, -15).flush()

    def deflated(size: int) -> tuple[bytes, int, int]:
        crc = 0
        for _ in range(size // len(block)):
            crc = zlib.crc32(block, crc)
        return compressed * (size // len(block)) + end, crc, size

    return deflated


def refused(path: Path, needle: str) -> str:
    done = runner.invoke(app, ["info", str(path)])
    assert done.exit_code == 2, done.output
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in done.output, done.output
    assert needle in lines[0], lines[0]
    assert done.stdout == ""
    return lines[0]


def test_the_real_model_loads_and_its_members_are_within_their_bounds(exported):
    manifest = manifest_of(exported["combined"])
    limits = model_file.member_limits(manifest, "model")
    for name, data in members(exported["combined"]).items():
        assert len(data) <= limits[name], name
        if name != MANIFEST:
            assert manifest["members"][name]["bytes"] == len(data)
    assert set(manifest["members"]) == {SPEC, WEIGHTS, NETWORK, AUDIT} and manifest["formulas"] > 0
    model = Recognizer.load(exported["combined"])
    assert model.weights.height == manifest["formulas"] and model.network.weights["prior.weight"].shape == (7, 14)
    shown = runner.invoke(app, ["info", str(exported["combined"])])
    assert shown.exit_code == 0 and "network.npz" in shown.stdout and "limit" in shown.stdout


@pytest.mark.parametrize("cut", [0, 1, 4, 22, 30, 100, 0.25, 0.5, 0.75, 0.9, 0.99, -200, -40, -22, -21, -1])
def test_a_truncated_model_file_is_refused(exported, tmp_path, cut):
    data = exported["combined"].read_bytes()
    keep = int(cut * len(data)) if isinstance(cut, float) else cut % len(data) if cut < 0 else cut
    refused(_bytes(tmp_path, data[:keep]), "not an mlnseq model file")


def _bytes(folder: Path, data: bytes) -> Path:
    path = folder / "model.mlnseq"
    path.write_bytes(data)
    return path


@pytest.mark.parametrize("member", [MANIFEST, SPEC, WEIGHTS, NETWORK])
@pytest.mark.parametrize("where", [0.0, 0.5, 1.0])
def test_a_flipped_byte_in_each_member_is_refused(exported, tmp_path, member, where):
    data = bytearray(exported["combined"].read_bytes())
    with zipfile.ZipFile(exported["combined"]) as archive:
        info = archive.getinfo(member)
    start = info.header_offset + 30 + len(info.filename)  # the member's bytes (stored: as they are)
    data[start + min(int(where * info.compress_size), info.compress_size - 1)] ^= 0x20
    said = refused(_bytes(tmp_path, bytes(data)), "is corrupted: a member fails the zip's own check (Bad CRC-32")
    assert "its bytes changed since it was written" in said and "truncated or foreign" not in said


@pytest.mark.parametrize("member", [SPEC, WEIGHTS, NETWORK])
def test_a_member_swapped_for_another_models_is_refused(exported, tmp_path, member):
    other = {SPEC: "mln", WEIGHTS: "mln", NETWORK: "lstm"}[member]
    entries = members(exported["combined"])
    swapped = members(exported[other])[member]
    if member == SPEC:  # the two models share their spec and weights: another model's differ
        swapped += b"# another model's spec\n"
    if member == WEIGHTS:
        swapped = parquet(pl.read_parquet(io.BytesIO(swapped)).head(-1))
    assert swapped != entries[member]
    refused(write(tmp_path / "swapped.mlnseq", entries | {member: swapped}), "not the one its manifest declares")


@pytest.mark.parametrize(("member", "needle"), [(NETWORK, "lacks network.npz"), (WEIGHTS, "lacks weights.parquet"),
                                                (MANIFEST, "no manifest.json")])
def test_a_missing_member_is_refused(exported, tmp_path, member, needle):
    entries = {k: v for k, v in members(exported["combined"]).items() if k != member}
    refused(write(tmp_path / "missing.mlnseq", entries), needle)


def test_extra_members_are_refused(exported, tmp_path):
    entries = members(exported["combined"])
    refused(write(tmp_path / "six.mlnseq", entries | {"notes.txt": b"hello"}), "declares 6 members; a model file holds at most 5")
    lstm = members(exported["lstm"])
    refused(write(tmp_path / "unknown.mlnseq", lstm | {"evil.py": b"import os"}), "'evil.py', which is not a model file's member")
    refused(write(tmp_path / "undeclared.mlnseq", lstm | {WEIGHTS: entries[WEIGHTS]}),
            "holds weights.parquet, which its manifest does not declare")
    many = tmp_path / "many.mlnseq"
    with zipfile.ZipFile(many, "w") as archive:
        for i in range(10_000):
            archive.writestr(f"{i}", b"")
    refused(many, "declares 10,000 members")


def test_an_oversized_member_is_refused(exported, tmp_path):
    spec = members(exported["combined"])[SPEC] + b"#" * model_file.SPEC_LIMIT
    refused(write(tmp_path / "big.mlnseq", resealed(exported["combined"], binarize_toml=spec)),
            f"binarize.toml declares {len(spec):,} bytes ({len(spec):,} compressed), over its limit of 1,048,576 bytes")
    manifest = manifest_of(exported["combined"])
    manifest["network"]["model"]["hidden_size"] = 4096  # a network of 67 million numbers
    refused(write(tmp_path / "huge.mlnseq", resealed(exported["combined"], manifest)),
            "its manifest declares a network.npz of up to")


def test_a_zip_bomb_is_refused_before_it_is_inflated(exported, tmp_path, spaces):
    entries = members(exported["combined"])
    bomb = raw_zip(tmp_path / "bomb.mlnseq", {k: v for k, v in entries.items() if k != MANIFEST},
                   {MANIFEST: spaces(BOMB_BYTES)})
    assert bomb.stat().st_size < 3 * 2**20
    with zipfile.ZipFile(bomb) as archive:
        assert archive.getinfo(MANIFEST).file_size == BOMB_BYTES
    refused(bomb, "manifest.json declares 2,147,483,648 bytes")
    stream, crc, _ = spaces(16 * 2**20)
    liar = raw_zip(tmp_path / "liar.mlnseq", {}, {MANIFEST: (stream, crc, 1000)})  # its header says 1,000 bytes
    refused(liar, "is corrupted: a member fails the zip's own check")  # its header lies about its size
    arrays = members_of_bytes(members(exported["combined"])[NETWORK])  # network.npz whose std.npy is a bomb
    inner = raw_zip(tmp_path / "inner.npz", {k: v for k, v in arrays.items() if k != "std.npy"},
                    {"std.npy": spaces(4 * 2**20)}).read_bytes()
    refused(write(tmp_path / "nested.mlnseq", resealed(exported["combined"], network_npz=inner)),
            "network.npz: std.npy declares 4,194,304 bytes")


def members_of_bytes(data: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        return {name: archive.read(name) for name in archive.namelist()}


@pytest.mark.parametrize(("data", "needle"), [
    (b"", "not an mlnseq model file"),
    (b"name,value\n1,2\n", "not an mlnseq model file"),
    (b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 8, "not an mlnseq model file"),
    (np.random.default_rng(0).bytes(50_000), "not an mlnseq model file"),
])
def test_a_file_that_is_not_a_zip_is_refused(tmp_path, data, needle):
    refused(_bytes(tmp_path, data), needle)


def test_a_zip_of_other_compression_or_a_manifest_that_is_not_json_is_refused(exported, tmp_path):
    entries = members(exported["lstm"])
    lzma = tmp_path / "lzma.mlnseq"
    with zipfile.ZipFile(lzma, "w", zipfile.ZIP_LZMA) as archive:
        for name, data in entries.items():
            archive.writestr(name, data)
    refused(lzma, "compressed with method 14")
    refused(write(tmp_path / "deep.mlnseq", entries | {MANIFEST: b"[" * 100_000}), "manifest.json is not JSON")
    refused(write(tmp_path / "list.mlnseq", entries | {MANIFEST: b"[1, 2]"}), "model-file format None")


def test_nan_or_infinity_in_the_network_or_the_weights_is_refused(exported, tmp_path):
    arrays = network_arrays(exported["combined"])
    arrays["h2c.weight"][3, 5] = np.nan
    refused(write(tmp_path / "nan.mlnseq", resealed(exported["combined"], network_npz=npz(arrays))),
            "its network's h2c.weight holds NaN or infinity")
    arrays = network_arrays(exported["combined"]) | {"std": np.zeros(3, dtype=np.float32)}
    refused(write(tmp_path / "std.mlnseq", resealed(exported["combined"], network_npz=npz(arrays))),
            "a std that is not positive")
    weights = pl.read_parquet(io.BytesIO(members(exported["combined"])[WEIGHTS]))
    weights = weights.with_columns(pl.when(pl.int_range(pl.len()) == 7).then(float("inf")).otherwise(pl.col("weight"))
                                   .alias("weight"))
    refused(write(tmp_path / "inf.mlnseq", resealed(exported["combined"], weights_parquet=parquet(weights))),
            "has weight inf and hard False; a formula is hard or has a finite weight")
    weights = weights.with_columns(pl.lit(None, dtype=pl.Boolean).alias("hard"))
    refused(write(tmp_path / "null.mlnseq", resealed(exported["combined"], weights_parquet=parquet(weights))),
            "and hard None; a formula is hard or has a finite weight")


def test_a_spec_that_nests_too_deeply_is_refused(exported, tmp_path):
    spec = b"[[predicate]]\nname = " + b"[" * 100_000
    refused(write(tmp_path / "deep.mlnseq", resealed(exported["mln"], binarize_toml=spec)), "binarize.toml nests too deeply")


def test_shapes_that_disagree_with_the_manifest_are_refused(exported, tmp_path):
    arrays = network_arrays(exported["combined"])
    arrays["rnn.weight_hh_l0"] = arrays["rnn.weight_hh_l0"][:, :16]
    refused(write(tmp_path / "shape.mlnseq", resealed(exported["combined"], network_npz=npz(arrays))),
            "its network's rnn.weight_hh_l0 is float64 of shape (128, 16); its manifest's network makes float of shape (128, 32)")
    arrays = network_arrays(exported["combined"])
    arrays["mean"] = arrays["mean"].astype(object)
    refused(write(tmp_path / "object.mlnseq", resealed(exported["combined"], network_npz=npz(arrays))), "mean is object")
    refused(write(tmp_path / "lstm-net.mlnseq", resealed(exported["combined"], network_npz=members(exported["lstm"])[NETWORK])),
            "a lstm network with PriorLayer holds")
    manifest = manifest_of(exported["combined"])
    manifest["network"]["model"]["n_features"] = 4
    refused(write(tmp_path / "features.mlnseq", resealed(exported["combined"], manifest)),
            "its network's n_features is 4, but the manifest declares 3")
    manifest = manifest_of(exported["combined"]) | {"formulas": 3}
    refused(write(tmp_path / "formulas.mlnseq", resealed(exported["combined"], manifest)),
            "formulas in")


def test_an_unknown_network_type_is_refused(exported, tmp_path):
    manifest = manifest_of(exported["combined"])
    manifest["network"]["model"]["cell"] = "transformer"
    refused(write(tmp_path / "cell.mlnseq", resealed(exported["combined"], manifest)),
            "its network's cell 'transformer' is not one this mlnseq runs")
    manifest = manifest_of(exported["combined"])
    manifest["network"]["name"] = "tcn"
    refused(write(tmp_path / "name.mlnseq", resealed(exported["combined"], manifest)), "network 'tcn' is not one this mlnseq runs")
    manifest = manifest_of(exported["combined"])
    manifest["network"]["model"]["num_layers"] = 2
    refused(write(tmp_path / "layers.mlnseq", resealed(exported["combined"], manifest)), "'model' is not an object of")
    manifest = manifest_of(exported["combined"]) | {"method": "hmm"}
    refused(write(tmp_path / "method.mlnseq", resealed(exported["combined"], manifest)), "method 'hmm'")


def test_classes_and_weights_that_disagree_are_refused(exported, tmp_path):
    manifest = manifest_of(exported["mln"])
    manifest["classes"] = manifest["classes"][:6]
    refused(write(tmp_path / "classes.mlnseq", resealed(exported["mln"], manifest)),
            "weights.parquet has a formula of class 'S7 align and place', which is not one of the manifest's 6 classes")
    weights = pl.read_parquet(io.BytesIO(members(exported["mln"])[WEIGHTS]))
    weights = weights.with_columns(pl.col("formula").str.replace("S3 lift peg", "S9 lift pole", literal=True))
    refused(write(tmp_path / "formula.mlnseq", resealed(exported["mln"], weights_parquet=parquet(weights))),
            "S9 lift pole")
    manifest = manifest_of(exported["mln"])
    manifest["predicates"] = manifest["predicates"][1:]
    refused(write(tmp_path / "predicates.mlnseq", resealed(exported["mln"], manifest)), "binarize.toml makes predicate columns")
    manifest = manifest_of(exported["mln"]) | {"classes": ["a", "a", "b", "c", "d", "e", "f"]}
    refused(write(tmp_path / "twice.mlnseq", resealed(exported["mln"], manifest)), "'classes' is not a list of unique strings")


TCN_MODEL = {"n_features": 3, "n_classes": 7, "hidden_size": 32, "cell": "tcn", "prior_layer": True,
             "kernel_size": 3, "levels": 5, "smoothing": 0.15}


@pytest.mark.parametrize(("change", "needle"), [
    ({"chosen_by_cross_validation": "yes"}, "manifest.json chosen_by_cross_validation is not an object"),
    ({"chosen_by_cross_validation": {"method": "combined"}}, "chosen_by_cross_validation lacks 'name'"),
    ({"network_weight_how": "guessed"}, "network_weight_how 'guessed' is not one this mlnseq runs"),
    ({"network_weight": -1}, "'network_weight' is not null or a finite number from 0"),
    ({"network_weight": "1"}, "'network_weight' is not null or a finite number from 0"),
    ({"paper_floor": "zero"}, "paper_floor 'zero' is not one this mlnseq runs (clamp, shift)"),
    ({"mln_mode": "fast"}, "mln_mode 'fast' is not one this mlnseq runs"),
    ({"decode": "blur"}, "decoder 'blur' is not one this mlnseq runs"),
    ({"decode": "smooth", "lag": None}, "lag must be a whole number of frames"),
    ({"lag": 1.5}, "lag 1.5 is not a whole number of frames"),
    ({"rate_hz": "fast"}, "rate_hz 'fast' is not null or a number >= 0"),
    ({"reading": {"env": {"deep": 1}}}, "'reading' is not an object of option -> value"),
    ({"reading": "table"}, "'reading' is not an object of option -> value"),
    ({"source": 3}, "'source' is not a string"),
    ({"validation_frame_accuracy": 1.5}, "'validation_frame_accuracy' is not null or a finite number from 0 to 1"),
    ({"created": None}, "'created' is not a string"),
    ({"extra": "x"}, "holds 'extra', which is not a field of a format 3 manifest"),
    ({"network": {"mode": "sometimes"}}, "network mode 'sometimes' is not one this mlnseq runs"),
    ({"network": {"kept_epoch": "last"}}, "network 'kept_epoch' is not a count"),
    ({"network": {"seed": 1.5}}, "network 'seed' is not an integer"),
    ({"network": {"prior": "vibes"}}, "network prior 'vibes' is not one this mlnseq runs"),
    ({"network": {"model": TCN_MODEL | {"smoothing": "lots"}}}, "its network's smoothing is 'lots', not a number >= 0"),
    ({"network": {"model": TCN_MODEL | {"smoothing": -1.0}}}, "its network's smoothing is -1.0, not a number >= 0"),
    ({"network": {"model": TCN_MODEL | {"levels": 2.5}}}, "its network's levels is 2.5, not an integer"),
    ({"network": {"model": TCN_MODEL | {"prior_layer": 1}}}, "its network's prior_layer is 1, not true or false"),
    ({"network": {"model": TCN_MODEL | {"kernel_size": 1, "levels": 64}}},
     "kernel_size must be 2 or more and levels at most 16, got 1 and 64"),
    ({"network": {"model": TCN_MODEL | {"kernel_size": 2, "levels": 17}}},
     "kernel_size must be 2 or more and levels at most 16, got 2 and 17"),
])
def test_every_manifest_field_is_checked(exported, tmp_path, change, needle):
    manifest = manifest_of(exported["combined"])
    for key, value in change.items():
        manifest[key] = manifest[key] | value if key == "network" else value
    refused(write(tmp_path / "field.mlnseq", resealed(exported["combined"], manifest)), needle)


@pytest.mark.parametrize("key", ["paper_floor", "network_weight_how", "chosen_by_cross_validation", "reading"])
def test_a_manifest_lacking_a_field_is_refused(exported, tmp_path, key):
    manifest = {k: v for k, v in manifest_of(exported["combined"]).items() if k != key}
    refused(write(tmp_path / "lacks.mlnseq", resealed(exported["combined"], manifest)), f"manifest.json lacks {key!r}")


def test_a_format_2_model_file_is_refused_with_its_remedy(exported, tmp_path):
    entries = members(exported["lstm"])
    old = json.loads(entries[MANIFEST]) | {"format": 2}
    refused(write(tmp_path / "old.mlnseq", entries | {MANIFEST: json.dumps(old).encode()}),
            "is model-file format 2 from mlnseq")


def test_a_learned_network_weight_of_0_is_kept(exported, tmp_path):
    """CLL may learn the weight 0 (the network counts for nothing in the chain): the file loads and decodes with 0."""
    manifest = manifest_of(exported["combined"]) | {"network_weight": 0.0, "network_weight_how": "learned"}
    model = Recognizer(resealed(exported["combined"], manifest), "zero")
    assert model.network_weight == 0.0 and model.manifest.network_weight_how == "learned"
    shown = runner.invoke(app, ["info", str(write(tmp_path / "zero.mlnseq", resealed(exported["combined"], manifest)))])
    assert shown.exit_code == 0 and "0 (learned on out-of-fold predictions)" in shown.stdout
