"""export: one model file (``.mlnseq``) holding all a recogniser needs, for predict, stream and the Python API.

The file is a zip: ``manifest.json`` (format version, mlnseq version, method, decoding and its network
factor weight, classes, features in order, the source, the predicate columns, the network's
configuration, the input digests, notes, the number of formulas, every other member's size and SHA-256),
the predicate spec ``binarize.toml``, the MLN's ``weights.parquet`` and the network's arrays
``network.npz`` (with its standardisation). A method that needs no MLN (lstm, undecoded) carries no spec
and no weights. stages/model_file.py writes and reads it (docs/model-file.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stages import artifacts, model_file, recognizer
from stages.errors import BadInput, check_choice
from stages.recognizer import DECODES, MLN_MODES


@dataclass(frozen=True)
class ExportOptions:
    """Options of `mlnseq export`."""

    method: str = "combined"
    decode: str = "none"
    mln_mode: str = "paper"
    output: Path | None = None  # default: WORKDIR/METHOD[+DECODE].mlnseq

    def validate(self) -> None:
        check_choice("method", self.method, recognizer.METHODS)
        check_choice("decode", self.decode, DECODES)
        check_choice("mln-mode", self.mln_mode, MLN_MODES)

    def output_path(self, workdir: Path) -> Path:
        if self.output is not None:
            return Path(self.output)
        return Path(workdir) / f"{recognizer.decoded_name(self.method, self.decode)}{model_file.MODEL_SUFFIX}"


@dataclass(frozen=True)
class Exported:
    path: Path
    manifest: dict[str, Any]


def run(workdir: Path, options: ExportOptions) -> Exported:
    """Gather a trained method from ``workdir`` into one model file; it is loaded once before it is written."""
    options.validate()
    workdir = Path(workdir)
    frames_path = workdir / artifacts.FRAMES
    frames_meta = artifacts.read_metadata(frames_path, "frames")
    inputs = [frames_path]
    notes: list[str] = []
    network_name = recognizer.network_of(options.method)
    checkpoint = network = None
    if network_name is not None:
        checkpoint = recognizer.load_checkpoint(workdir, network_name, frames_meta)
        inputs.append(artifacts.checkpoint_path(workdir, network_name))
        config = checkpoint.config
        network = {"name": network_name, "mode": config["mode"], "prior": config.get("prior"),
                   "seed": config["seed"], "kept_epoch": config["kept_epoch"], "model": config["model"]}
        if config["mode"] == "segment":
            notes.append(f"its {network_name} network was trained in segment mode, its state reset at every true "
                         "segment boundary, which new recordings and live streams do not give: predict and stream "
                         "run it over whole episodes (`train --mode stream` makes a network for streams)")

    spec_text = weights = None
    columns: list[str] = []
    if recognizer.needs_mln(options.method, options.decode):
        predicates_path, weights_path = workdir / artifacts.PREDICATES, workdir / artifacts.WEIGHTS
        predicates_meta = artifacts.read_metadata(predicates_path, "predicates")
        weights, _ = artifacts.read_table(weights_path, "weights")
        spec_text = predicates_meta["spec"]["text"]
        columns = [c for group in predicates_meta["predicates"].values() for c in group]
        inputs += [predicates_path, weights_path]

    choice = None
    if options.decode != "none" and network_name is not None:
        predicted = recognizer.predict_workdir(workdir, options.mln_mode, (options.decode,), (options.method,))
        choice = predicted.choices[recognizer.decoded_name(options.method, options.decode)]
        notes += [n for n in predicted.notes if "validation part" in n or "uniform transitions" in n]

    manifest = {
        "mlnseq_version": artifacts.package_version(),
        "created": artifacts.created_time(),
        "method": options.method,
        "decode": options.decode,
        "mln_mode": options.mln_mode,
        "network_weight": None if choice is None else choice.weight,
        "validation_frame_accuracy": None if choice is None else choice.accuracy,
        "classes": list(frames_meta["classes"]),
        "features": list(frames_meta["features"]),
        "source": frames_meta.get("source", ""),
        "reading": frames_meta.get("reading") or {"env": frames_meta.get("source", "")},  # how predict reads
        "predicates": columns,
        "network": network,
        "inputs": {p.name: artifacts.file_digest(p) for p in inputs},
        "notes": notes,
    }
    entries = model_file.model_entries(manifest, spec_text, weights, None if checkpoint is None else checkpoint.network)
    recognizer.Recognizer(entries, str(workdir))  # a model that cannot be loaded is not written
    return Exported(model_file.write_model(options.output_path(workdir), entries), manifest)
