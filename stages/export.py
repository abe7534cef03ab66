"""export: one model file (``.mlnseq``) holding all a recogniser needs, for predict, stream and the Python API.

The file is a zip: ``manifest.json`` (format version, mlnseq version, method, decoding and its network
factor weight, classes, features in order, the source, the predicate columns, the network's
configuration, the input digests, notes, the number of formulas, every other member's size and SHA-256),
the predicate spec ``binarize.toml``, the MLN's ``weights.parquet`` and the network's arrays
``network.npz`` (with its standardisation). A method that needs no MLN (lstm, undecoded) carries no spec
and no weights. stages/model/model_file.py writes and reads it (docs/model-file.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from mlnseq.catalog import artifacts
from mlnseq.model import model_file
from mlnseq.recognition import network_weight, recognizer
from mlnseq.model.checkpoints import load_checkpoint
from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.decoders import Decoder, Decoding
from mlnseq.catalog.methods import METHODS, MLN_MODES, decoded_name, needs_mln, network_of
from mlnseq.catalog.notes import Note


AUTO = "auto"  # --method auto: the method, decoder and lag with the best cross-validated figures in the workdir
SCORED_ALWAYS = ("none", "filter", "viterbi")  # decoders export runs without asking conflate whether it scored them


@dataclass(frozen=True)
class ExportOptions:
    """Options of `mlnseq export`."""

    method: str = "combined"
    decode: str = "none"
    mln_mode: str = "paper"
    output: Path | None = None  # default: WORKDIR/METHOD[+DECODE].mlnseq
    lag: int | None = None  # frames: a lagged decoder's lag, or with --method auto the budget
    latency: float | None = None  # seconds: the same where the recordings' rate is known

    def validate(self) -> None:
        check_choice("method", self.method, (*METHODS, AUTO))
        check_choice("decode", self.decode, [d.value for d in Decoder])
        check_choice("mln-mode", self.mln_mode, MLN_MODES)
        if self.lag is not None and self.lag < 0:
            raise BadInput(f"--lag {self.lag}: a lag is at least 0 frames")
        if self.latency is not None and not self.latency >= 0:
            raise BadInput(f"--latency {self.latency:g}: a latency is at least 0 seconds")
        if self.lag is not None and self.latency is not None:
            raise BadInput("give --lag FRAMES or --latency SECONDS, not both")

    def output_path(self, workdir: Path, decode: str | None = None) -> Path:
        if self.output is not None:
            return Path(self.output)
        return Path(workdir) / f"{decoded_name(self.method, decode or self.decode)}{model_file.MODEL_SUFFIX}"


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
    options, decoding, chosen, timing = decoding_of(workdir, options, frames_meta)
    inputs = [frames_path]
    notes: list[str] = []
    network_name = network_of(options.method)
    checkpoint = network = None
    if network_name is not None:
        checkpoint = load_checkpoint(workdir, network_name, frames_meta)
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
    if needs_mln(options.method, options.decode):
        predicates_path, weights_path = workdir / artifacts.PREDICATES, workdir / artifacts.WEIGHTS
        predicates_meta = artifacts.read_metadata(predicates_path, "predicates")
        weights, _ = artifacts.read_table(weights_path, "weights")
        spec_text = predicates_meta["spec"]["text"]
        columns = [c for group in predicates_meta["predicates"].values() for c in group]
        inputs += [predicates_path, weights_path]

    choice = None
    if options.decode != "none" and network_name is not None:
        choice, said = weight_choice(workdir, replace(options, decode=decoding.name))
        notes += [n.text for n in said]

    manifest = {
        "mlnseq_version": artifacts.package_version(),
        "created": artifacts.created_time(),
        "method": options.method,
        "decode": options.decode,
        "mln_mode": options.mln_mode,
        "network_weight": None if choice is None else choice.weight,
        "network_weight_how": None if choice is None else choice.how,
        "chosen_by_cross_validation": chosen,
        "validation_frame_accuracy": None if choice is None else choice.accuracy,
        "classes": list(frames_meta["classes"]),
        "features": list(frames_meta["features"]),
        "source": frames_meta.get("source", ""),
        "reading": frames_meta.get("reading") or {"env": frames_meta.get("source", "")},  # how predict reads
        "predicates": columns,
        "network": network,
        "inputs": {p.name: artifacts.file_digest(p) for p in inputs},
        "notes": notes,
        **timing,
    }
    entries = model_file.model_entries(manifest, spec_text, weights, None if checkpoint is None else checkpoint.network)
    recognizer.Recognizer(entries, str(workdir))  # a model that cannot be loaded is not written
    return Exported(model_file.write_model(options.output_path(workdir, decoding.name), entries), manifest)


def decoding_of(workdir: Path, options: ExportOptions,
                frames_meta: dict[str, Any]) -> tuple[ExportOptions, Decoding, dict[str, Any] | None, dict[str, Any]]:
    """The method and decoding to export (``--method auto``: chosen by cross-validation within the budget), the
    choice's record, and the manifest's lag, latency, rate and start distribution."""
    from mlnseq.recognition import latency

    rate = latency.rate_of(frames_meta)
    decoder = Decoder(options.decode)
    chosen = None
    if options.method == AUTO:
        budget = latency.budget_frames(options.lag, options.latency, rate, str(workdir))
        meta = _scored(workdir, f"--method {AUTO}")
        figures = (meta.get("cross_validation") or {}).get("figures") or {}
        if not figures:
            raise BadInput(f"--method {AUTO}: {workdir} holds no cross-validated figures; train its networks with "
                           f"folds (`mlnseq train --folds K`, and `mlnseq learn-weights --folds K`), then run "
                           f"`mlnseq conflate --decode all`")
        best, fitting = latency.choose(figures, budget, None if decoder is Decoder.NONE else decoder,
                                    bool(meta.get("hard_rules")), str(workdir))
        chosen = {**best.record(), "figures": best.figures, "budget_frames": budget,
                  "candidates": {c.name: c.figures for c in fitting}, "folds": meta["cross_validation"]["folds"]["k"]}
        options, decoding = replace(options, method=best.method, decode=best.decoding.decoder.value), best.decoding
    else:
        lag = options.lag
        if options.latency is not None and decoder.lagged:
            lag = latency.budget_frames(None, options.latency, rate, str(workdir))
        if decoder.lagged and lag is None:
            raise BadInput(f"--decode {decoder.value} waits a number of frames: give --lag FRAMES "
                           "(or --latency SECONDS)")
        decoding = Decoding(decoder, lag)
        if decoder.value not in SCORED_ALWAYS:
            name = decoded_name(options.method, decoding.name)
            if name not in _scored(workdir, f"--decode {decoding.name}").get("methods", []):
                raise BadInput(f"--decode {decoding.name}: {workdir} has no {name} predictions; run `mlnseq conflate "
                               f"--decode {decoder.value}" + (f" --lags {decoding.lag}`" if decoder.lagged else "`")
                               + " first")
    timing = {"lag": decoding.lag, "latency_s": decoding.latency_s(rate) if not decoder.offline else None,
              "rate_hz": rate, "start": None}
    if decoding.decoder is not Decoder.NONE:
        timing["start"] = start_distribution(workdir).tolist()
    return options, decoding, chosen, timing


def _scored(workdir: Path, option: str) -> dict[str, Any]:
    path = workdir / artifacts.PREDICTIONS
    if not path.exists():
        raise BadInput(f"{option} reads the figures conflate records: {path} not found; run `mlnseq conflate "
                       "--decode all` first")
    return artifacts.read_metadata(path, "predictions")


def start_distribution(workdir: Path):
    """The chains' start distribution (log [C]) from the training split's episodes, as conflate fits it."""
    import numpy as np
    import polars as pl

    from mlnseq.recognition.decoding import start_of

    frames = pl.read_parquet(workdir / artifacts.FRAMES, columns=["episode", "label", "split"])
    meta = artifacts.read_metadata(workdir / artifacts.FRAMES, "frames")
    train = frames["split"].to_numpy() != "test"
    return start_of(frames["label"].to_numpy().astype(np.int64), frames["episode"].to_numpy(), train,
                    len(meta["classes"]))


def weight_choice(workdir: Path, options: ExportOptions) -> tuple[network_weight.WeightChoice, list[Note]]:
    """The network factor's weight of the one decoded network method exported, as conflate chooses it, and
    the notes that bear on it."""
    from mlnseq.recognition.cross_validation import test_weight
    from mlnseq.mln.factors import MLNFactors
    from mlnseq.recognition.workdir_inputs import read_workdir

    network = network_of(options.method)
    inputs = read_workdir(workdir, (network,))
    run_, mln_inputs = inputs.networks[network], inputs.mln
    mln = MLNFactors.from_weights(mln_inputs.weights, mln_inputs.columns, inputs.classes)
    if inputs.folds is not None and network in inputs.folds.log_probs:
        return (network_weight.WeightChoice(test_weight(options.method, inputs, mln), None, {}, "learned"),
                network_weight.decoding_notes(mln.temporal, []))
    unvalidated = [] if run_.checkpoint.config.get("val_spans") else [network]
    notes = network_weight.decoding_notes(mln.temporal, unvalidated)
    choice = network_weight.choose(options.method, options.decode, mln, mln_inputs.evidence, inputs.data.episodes,
                                   run_.parts, run_.log_probs, inputs.data.labels)
    return choice, notes
