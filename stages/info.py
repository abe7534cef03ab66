"""info: what a model file holds, as rows of words (the command prints them as a table)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mlnseq import networks
from mlnseq.catalog import methods
from mlnseq.model import model_file


@dataclass(frozen=True)
class ModelInfo:
    """A model file's manifest and its described rows (name, value), in the order they are shown."""

    manifest: dict[str, Any]
    rows: list[tuple[str, str]]


def describe(manifest: dict[str, Any], entries: dict[str, bytes], path: Path) -> list[tuple[str, str]]:
    """The rows `mlnseq info` shows for a loaded model's manifest and members."""
    weight = manifest.get("network_weight")
    accuracy = manifest.get("validation_frame_accuracy")
    rows = [
        ("method", methods.decoded_name(manifest["method"], manifest["decode"])),
        ("network factor weight", "–" if weight is None else f"{weight:g}"
         + ("" if accuracy is None else f" (validation frame accuracy {accuracy:.1%})")),
        ("classes", ", ".join(manifest["classes"])),
        ("features", ", ".join(manifest["features"])),
        ("source", manifest.get("source", "")),
        ("decoder", _decoder_row(manifest)),
    ]
    chosen = manifest.get("chosen_by_cross_validation")
    if chosen:
        figures = chosen["figures"]
        rows.append(("chosen by", f"{chosen['folds']}-fold cross-validation among "
                                  f"{', '.join(sorted(chosen['candidates']))}: segment accuracy "
                                  f"{figures['segment_accuracy']:.1f} %, "
                                  f"frame accuracy {figures['frame_accuracy']:.1f} %, "
                                  f"edit {figures['edit']:.1f}, F1@50 {figures['f1_50']:.1f}"))
    if manifest.get("network_weight_how") == "learned":
        rows[1] = ("network factor weight", f"{weight:g} (learned on out-of-fold predictions)")
    network = manifest.get("network")
    if network:
        model_config = network["model"]
        rows.append(("network", f"{network['name']}: {networks.describe(model_config)}, "
                                f"{network['mode']} mode, seed {network['seed']}, epoch {network['kept_epoch']}"
                                + (f", PriorLayer input {network['prior']}" if network.get("prior") else "")))
    if model_file.WEIGHTS in entries:
        columns = len(manifest["predicates"])
        rows.append(("MLN", f"{columns} predicate column{'' if columns == 1 else 's'}, mln-mode {manifest['mln_mode']}"))
    limits = model_file.member_limits(manifest, path)
    rows.append(("members", ", ".join(f"{name} {len(data):,} bytes (limit {limits[name]:,})"
                                      for name, data in entries.items())))
    rows += [("written by", f"mlnseq {manifest['mlnseq_version']}, {manifest['created']}, format {manifest['format']}"),
             ("inputs", ", ".join(f"{k} {v}" for k, v in manifest["inputs"].items()))]
    return rows


def run(path: Path) -> ModelInfo:
    """Read and check the model file at ``path`` (as the recogniser loads it) and describe it."""
    from mlnseq.recognition.recognizer import Recognizer

    entries = model_file.read_model(path)
    manifest = Recognizer(entries, str(path)).manifest  # loads, or says in one line why it cannot
    return ModelInfo(manifest, describe(manifest, entries, path))


def _decoder_row(manifest: dict[str, Any]) -> str:
    """The decoder, its lag in frames and seconds, and whether it starts chains from a fitted start distribution."""
    decode, lag, latency = manifest["decode"], manifest.get("lag"), manifest.get("latency_s")
    if decode == "none":
        return "none (per frame)"
    if decode in ("viterbi", "posterior", "posterior-legal"):
        text = f"{decode} (offline: whole recordings; a stream filters)"
    else:
        seconds = "" if latency is None else f" = {latency:g} s"
        rate = "" if manifest.get("rate_hz") else " (frame rate unknown)"
        text = f"{decode}, lag {lag or 0} frame(s){seconds}{rate if lag else ''}"
    return text + (", start distribution fitted" if manifest.get("start") is not None else "")
