"""`mlnseq fit`: a user's recogniser from their recordings in one command.

Composes the stages' own `run` functions (each stays a command of its own): collect, binarize (the spec
suggested from the data unless --spec), formulas (per-frame template and learned transitions unless
--formulas), learn-weights and train (stream mode) with folds, conflate with every decoder, export
--method auto. It takes collect's source options as they are (the same flags, read from collect's signature).
"""

from __future__ import annotations

import importlib.resources
import inspect
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.markup import escape

from mlnseq_cli import collect as collect_cli
from mlnseq.catalog.errors import BadInput
from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, reported_errors

SUGGESTED_SPEC = "suggested.binarize.toml"
FORMULAS = Path(importlib.resources.files("mlnseq") / "specs" / "temporal.mln")
DECODES = ("filter", "viterbi")


HELP = {
    "spec": "Your predicate spec \\[default: one suggested from the training split, written to "
            "suggested.binarize.toml in the workdir].",
    "formulas": "Your formulas (.mln) \\[default: every predicate value => every class, plus learned transitions "
                "between classes].",
    "folds": "Cross-validation folds \\[default: one per training episode, at most 5; blocks of frames with a "
             "single episode].",
    "decode": "filter: online, for live use (predict, stream); viterbi: offline, whole recordings.",
}


def fit_options(
    spec: Annotated[Optional[Path], typer.Option(help=HELP["spec"], dir_okay=False)] = None,
    formulas: Annotated[Optional[Path], typer.Option(help=HELP["formulas"], dir_okay=False)] = None,
    folds: Annotated[Optional[int], typer.Option(help=HELP["folds"], show_default=False)] = None,
    epochs: Annotated[int, typer.Option(help="The network's passes over the training split.")] = 100,
    decode: Annotated[str, typer.Option(help=HELP["decode"])] = "filter",
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="The model file \\[default: "
                                                   "WORKDIR/model.mlnseq].", dir_okay=False)] = None,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """fit's own options (their signature joins collect's below)."""


def fit(**flags: Any) -> None:
    """Recordings to a model file in one command: collect (the same source options), binarize (the spec suggested
    from the training split, or --spec), formulas (or --formulas), learn-weights and train in stream mode with K
    folds, conflate with every decoder, export --method auto into MODEL; prints what it chose and why. Every
    stage's files stay in WORKDIR, so any stage can be rerun on its own."""
    own = {name: flags.pop(name) for name in inspect.signature(fit_options).parameters}
    workdir = Path(own["workdir"])
    if own["decode"] not in DECODES:
        raise typer.BadParameter(f"use {' or '.join(DECODES)}", param_hint="--decode")
    with reported_errors():
        plan = stages(collect_cli.collect_options(**{k: v for k, v in flags.items() if k != "workdir"}), own, workdir)
        run_plan(plan, own, workdir)


def stages(collect_options: Any, own: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Collect and binarize, then the options of the stages after them (K chosen from the frames)."""
    from mlnseq import binarize, collect
    from mlnseq.recognition import folds as folding

    collect_options.validate()
    path, collected = collect.run(workdir, collect_options)
    collect_cli.print_collected(path, collected)
    suggested = None if own["spec"] is not None else workdir / SUGGESTED_SPEC
    _, binarized = binarize.run(workdir, binarize.BinarizeOptions(spec=own["spec"], suggest=suggested))
    columns = binarized.meta["predicates"]
    said = (f"the spec suggested from the training split, {suggested} (copy and edit it, then --spec)"
            if suggested else f"your spec {own['spec']}")
    console.print(f"[green]binarize[/]: {counted(len(columns), 'predicate')}, "
                  f"{counted(sum(map(len, columns.values())), 'column')} from {said}; "
                  f"`mlnseq binarize --table -w {workdir}` shows which separate which classes", highlight=False)
    frames = collected.frames
    k = own["folds"] if own["folds"] is not None else folding.suggested(frames["episode"].to_numpy(),
                                                                          frames["split"].to_numpy())
    if k:
        folds = folding.assign(frames["episode"].to_numpy(), frames["split"].to_numpy(), frames["label"].to_numpy(), k)
        episodes = frames.filter(frames["split"] == "train")["episode"].n_unique()
        console.print(f"folds: {folds.describe()} ({counted(episodes, 'training episode')}"
                      + ("" if own["folds"] is not None else "; fit's default: one per episode, at most 5")
                      + "): cross-validation chooses the network's weight and the method", highlight=False)
    else:
        console.print("folds: none (" + ("--folds 0" if own["folds"] == 0 else "a training split too small for 2")
                      + "): nothing is chosen by cross-validation", highlight=False)
    return {"k": k}


def run_plan(plan: dict[str, Any], own: dict[str, Any], workdir: Path) -> None:
    """formulas, learn-weights, train, conflate and export, each by its own `run`; print what was chosen."""
    from mlnseq import conflate, export, formulas, learn_weights, train
    from mlnseq_cli.train import epoch_progress

    k = plan["k"]
    written = formulas.run(workdir, formulas.FormulasOptions(spec=own["formulas"] or FORMULAS))
    said = (f"your {own['formulas']}" if own["formulas"] else
            f"the built-in {FORMULAS.name}: each predicate value => each class, transitions between classes")
    console.print(f"[green]formulas[/]: {written.path} from {said}", highlight=False)
    _, learned = learn_weights.run(workdir, learn_weights.LearnWeightsOptions(formulas=written.path, folds=k))
    for warning in learned.warnings:
        console.print(f"[yellow]warning[/]: {escape(warning)}")
    console.print(f"[green]learn-weights[/]: {counted(learned.weights.height, 'formula')} weighted "
                  f"({learned.objective})"
                  + (f", and each of the {k} folds' without it" if k else ""), highlight=False)
    options = train.TrainOptions(mode="stream", folds=k, epochs=own["epochs"])
    with epoch_progress("lstm (stream mode)" + (f", then {k} fold networks" if k else ""), own["epochs"]) as progress:
        trained = train.run(workdir, options, progress)
    for warning in trained.trained.warnings:
        console.print(f"[yellow]warning[/]: {escape(warning)}")
    console.print(f"[green]train[/]: {trained.checkpoint} (stream mode: whole episodes, as live frames come"
                  + (f"; {k} fold networks for out-of-fold predictions" if k else "") + ")", highlight=False)
    result = conflate.run(workdir, conflate.ConflateOptions(decode=("none", "filter", "viterbi")))
    console.print(f"[green]conflate[/]: {len(result.methods)} methods, every decoder: {', '.join(result.methods)}",
                  highlight=False)
    exported = export_chosen(k, own, workdir)
    why = "online, as live frames come" if own["decode"] == "filter" else "offline, over whole recordings"
    console.print(f"[green]fit[/]: wrote {exported.path} ({exported.manifest.method}, decode {own['decode']}: {why}); "
                  f"next: `mlnseq predict {exported.path} --source NEW` or `mlnseq stream {exported.path}`",
                  highlight=False)


def export_chosen(k: int, own: dict[str, Any], workdir: Path) -> Any:
    """export --method auto (conflation without folds), its choice said, then the test split's figures."""
    from mlnseq import eval as evaluation, export

    output = own["output"] or workdir / "model.mlnseq"
    method = "auto" if k else "conflation"
    exported = export.run(workdir, export.ExportOptions(method=method, decode=own["decode"], output=output))
    chosen = exported.manifest.chosen_by_cross_validation
    if chosen:
        for name, figures in sorted(chosen.candidates.items(), key=lambda item: -item[1]["segment_accuracy"]):
            console.print(f"  {name:<22} cross-validated: segment {figures['segment_accuracy']:5.1f} %, frame "
                          f"{figures['frame_accuracy']:5.1f} %, edit {figures['edit']:5.1f}", highlight=False)
        score = "segment accuracy" if own["decode"] == "filter" else "mean of segment accuracy and edit"
        console.print(f"chose {chosen.name}: the best {score} by {chosen.folds}-fold cross-validation on the "
                      "training split (the test split unread)", highlight=False)
    else:
        why = "--folds 0" if own["folds"] == 0 else "a training split too small for 2 folds"
        console.print(f"chose conflation (network and MLN) without cross-validation ({why}): nothing to choose on",
                      highlight=False)
    name = chosen.name if chosen else f"conflation+{own['decode']}"
    try:
        scored = evaluation.run(workdir, evaluation.EvalOptions(method=name)).results[name]
    except BadInput:  # no test split: nothing held out to score
        return exported
    console.print(f"test split (held out of everything above): {name} frame accuracy {scored['frame_accuracy']:.1%}, "
                  f"segment accuracy {scored['segment_accuracy']:.1%}", highlight=False)
    return exported


def _joined() -> inspect.Signature:
    """collect's parameters (without its --workdir) then fit's own, for typer to read."""
    source = [p for n, p in inspect.signature(collect_cli.collect, eval_str=True).parameters.items() if n != "workdir"]
    return inspect.Signature(source + list(inspect.signature(fit_options, eval_str=True).parameters.values()))


fit.__signature__ = _joined()  # type: ignore[attr-defined]
