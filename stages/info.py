"""info: what a model file holds, as rows of words (the command prints them as a table)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mlnseq import networks
from mlnseq.catalog import methods
from mlnseq.catalog.methods import WeightSource
from mlnseq.model import model_file
from mlnseq.model.manifest import Chosen, Manifest


@dataclass(frozen=True)
class ModelInfo:
    """A model file's manifest and its described rows (name, value), in the order they are shown."""

    manifest: Manifest
    rows: list[tuple[str, str]]


def weight_text(manifest: Manifest) -> str:
    """The network factor's weight and how it was set, or '–'."""
    weight, accuracy = manifest.network_weight, manifest.validation_frame_accuracy
    if weight is None:
        return "–"
    if manifest.network_weight_how == WeightSource.LEARNED:
        return f"{weight:g} (learned on out-of-fold predictions)"
    return f"{weight:g}" + ("" if accuracy is None else f" (validation frame accuracy {accuracy:.1%})")


def chosen_text(chosen: Chosen) -> str:
    figures = chosen.figures
    return (f"{chosen.folds}-fold cross-validation among {', '.join(sorted(chosen.candidates))}: segment accuracy "
            f"{figures['segment_accuracy']:.1f} %, frame accuracy {figures['frame_accuracy']:.1f} %, "
            f"edit {figures['edit']:.1f}, F1@50 {figures['f1_50']:.1f}")


def describe(manifest: Manifest, entries: dict[str, bytes], path: Path) -> list[tuple[str, str]]:
    """The rows `mlnseq info` shows for a loaded model's manifest and members."""
    rows = [
        ("method", methods.decoded_name(manifest.method, manifest.decode)),
        ("network factor weight", weight_text(manifest)),
        ("classes", ", ".join(manifest.classes)),
        ("features", ", ".join(manifest.features)),
        ("source", manifest.source),
        ("decoder", _decoder_row(manifest)),
        *reading_rows(manifest.reading or {}),
    ]
    if manifest.chosen_by_cross_validation is not None:
        rows.append(("chosen by", chosen_text(manifest.chosen_by_cross_validation)))
    network = manifest.network
    if network is not None:
        rows.append(("network", f"{network.name}: {networks.describe(network.model)}, {network.mode} mode, "
                                f"seed {network.seed}, epoch {network.kept_epoch}"
                                + (f", PriorLayer input {network.prior}" if network.prior else "")))
    if model_file.WEIGHTS in entries:
        columns = len(manifest.predicates)
        rows.append(("MLN", f"{columns} predicate column{'' if columns == 1 else 's'}, mln-mode {manifest.mln_mode}, "
                            f"paper floor {manifest.paper_floor}"))
    if model_file.AUDIT in entries:
        rows.append(("audit", audit_text(entries[model_file.AUDIT], path)))
    limits = model_file.member_limits(manifest, path)
    rows.append(("members", "\n".join(f"{name} {len(data):,} bytes (limit {limits[name]:,})"
                                      for name, data in entries.items())))
    rows += [("written by", f"mlnseq {manifest.mlnseq_version}, {manifest.created}, format {manifest.format}"),
             ("inputs", ", ".join(f"{k} {v}" for k, v in manifest.inputs.items()))]
    return rows


def reading_rows(reading: dict[str, Any]) -> list[tuple[str, str]]:
    """How the model's recordings were read, as `predict` will read new ones (the manifest's ``reading``)."""
    said = [f"--env {reading['env']}"] if reading.get("env") else []
    if reading.get("topics"):
        said.append(f"topics {', '.join(reading['topics'])}")
    if reading.get("rate"):
        said.append(f"at {reading['rate']:g} Hz")
    if reading.get("label_topic"):
        said.append(f"labels from {reading['label_topic']}")
    elif reading.get("label_column") and reading.get("env") not in ("rosbag", "fetch", "desk"):
        said.append(f"label column {reading['label_column']}")
    said += [f"{key.split('_')[0]} column {reading[key]}" for key in ("episode_column", "time_column")
             if reading.get(key)]
    if reading.get("labels_unit"):
        said.append(f"intervals in {reading['labels_unit']}")
    return [("reading", "; ".join(said))] if said else []


def run(path: Path) -> ModelInfo:
    """Read and check the model file at ``path`` (as the recogniser loads it) and describe it."""
    from mlnseq.recognition.recognizer import Recognizer

    entries = model_file.read_model(path)
    manifest = Recognizer(entries, str(path)).manifest  # loads, or says in one line why it cannot
    return ModelInfo(manifest, describe(manifest, entries, path))


def _decoder_row(manifest: Manifest) -> str:
    """The decoder, its lag in frames and seconds, and whether it starts chains from a fitted start distribution."""
    decode, lag, latency = manifest.decode, manifest.lag, manifest.latency_s
    if decode == "none":
        return "none (per frame)"
    if decode in ("viterbi", "posterior", "posterior-legal"):
        text = f"{decode} (offline: whole recordings; a stream filters)"
    else:
        seconds = "" if latency is None else f" = {latency:g} s"
        rate = "" if manifest.rate_hz else " (frame rate unknown)"
        text = f"{decode}, lag {lag or 0} frame(s){seconds}{rate if lag else ''}"
    return text + (", start distribution fitted" if manifest.start is not None else "")


def audit_text(data: bytes, path: Path) -> str:
    """What `mlnseq audit` learned: the labelled orders, rules and allowances, and how they were chosen."""
    from mlnseq.auditing.profile import Profile

    profile = Profile.read(data, path)
    calibration = profile.calibration
    allowances = ", ".join(f"{check} {value:.3g}" for check, value in sorted(profile.allowances.items()))
    order = " > ".join(profile.classes[k] for k in profile.phases)
    accuracy = "" if calibration.accuracy is None else f"; its decoding {calibration.accuracy:.1%} right on them"
    accuracy += "" if calibration.trusted else ", not to be trusted"
    return (f"{len(profile.orders)} labelled recordings ({order}), {len(profile.rules)} rules; allowances "
            f"{allowances or 'the least'} ({calibration.how}, {calibration.flagged} of {calibration.recordings} "
            f"flagged by allowances set without them{accuracy})")
