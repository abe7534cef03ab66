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
from mlnseq.catalog.methods import DECODES, METHODS, MLN_MODES, decoded_name, needs_mln, network_of
from mlnseq.catalog.notes import Note


AUTO = "auto"  # --method auto: the decoded method with the best cross-validated figures in the workdir


@dataclass(frozen=True)
class ExportOptions:
    """Options of `mlnseq export`."""

    method: str = "combined"
    decode: str = "none"
    mln_mode: str = "paper"
    output: Path | None = None  # default: WORKDIR/METHOD[+DECODE].mlnseq
    force: bool = False  # overwrite an existing --output (the default output, a workdir artifact, is replaced)

    def validate(self) -> None:
        check_choice("method", self.method, (*METHODS, AUTO))
        if self.method == AUTO and self.decode not in ("filter", "viterbi"):
            raise BadInput(f"--method {AUTO} chooses among decoded methods: add --decode filter (online) or "
                           "--decode viterbi (offline)")
        check_choice("decode", self.decode, DECODES)
        check_choice("mln-mode", self.mln_mode, MLN_MODES)

    def output_path(self, workdir: Path) -> Path:
        if self.output is not None:
            return Path(self.output)
        return Path(workdir) / f"{decoded_name(self.method, self.decode)}{model_file.MODEL_SUFFIX}"


@dataclass(frozen=True)
class Exported:
    path: Path
    manifest: dict[str, Any]


def run(workdir: Path, options: ExportOptions) -> Exported:
    """Gather a trained method from ``workdir`` into one model file; it is loaded once before it is written."""
    options.validate()
    workdir = check_output(options, Path(workdir))
    chosen = None
    if options.method == AUTO:
        chosen = choose_method(workdir, options.decode)
        options = replace(options, method=chosen["method"])
    frames_path = workdir / artifacts.FRAMES
    frames_meta = artifacts.read_metadata(frames_path, "frames")
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
        choice, said = weight_choice(workdir, options)
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
    }
    entries = model_file.model_entries(manifest, spec_text, weights, None if checkpoint is None else checkpoint.network)
    recognizer.Recognizer(entries, str(workdir))  # a model that cannot be loaded is not written
    return Exported(model_file.write_model(options.output_path(workdir), entries), manifest)


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


def choose_method(workdir: Path, decode: str) -> dict[str, Any]:
    """``--method auto``: among the decoded methods conflate predicted in ``workdir`` with ``decode``, the one with
    the best cross-validated choice score (cross_validation.choice_score), with its figures and the others'."""
    from mlnseq.recognition.cross_validation import choice_score

    path = workdir / artifacts.PREDICTIONS
    if not path.exists():
        raise BadInput(f"--method {AUTO} chooses on the cross-validated figures conflate records: {path} not found; "
                       f"run `mlnseq train --folds K` and `mlnseq conflate --decode {decode}` first")
    meta = artifacts.read_metadata(path, "predictions")
    figures = (meta.get("cross_validation") or {}).get("figures") or {}
    candidates = {name: f for name, f in figures.items() if name.endswith(f"+{decode}")}
    if not candidates:
        raise BadInput(f"--method {AUTO}: {workdir} holds no cross-validated {decode} figures; train its networks "
                       f"with folds (`mlnseq train --folds K`, and `mlnseq learn-weights --folds K`), then run "
                       f"`mlnseq conflate --decode {decode}`")
    best = max(candidates, key=lambda name: choice_score(candidates[name], decode))
    return {"method": best.partition("+")[0], "name": best, "figures": candidates[best],
            "score": choice_score(candidates[best], decode), "candidates": candidates,
            "folds": meta["cross_validation"]["folds"]["k"]}


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
