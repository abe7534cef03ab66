"""export: one model file (``.mlnseq``) holding all a recogniser needs, for predict, stream and the Python API.

The file is a zip: ``manifest.json`` (format version, mlnseq version, method, decoding with its lag, latency,
the recordings' rate and the chains' start distribution, its network factor weight, classes, features in order,
the source, the predicate columns, the network's configuration, the input digests, notes, the number of formulas,
every other member's size and SHA-256), the predicate spec ``binarize.toml``, the MLN's ``weights.parquet`` and
the network's arrays ``network.npz`` (with its standardisation). A method that needs no MLN (the network alone,
undecoded) carries no spec and no weights. stages/model/model_file.py writes and reads it,
stages/model/manifest.py checks its manifest (docs/model-file.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from mlnseq.catalog import artifacts
from mlnseq.catalog.decoders import Decoder
from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.methods import (ALIASES, METHODS, MLN_MODES, Method, MLNMode, PaperFloor, decoded_name, member,
                                    needs_mln, network_of, split_name)
from mlnseq.catalog.notes import Note
from mlnseq.mln import formula_sources
from mlnseq.model import model_file
from mlnseq.model.checkpoints import Checkpoint, load_checkpoint
from mlnseq.model.manifest import Manifest, NetworkEntry
from mlnseq.choosing import latency
from mlnseq.recognition import recognizer
from mlnseq.choosing.network_weight import WeightChoice, WeightDecision, decoding_notes
from mlnseq.choosing.workdir_inputs import paper_floor, read_workdir

AUTO = latency.AUTO  # --method auto: the method, decoder and lag with the best cross-validated figures in the workdir


@dataclass(frozen=True)
class ExportOptions:
    """Options of `mlnseq export`."""

    method: Method | str = Method.COMBINED  # a method (``network`` for the network alone), or auto
    decode: str = "none"
    mln_mode: MLNMode = MLNMode.PAPER
    output: Path | None = None  # default: WORKDIR/METHOD[+DECODE].mlnseq
    force: bool = False  # overwrite an existing --output (the default output, a workdir artifact, is replaced)
    lag: int | None = None  # frames: a lagged decoder's lag, or with --method auto the budget
    latency: float | None = None  # seconds: the same where the recordings' rate is known

    def __post_init__(self) -> None:
        object.__setattr__(self, "method", member(Method, self.method, ALIASES))
        object.__setattr__(self, "mln_mode", member(MLNMode, self.mln_mode))

    def named(self) -> ExportOptions:
        """The options with a method or decoder given as commands print it (``conflation+smooth-legal@25``,
        ``--decode smooth-legal@5``) split into method, decode and lag."""
        method, decode, lag = split_name(str(self.method), self.decode, self.lag)
        return replace(self, method=member(Method, method, ALIASES), decode=decode, lag=lag)

    def validate(self) -> None:
        named = self.named()  # a name as commands print it (a sweep's grid too) checked as its parts
        check_choice("method", named.method, ("network", *METHODS, AUTO))
        check_choice("decode", named.decode, [d.value for d in Decoder])
        check_choice("mln-mode", self.mln_mode, MLN_MODES)
        if named.lag is not None and named.lag < 0:
            raise BadInput(f"--lag {named.lag}: a lag is at least 0 frames")
        if self.latency is not None and not self.latency >= 0:
            raise BadInput(f"--latency {self.latency:g}: a latency is at least 0 seconds")
        if named.lag is not None and self.latency is not None:
            raise BadInput("give --lag FRAMES or --latency SECONDS, not both")

    def output_path(self, workdir: Path, decode: str | None = None) -> Path:
        if self.output is not None:
            return Path(self.output)
        return Path(workdir) / f"{decoded_name(self.method, decode or self.decode)}{model_file.MODEL_SUFFIX}"


@dataclass(frozen=True)
class Exported:
    path: Path
    manifest: Manifest


SEGMENT_NOTE = ("its {network} network was trained in segment mode, its state reset at every true segment boundary, "
                "which new recordings and live streams do not give: predict and stream run it over whole episodes "
                "(`train --mode stream` makes a network for streams)")


def run(workdir: Path, options: ExportOptions) -> Exported:
    """Gather a trained method from ``workdir`` into one model file; it is loaded once before it is written."""
    options = options.named()
    options.validate()
    workdir = check_output(options, Path(workdir))
    frames_path = workdir / artifacts.FRAMES
    frames_meta = artifacts.read_metadata(frames_path, "frames")
    picked = latency.pick(workdir, options.method, options.decode, options.lag, options.latency, frames_meta)
    options = replace(options, method=Method(picked.method), decode=picked.decoding.decoder.value)
    inputs, notes = [frames_path], []
    network = network_of(options.method)
    checkpoint = None
    if network is not None:
        checkpoint = load_checkpoint(workdir, network, frames_meta)
        inputs.append(artifacts.checkpoint_path(workdir, network))
        if checkpoint.mode == "segment":
            notes.append(SEGMENT_NOTE.format(network=network))
    spec_text = weights = None
    columns: list[str] = []
    if needs_mln(options.method, options.decode):
        spec_text, weights, columns = _mln(workdir, inputs)
    choice = None
    if options.decode != "none" and network is not None:
        choice, said = weight_choice(workdir, options.method, picked.decoding.name)
        notes += [n.text for n in said]
    floor = paper_floor(workdir, frames_meta)  # as conflate floors the MLN's sums
    manifest = _manifest(options, frames_meta, floor, choice, picked, checkpoint, columns, inputs, notes)
    network = None if checkpoint is None else checkpoint.network
    entries = model_file.model_entries(manifest, spec_text, weights, network)
    made = recognizer.Recognizer(entries, str(workdir))  # a model that cannot be loaded is not written
    audit, said = audit_profile(workdir, made)
    manifest = replace(manifest, notes=manifest.notes + said)
    entries = model_file.model_entries(manifest, spec_text, weights, network, audit)
    recognizer.Recognizer(entries, str(workdir))
    return Exported(model_file.write_model(options.output_path(workdir, picked.decoding.name), entries), manifest)


def audit_profile(workdir: Path, made: recognizer.Recognizer) -> tuple[bytes | None, list[str]]:
    """What `mlnseq audit` needs, learned from the workdir's labelled training recordings (stages/auditing/), or
    the note saying why the model holds none."""
    from mlnseq.auditing.calibration import calibrated

    try:
        return calibrated(workdir, made).to_json(), []
    except BadInput as error:
        return None, [f"no audit profile: {error}"]


def _mln(workdir: Path, inputs: list[Path]) -> tuple[str, Any, list[str]]:
    """The predicate spec's text, the MLN's weights and the predicate columns (their files added to ``inputs``)."""
    predicates_path, weights_path = workdir / artifacts.PREDICATES, workdir / artifacts.WEIGHTS
    predicates_meta = artifacts.read_metadata(predicates_path, "predicates")
    weights, weights_meta = artifacts.read_table(weights_path, "weights")
    inputs += [predicates_path, weights_path]
    formulas = formula_sources.formulas_of(weights_path, weights_meta)
    if formulas is not None:  # each formula's file, line and text as written, for explanations
        text = formulas.read_text(encoding="utf-8")
        weights = formula_sources.annotated(weights, formula_sources.written_lines(text, formulas))
    columns = [c for group in predicates_meta["predicates"].values() for c in group]
    return predicates_meta["spec"]["text"], weights, columns


def _manifest(options: ExportOptions, frames_meta: dict[str, Any], floor: PaperFloor, choice: WeightChoice | None,
              picked: latency.Picked, checkpoint: Checkpoint | None, columns: list[str], inputs: list[Path],
              notes: list[str]) -> Manifest:
    network = None
    if checkpoint is not None:
        config = checkpoint.config
        network = NetworkEntry(network_of(options.method), config["mode"], config.get("prior"), config["seed"],
                               config["kept_epoch"], config["model"])
    source = frames_meta.get("source", "")
    return Manifest(
        mlnseq_version=artifacts.package_version(), created=artifacts.created_time(), method=options.method,
        decode=options.decode, mln_mode=options.mln_mode, paper_floor=floor,
        network_weight=None if choice is None else choice.weight,
        network_weight_how=None if choice is None else choice.how, chosen_by_cross_validation=picked.chosen,
        validation_frame_accuracy=None if choice is None else choice.accuracy,
        classes=list(frames_meta["classes"]), features=list(frames_meta["features"]), source=source,
        reading=frames_meta.get("reading") or {"env": source},  # how predict reads
        predicates=columns, network=network, inputs={p.name: artifacts.file_digest(p) for p in inputs}, notes=notes,
        lag=picked.decoding.lag, latency_s=picked.latency_s, rate_hz=picked.rate_hz, start=picked.start)


def check_output(options: ExportOptions, workdir: Path) -> Path:
    """The workdir, once the output is checked: refuse an --output that exists (without --force), or that is one
    of the workdir's other files (its frames, predicates, weights, checkpoints...), even with --force."""
    path = options.output_path(workdir)
    folders = (workdir.resolve(), (workdir / artifacts.MODELS_DIR).resolve())
    if path.is_file() and path.resolve().parent in folders and path.suffix != model_file.MODEL_SUFFIX:
        raise BadInput(f"--output {path} is {workdir}'s own {path.name}, which the model is made from; name a "
                       f"{model_file.MODEL_SUFFIX} file")
    if options.output is not None and path.exists() and not options.force:
        raise BadInput(f"{path} exists; pass --force to overwrite it, or name another file")
    return workdir


def weight_choice(workdir: Path, method: Method, decode: str) -> tuple[WeightChoice, list[Note]]:
    """The network factor's weight of the one decoded network method exported, decided as conflate decides it
    (recognition/network_weight.py), and the notes that bear on it; the weight conflate learned where it is still
    the workdir's (``conflated_weight``)."""
    from mlnseq.mln.factors import MLNFactors

    recorded = conflated_weight(workdir, decoded_name(method, decode))
    if recorded is not None:
        return recorded

    network = network_of(method)
    inputs = read_workdir(workdir, (network,))
    mln = MLNFactors.from_weights(inputs.mln.weights, inputs.mln.columns, inputs.classes)
    decision = WeightDecision(inputs, mln)
    return decision.choice(method, decode), decision.notes([network])


def conflated_weight(workdir: Path, name: str) -> tuple[WeightChoice, list[Note]] | None:
    """The weight conflate learned for ``name`` on the out-of-fold predictions, and the notes deciding it says, where
    predictions.parquet records it (conflate chose it: no --network-weight): the same decision, not made twice over
    every frame; None otherwise. A predictions.parquet whose inputs (networks, their out-of-fold predictions,
    weights, predicates, frames) changed since is refused as it is everywhere (StaleArtifact)."""
    import polars as pl

    from mlnseq.catalog.methods import WeightSource

    path = workdir / artifacts.PREDICTIONS
    if not path.exists():
        return None
    meta = artifacts.read_metadata(path, "predictions")
    record = (meta.get("network_weights") or {}).get(name)
    if meta.get("network_weight_option") is not None or not record or record.get("how") != str(WeightSource.LEARNED):
        return None
    weights = pl.read_parquet(workdir / artifacts.WEIGHTS, columns=["weight", "hard", "temporal"])
    temporal = bool(weights.filter((pl.col("weight") != 0) | pl.col("hard"))["temporal"].any())  # as MLNFactors counts
    return WeightChoice(float(record["weight"]), None, {}, WeightSource.LEARNED), decoding_notes(temporal, [])
