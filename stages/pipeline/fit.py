"""``mlnseq.fit``: a user's recordings to a model file, each stage run by its own ``run``, and what it chose.

collect (collect's own options; recordings without labels labelled by alignment to the labelled ones), binarize
(predicates and formulas learned from the training split by cross-validation, or ``spec``), formulas (the learned
ones, or ``formulas``; with ``spec`` alone the built-in temporal.mln), learn-weights and train (stream mode) with K
folds, conflate with every decoder within the latency budget, export --method auto within it (conflation+filter
without folds), then the test split's figures of the choice and the network alone. Every stage's file stays in the
workdir, so any stage can be rerun on its own. The stages are imported where they run: ``import mlnseq`` and
``mlnseq fit --help`` stay light.
"""

from __future__ import annotations

import importlib.resources
import os
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from mlnseq.catalog.errors import BadInput, check_choice
from mlnseq.catalog.methods import Method, decoded_name
from mlnseq.catalog.notes import MISSING_INPUT
from mlnseq.choosing import latency
from mlnseq.pipeline import parts
from mlnseq.pipeline.parts import Executor
from mlnseq.sources.splits import Holdout
from mlnseq.pipeline.steps import (BinarizeStep, CollectStep, Fitted, FoldStep, FormulasFrom, FormulasStep, TestFigures,
                                   TrainStep, WeightsStep)

if TYPE_CHECKING:
    from mlnseq.collect import CollectOptions
    from mlnseq.conflate import ConflateResult
    from mlnseq.export import Exported
    from mlnseq.labelling.label_next import Proposal
    from mlnseq.sources.recording import Collected
    from mlnseq.train import EpochDone, TrainOptions, TrainResult

__all__ = ["fit", "FitOptions", "Observer", "Fitted", "CollectStep", "BinarizeStep", "FoldStep", "FormulasStep",
           "WeightsStep", "TrainStep", "TestFigures", "FormulasFrom"]

TEMPLATE = Path(importlib.resources.files("mlnseq") / "specs" / "temporal.mln")  # formulas for a spec alone
MODEL = "model.mlnseq"  # in the workdir, without --output
SETTLED = {"optimizer": "averaged", "members": 3, "updates": 3000}  # how fit trains its networks (docs/reproduce.md)


@dataclass(frozen=True)
class FitOptions:
    """fit's own options (the source's are collect's ``CollectOptions``)."""

    spec: Path | None = None  # your predicate spec; None: predicates learned from the training split
    formulas: Path | None = None  # your formulas; None: the learned ones (with ``spec``: the built-in temporal.mln)
    folds: int | None = None  # cross-validation folds; None: one per training episode, at most 5
    epochs: int = 100  # the network's passes over the training split, at most (networks/updates.py)
    seed: int = 0  # the networks' seed (and fetch's simulation's)
    latency: float | None = None  # seconds a frame may wait (at the recordings' rate)
    lag: int | None = None  # the same in frames; neither (and not offline): lag 0
    offline: bool = False  # no budget: offline decoders over whole recordings too
    output: Path | None = None  # the model file; None: WORKDIR/model.mlnseq (replaced)
    force: bool = False  # overwrite an existing output, and a learned spec or formulas edited by hand
    executor: Executor = Executor.LOCAL  # where the logic and the networks run (pipeline/parts.py)
    profile: Path | None = None  # --executor slurm: a Snakemake profile folder

    def __post_init__(self) -> None:
        for name in ("spec", "formulas", "output", "profile"):  # a path given as text
            if isinstance(getattr(self, name), str):
                object.__setattr__(self, name, Path(getattr(self, name)))
        if isinstance(self.executor, str):
            check_choice("executor", self.executor, [e.value for e in Executor])
            object.__setattr__(self, "executor", Executor(self.executor))

    def validate(self) -> None:
        """What can be checked before any work (the networks' options too: ``train_options``)."""
        given = [n for n in ("latency", "lag") if getattr(self, n) is not None] + (["offline"] if self.offline else [])
        if len(given) > 1:
            raise BadInput(f"give one of --latency, --lag and --offline, not {' and '.join('--' + g for g in given)}")
        if self.output is not None and Path(self.output).exists() and not self.force:
            raise BadInput(f"--output {self.output} exists: pass --force to overwrite it, or name another file")
        if self.spec is not None and not Path(self.spec).is_file():
            raise BadInput(f"--spec {self.spec} not found: point it at a .binarize.toml file")
        if self.formulas is not None and not Path(self.formulas).is_file():
            raise BadInput(f"--formulas {self.formulas} not found: give a .mln file of formulas")
        self.train_options(self.folds).validate()
        parts.check(self.executor, self.profile)

    def train_options(self, folds: int | None) -> TrainOptions:
        """train's: an LSTM in stream mode (whole episodes, as live frames come) with ``folds`` fold networks, trained
        to settle (``SETTLED``: averaged SGD, stopped by the folds, the mean of 3 networks)."""
        from mlnseq.train import TrainOptions

        return TrainOptions(mode="stream", folds=folds, epochs=self.epochs, seed=self.seed, **SETTLED)


class Observer:
    """What ``fit`` says as it goes: each method is called as its stage finishes, with the stage's typed result;
    here each says nothing (fit's default). A caller overrides those it shows (``mlnseq fit`` prints every one)."""

    def collected(self, step: CollectStep) -> None: ...

    def binarized(self, step: BinarizeStep) -> None: ...

    def folded(self, step: FoldStep) -> None: ...

    def formulas_written(self, step: FormulasStep) -> None: ...

    def weights_learned(self, step: WeightsStep) -> None: ...

    def training(self, epochs: int, folds: int) -> AbstractContextManager[Callable[[EpochDone], None]]:
        """Held open while the networks train (the network, then ``folds`` fold networks); what it gives hears each
        epoch of the network."""
        return nullcontext(lambda done: None)

    def trained(self, step: TrainStep) -> None: ...

    def conflated(self, step: ConflateResult) -> None: ...

    def parts_running(self, executor: Executor, logs: Path) -> None:
        """The logic and the networks start as jobs (``executor`` not local; their logs in ``logs``): the stages'
        methods follow, in their order, once both have finished."""


def fit(source: CollectOptions, workdir: str | os.PathLike[str], options: FitOptions = FitOptions(),
        observer: Observer | None = None) -> Fitted:
    """Recordings to a model file: every stage by its own ``run`` into ``workdir``, choosing by cross-validation
    within the latency budget; ``observer`` hears each stage as it finishes. Bad options and inputs raise
    ``mlnseq.BadInput`` (options before any work)."""
    from mlnseq import train

    observer = observer or Observer()
    source.validate()
    options.validate()
    workdir = Path(workdir)
    source = replace(source, holdout=source.holdout or Holdout.UNLESS_FEW,  # few labelled recordings: all train
                     align=True)  # recordings without labels: labelled by alignment to the labelled ones
    collected = _collect(source, workdir, options)
    observer.collected(collected)
    if options.executor is not Executor.LOCAL:
        binarized, folding, formulas, weights, trained = _elsewhere(collected, workdir, options, observer)
    elif parts.beside(collected.collected.frames):
        binarized, folding, formulas, weights, trained = _beside(collected, workdir, options, observer)
    else:
        binarized = _binarize(workdir, options)
        observer.binarized(binarized)
        folding = _folds(collected.collected, options.folds)
        observer.folded(folding)
        formulas = _formulas(workdir, options, binarized)
        observer.formulas_written(formulas)
        weights = _weights(workdir, formulas, folding.k)
        observer.weights_learned(weights)
        with observer.training(options.epochs, folding.k) as progress:
            result = train.run(workdir, options.train_options(folding.k), progress)
        trained = TrainStep(result, folding.k)
        observer.trained(trained)
    conflated = _conflate(workdir, collected.budget, bool(weights.learned.weights["hard"].any()))
    observer.conflated(conflated)
    exported, standing = _export(workdir, options, folding.k, collected.budget)
    method, decoding = latency.FALLBACK
    test = held_out(workdir, [standing.chosen.name if standing else decoded_name(method, decoding.name),
                              Method.NETWORK.value])
    proposal, files = _label_next(workdir, collected.collected, standing)
    return Fitted(exported=exported, standing=standing, test=test, collected=collected, binarized=binarized,
                  folding=folding, formulas=formulas, weights=weights, trained=trained, conflated=conflated,
                  proposal=proposal, proposal_files=files)


def _elsewhere(collected: CollectStep, workdir: Path, options: FitOptions, observer: Observer
               ) -> tuple[BinarizeStep, FoldStep, FormulasStep, WeightsStep, TrainStep]:
    """The logic and the networks as jobs of ``options.executor`` (pipeline/parts.py), side by side; the observer
    hears each stage once both have finished, in the order a local run says them."""
    folding = _folds(collected.collected, options.folds)
    out = parts.write_plan(workdir, (options, folding.k))
    observer.parts_running(options.executor, out / "logs")
    done = parts.run(workdir, options.executor, options.profile)
    (binarized, formulas, weights), trained = done["logic"], _restored(*done["network"])
    return _told(observer, binarized, folding, formulas, weights, trained)


def _beside(collected: CollectStep, workdir: Path, options: FitOptions, observer: Observer
            ) -> tuple[BinarizeStep, FoldStep, FormulasStep, WeightsStep, TrainStep]:
    """The logic in a second process of this machine while this one trains the networks (``parts.beside``); the
    observer hears the training as it goes, then the logic's stages and the training's end, in a local run's order."""
    from mlnseq import train

    folding = _folds(collected.collected, options.folds)
    with parts.logic_beside(workdir, (options, folding.k)) as logic:
        with observer.training(options.epochs, folding.k) as progress:
            result = train.run(workdir, options.train_options(folding.k), progress)
        binarized, formulas, weights = logic()
    return _told(observer, binarized, folding, formulas, weights, TrainStep(result, folding.k))


def _told(observer: Observer, binarized: BinarizeStep, folding: FoldStep, formulas: FormulasStep, weights: WeightsStep,
          trained: TrainStep) -> tuple[BinarizeStep, FoldStep, FormulasStep, WeightsStep, TrainStep]:
    """The parts' stages, finished side by side, said to ``observer`` in the order a local run says them."""
    observer.binarized(binarized)
    observer.folded(folding)
    observer.formulas_written(formulas)
    observer.weights_learned(weights)
    observer.trained(trained)
    return binarized, folding, formulas, weights, trained


def logic_part(workdir: Path, options: FitOptions, k: int) -> tuple[BinarizeStep, FormulasStep, WeightsStep]:
    """fit's logic: binarize, formulas and learn-weights with ``k`` folds."""
    binarized = _binarize(workdir, options)
    formulas = _formulas(workdir, options, binarized)
    return binarized, formulas, _weights(workdir, formulas, k)


def run_part(part: str, workdir: str) -> None:
    """One of fit's parts as a job (pipeline/parts.py): the logic (binarize, formulas, learn-weights) or the network
    (train), by the plan in the workdir; its result written back for fit, or the error fit raises."""
    from mlnseq import train
    from mlnseq.catalog.errors import MlnseqError

    options, k = parts.read_plan(Path(workdir))
    try:
        if part == "logic":
            result: object = logic_part(Path(workdir), options, k)
        else:
            trained = train.run(Path(workdir), options.train_options(k))
            model = trained.trained.model  # torch's module travels as its weights (it holds its type's module)
            result = (replace(trained, trained=replace(trained.trained, model=None)), k, model.config,
                      model.state_dict())
    except MlnseqError as error:  # fit says it as a local run would
        parts.write_result(Path(workdir), f"{part}.error", error)
        raise SystemExit(f"error: {error}") from None
    parts.write_result(Path(workdir), part, result)


def _restored(result: TrainResult, k: int, config: object, state: dict) -> TrainStep:
    """The network part's result with its torch module built again from its weights."""
    from mlnseq.networks.classifier import SequenceClassifier

    model = SequenceClassifier(config)
    model.load_state_dict(state)
    return TrainStep(replace(result, trained=replace(result.trained, model=model)), k)


def _label_next(workdir: Path, collected: Collected,
                standing: latency.Standing | None) -> tuple[Proposal | None, tuple[Path, ...]]:
    """The unlabelled recordings (where every one was clicked, the clicked ones) ranked by what labelling each would
    teach, and their proposed phases: the labels fit trained on, or the decoding of the conflation of the network
    and the MLN (a model file made for it and removed) where it cross-validates better; an earlier fit's ranking
    removed where there is nothing to rank."""
    from mlnseq import export
    from mlnseq.labelling import label_next
    from mlnseq.recognition.recognizer import Recognizer

    ranking, clicked = label_next.candidates(collected.meta)
    if not ranking:
        label_next.remove(workdir)
        return None, ()
    meta = collected.meta
    checked = (meta.get("aligned") or meta.get("clicks_filled") or {}).get("checked")
    proposed, why = label_next.chosen(checked, standing.chosen.figures["frame_accuracy"] if standing else None)
    model = workdir / ".label_next.mlnseq"
    try:
        export.run(workdir, export.ExportOptions(method=Method.CONFLATION.value, decode="filter", output=model,
                                                 force=True))
        proposal = label_next.propose(Recognizer.load(model), collected.frames, collected.meta["episode_names"],
                                      ranking, clicked, proposed, why)
    finally:
        model.unlink(missing_ok=True)
    return proposal, label_next.write(workdir, proposal)


def _collect(source: CollectOptions, workdir: Path, options: FitOptions) -> CollectStep:
    """collect, then the budget at the recordings' rate (a --latency the rate cannot say is refused here)."""
    from mlnseq import collect

    path, collected = collect.run(workdir, source)
    rate = latency.rate_of(collected.meta)
    return CollectStep(path, collected, rate, latency.fit_budget(options.lag, options.latency, options.offline, rate))


def _binarize(workdir: Path, options: FitOptions) -> BinarizeStep:
    from mlnseq import binarize
    from mlnseq.catalog import artifacts
    from mlnseq.learning.learned_files import formulas_path

    suggested = None if options.spec is not None else workdir / artifacts.LEARNED_SPEC
    path, binarized = binarize.run(workdir, binarize.BinarizeOptions(spec=options.spec, suggest=suggested,
                                                                     replace=options.force))
    learned = binarized.meta.get("learned") or None
    spec = suggested if suggested is not None else Path(options.spec)
    return BinarizeStep(path, binarized, spec, learned, formulas_path(spec) if learned else None)


def _folds(collected: Collected, asked: int | None) -> FoldStep:
    """K folds of the training split: as asked, else one per training episode (at most 5; blocks of frames where
    there is one episode), 0 where it is too small for 2."""
    from mlnseq.catalog import artifacts
    from mlnseq.choosing import folds as folding

    frames = artifacts.labelled(collected.frames)  # recordings without labels are in no fold
    episodes, splits, labels = (frames[c].to_numpy() for c in ("episode", "split", "label"))
    k = asked if asked is not None else folding.suggested(episodes, splits, labels=labels)
    cut = folding.assign(episodes, splits, labels, k) if k else None
    return FoldStep(k, cut, asked, frames.filter(frames["split"] == "train")["episode"].n_unique())


def _formulas(workdir: Path, options: FitOptions, binarized: BinarizeStep) -> FormulasStep:
    from mlnseq import formulas

    if options.formulas is not None:
        spec, origin = Path(options.formulas), FormulasFrom.YOURS
    elif binarized.learned_formulas is not None:
        spec, origin = binarized.learned_formulas, FormulasFrom.LEARNED
    else:
        spec, origin = TEMPLATE, FormulasFrom.TEMPLATE
    return FormulasStep(formulas.run(workdir, formulas.FormulasOptions(spec=spec)), spec, origin)


def _weights(workdir: Path, formulas: FormulasStep, k: int) -> WeightsStep:
    from mlnseq import learn_weights
    from mlnseq.catalog import artifacts

    _, learned = learn_weights.run(workdir, learn_weights.LearnWeightsOptions(formulas=formulas.written.path, folds=k))
    return WeightsStep(learned, workdir / artifacts.LEARNED_MLN, k)


def _conflate(workdir: Path, budget: int | None, hard_rules: bool) -> ConflateResult:
    """conflate with every decoder and lag within the budget. fit trains the network and learns the weights itself:
    the inputs conflate finds missing are the networks fit does not train (priorlayer), so their notes are not said."""
    from mlnseq import conflate

    decoders, lags = latency.scored_within(budget, hard_rules)
    result = conflate.run(workdir, conflate.ConflateOptions(decode=tuple(d.value for d in decoders), lags=lags))
    return replace(result, notes=[n for n in result.notes if n.code != MISSING_INPUT])


def _export(workdir: Path, options: FitOptions, k: int, budget: int | None
            ) -> tuple[Exported, latency.Standing | None]:
    """export --method auto within the budget (with folds; else conflation+filter), and its choice said back with
    the runner-up and the network alone."""
    from mlnseq import export
    from mlnseq.catalog import artifacts
    from mlnseq.model import model_file
    from mlnseq.model.manifest import MANIFEST

    output = options.output if options.output is not None else workdir / MODEL
    method, decoding = latency.FALLBACK
    exported = export.run(workdir, export.ExportOptions(method=latency.AUTO, lag=budget, output=output, force=True)
                          if k else export.ExportOptions(method=method, decode=decoding.decoder.value, output=output,
                                                         force=True))
    entries = model_file.read_model(exported.path)  # the manifest as written, its members and formulas counted
    exported = replace(exported, manifest=model_file.parse_manifest(entries[MANIFEST], exported.path))
    chosen = exported.manifest.chosen_by_cross_validation
    if chosen is None:
        return exported, None
    cross = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")["cross_validation"]
    return exported, latency.standing(cross, chosen.name, chosen.candidates)


def held_out(workdir: Path, names: list[str]) -> dict[str, TestFigures]:
    """The test split's frame and segment accuracy of ``names`` (none where there is no test split)."""
    from mlnseq import eval as evaluation

    figures = {}
    for name in dict.fromkeys(names):
        try:
            scored = evaluation.run(workdir, evaluation.EvalOptions(method=name)).results[name]
        except BadInput:  # no test split: nothing held out to score
            return {}
        figures[name] = TestFigures(scored["frame_accuracy"], scored["segment_accuracy"])
    return figures
