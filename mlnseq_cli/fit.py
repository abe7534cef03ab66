"""`mlnseq fit`: a user's recogniser from their recordings in one command.

Composes the stages' own `run` functions (each stays a command of its own): collect, binarize (predicates and
formulas learned from the training split unless --spec: `binarize --suggest`), formulas (the learned ones unless
--formulas; with --spec alone, the per-frame template and learned transitions), learn-weights and train (stream
mode) with folds, conflate with every decoder within the latency budget, export --method auto within it. It takes
collect's source options as they are (the same flags, read from collect's signature).
"""

from __future__ import annotations

import importlib.resources
import inspect
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.markup import escape

from mlnseq_cli import collect as collect_cli
from mlnseq.catalog.errors import BadInput
from mlnseq.sources.splits import FEW_LABELLED, Holdout
from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, fail, reported_errors

SUGGESTED_SPEC = "learned.binarize.toml"
FORMULAS = Path(importlib.resources.files("mlnseq") / "specs" / "temporal.mln")
ONLINE = ("filter", "filter-legal", "smooth", "smooth-legal", "lagviterbi", "lagviterbi-legal")  # within a budget


HELP = {
    "spec": "Your predicate spec \\[default: predicates learned from the training split, written to "
            "learned.binarize.toml in the workdir].",
    "formulas": "Your formulas (.mln) \\[default: the formulas learned with the predicates, learned.formulas.mln; "
                "with --spec, every predicate value => every class, plus learned transitions between classes].",
    "folds": "Cross-validation folds \\[default: one per training episode, at most 5; blocks of frames cut where "
             "the task restarts with a single episode].",
    "latency": "Seconds the recogniser may wait before it decides a frame: fit chooses among the methods, decoders "
               "and lags within it \\[default: lag 0, each frame decided as it comes].",
    "lag": "The same budget in frames.",
    "offline": "No budget: offline decoders (viterbi, posterior) over whole recordings too.",
}


def fit_options(
    spec: Annotated[Optional[Path], typer.Option(help=HELP["spec"], dir_okay=False)] = None,
    formulas: Annotated[Optional[Path], typer.Option(help=HELP["formulas"], dir_okay=False)] = None,
    folds: Annotated[Optional[int], typer.Option(help=HELP["folds"], show_default=False)] = None,
    epochs: Annotated[int, typer.Option(help="The network's passes over the training split.")] = 100,
    latency: Annotated[Optional[float], typer.Option(help=HELP["latency"], show_default=False)] = None,
    lag: Annotated[Optional[int], typer.Option(help=HELP["lag"], show_default=False)] = None,
    offline: Annotated[bool, typer.Option("--offline", help=HELP["offline"])] = False,
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="The model file \\[default: "
                                                   "WORKDIR/model.mlnseq].", dir_okay=False)] = None,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """fit's own options (their signature joins collect's below)."""


def fit(**flags: Any) -> None:
    """Recordings to a model file in one command: collect (the same source options), binarize (predicates and formulas
    learned from the training split by cross-validation, or --spec), formulas (or --formulas), learn-weights and train
    in stream mode with K folds, conflate with every decoder within the latency budget, export --method auto into
    MODEL; prints what it chose and why. Every stage's files stay in WORKDIR, so any stage can be rerun on its own."""
    own = {name: flags.pop(name) for name in inspect.signature(fit_options).parameters}
    workdir = Path(own["workdir"])
    given = [name for name in ("latency", "lag") if own[name] is not None] + (["offline"] if own["offline"] else [])
    if len(given) > 1:
        raise typer.BadParameter(f"give one of --latency, --lag and --offline, not {' and '.join(given)}",
                                 param_hint="--" + given[1])
    if own["output"] is not None and Path(own["output"]).exists():
        raise fail(f"--output {own['output']} exists: remove it or name another file (fit writes a new model)", 2)
    with reported_errors():
        options = collect_cli.collect_options(**{k: v for k, v in flags.items() if k != "workdir"})
        plan = stages(replace(options, holdout=options.holdout or Holdout.UNLESS_FEW), own, workdir)  # few labels
        run_plan(plan, own, workdir)


def stages(collect_options: Any, own: dict[str, Any], workdir: Path) -> dict[str, Any]:
    """Collect and binarize, then the options of the stages after them (K chosen from the frames)."""
    from mlnseq import binarize, collect
    from mlnseq.catalog import artifacts
    from mlnseq.choosing import folds as folding
    from mlnseq.choosing.latency import rate_of
    from mlnseq_cli.binarize import print_learned

    collect_options.validate()
    path, collected = collect.run(workdir, collect_options)
    collect_cli.print_collected(path, collected)
    splits = collected.frames["split"]
    n_labelled = collected.frames.filter(splits != "unlabelled")["episode"].n_unique()
    if n_labelled < FEW_LABELLED and not (splits == "test").any():
        console.print(f"{counted(n_labelled, 'labelled recording')}, fewer than {FEW_LABELLED}: every one trains, "
                      "none is spent on a test split; the cross-validated figures are the estimate", highlight=False)
    suggested = None if own["spec"] is not None else workdir / SUGGESTED_SPEC
    _, binarized = binarize.run(workdir, binarize.BinarizeOptions(spec=own["spec"], suggest=suggested))
    learned = binarized.meta.get("learned")
    if learned:
        print_learned(learned, suggested)
    columns = binarized.meta["predicates"]
    said = f"the learned spec {suggested}" if suggested else f"your spec {own['spec']}"
    console.print(f"[green]binarize[/]: {counted(len(columns), 'predicate')}, "
                  f"{counted(sum(map(len, columns.values())), 'column')} from {said}; "
                  f"`mlnseq binarize --table -w {workdir}` shows which separate which classes", highlight=False)
    frames = artifacts.labelled(collected.frames)  # recordings without labels are in no fold
    episodes, splits, labels = (frames[c].to_numpy() for c in ("episode", "split", "label"))
    k = own["folds"] if own["folds"] is not None else folding.suggested(episodes, splits)
    if k:
        cut = folding.assign(episodes, splits, labels, k)
        n_train = frames.filter(frames["split"] == "train")["episode"].n_unique()
        console.print(f"folds: {cut.describe()} ({counted(n_train, 'training episode')}"
                      + ("" if own["folds"] is not None else "; fit's default: one per episode, at most 5")
                      + "): cross-validation chooses the network's weight and the method", highlight=False)
    else:
        console.print("folds: none (" + ("--folds 0" if own["folds"] == 0 else "a training split too small for 2")
                      + "): nothing is chosen by cross-validation", highlight=False)
    formulas = own["formulas"] or (Path(learned["formulas"]) if learned else FORMULAS)
    return {"k": k, "formulas": formulas, "learned": bool(learned) and own["formulas"] is None,
            "rate": rate_of(collected.meta)}


def budget(own: dict[str, Any], rate: float | None) -> int | None:
    """The latency budget in frames: None offline, else --lag, else --latency at the recordings' rate, else 0."""
    from mlnseq.choosing.latency import budget_frames

    if own["offline"]:
        return None
    if own["lag"] is None and own["latency"] is None:
        return 0
    return budget_frames(own["lag"], own["latency"], rate, "the recordings")


def conflate_options(frames: int | None, hard: bool) -> Any:
    """Every decoder within the budget, at every lag of conflate's default lags within it and at the budget; the
    -legal forms only where the formulas have hard rules (without, they decode as the free forms)."""
    from mlnseq import conflate
    from mlnseq.catalog.decoders import DEFAULT_LAGS, Decoder

    decoders = [d for d in Decoder if d is Decoder.NONE or hard or not d.value.endswith("-legal")]
    if frames is None:
        return conflate.ConflateOptions(decode=tuple(d.value for d in decoders))
    lags = tuple(sorted({lag for lag in DEFAULT_LAGS if lag <= frames} | {frames}))
    return conflate.ConflateOptions(decode=tuple(d.value for d in decoders if d is Decoder.NONE or (
        d.value in ONLINE)), lags=lags)


def run_plan(plan: dict[str, Any], own: dict[str, Any], workdir: Path) -> None:
    """formulas, learn-weights, train, conflate and export, each by its own `run`; print what was chosen."""
    from mlnseq import conflate, formulas, learn_weights, train
    from mlnseq_cli.conflate import summary
    from mlnseq_cli.train import epoch_progress

    k = plan["k"]
    written = formulas.run(workdir, formulas.FormulasOptions(spec=plan["formulas"]))
    said = ("the formulas learned with the predicates" if plan["learned"] else f"your {own['formulas']}"
            if own["formulas"] else f"the built-in {FORMULAS.name}: each predicate value => each class, transitions")
    console.print(f"[green]formulas[/]: {written.path} from {said} ({plan['formulas']})", highlight=False)
    _, learned = learn_weights.run(workdir, learn_weights.LearnWeightsOptions(formulas=written.path, folds=k))
    for warning in learned.warnings:
        console.print(f"[yellow]warning[/]: {escape(warning)}")
    console.print(f"[green]learn-weights[/]: {counted(learned.weights.height, 'formula')} weighted "
                  f"({learned.objective}), each with its weight in {workdir / 'learned.mln'}"
                  + (f", and each of the {k} folds' without it" if k else ""), highlight=False)
    options = train.TrainOptions(mode="stream", folds=k, epochs=own["epochs"])
    with epoch_progress("lstm (stream mode)" + (f", then {k} fold networks" if k else ""), own["epochs"]) as progress:
        trained = train.run(workdir, options, progress)
    for warning in trained.trained.warnings:
        console.print(f"[yellow]warning[/]: {escape(warning)}")
    console.print(f"[green]train[/]: {trained.checkpoint} (stream mode: whole episodes, as live frames come"
                  + (f"; {k} fold networks for out-of-fold predictions" if k else "") + ")", highlight=False)
    frames_budget = budget(own, plan["rate"])
    result = conflate.run(workdir, conflate_options(frames_budget, bool(learned.weights["hard"].any())))
    summary(result, workdir)
    exported = export_chosen(k, own, frames_budget, workdir)
    why = ("offline, over whole recordings" if frames_budget is None else "online, as live frames come"
           if not frames_budget else f"within {counted(frames_budget, 'frame')} of each frame")
    console.print(f"[green]fit[/]: wrote {exported.path} ({exported.manifest.method}, decode {exported.manifest.decode}"
                  f"{'' if exported.manifest.lag is None else f' at lag {exported.manifest.lag}'}: {why}); next: "
                  f"`mlnseq predict {exported.path} --source NEW` or `mlnseq stream {exported.path}`", highlight=False)


def export_chosen(k: int, own: dict[str, Any], frames_budget: int | None, workdir: Path) -> Any:
    """export --method auto within the budget (conflation without folds), its choice, the runner-up and the network
    alone said with their cross-validated figures, then the test split's figures of the choice and the network."""
    from mlnseq import export
    from mlnseq.catalog import artifacts
    from mlnseq.choosing.latency import candidates, ranked

    output = own["output"] or workdir / "model.mlnseq"
    options = (export.ExportOptions(method="auto", lag=frames_budget, output=output, force=True) if k else
               export.ExportOptions(method="conflation", decode="filter", output=output, force=True))
    exported = export.run(workdir, options)
    chosen = exported.manifest.chosen_by_cross_validation
    if not chosen:
        why = "--folds 0" if own["folds"] == 0 else "a training split too small for 2 folds"
        console.print(f"chose conflation+filter (network and MLN) without cross-validation ({why}): nothing to choose "
                      "on", highlight=False)
        test_figures(workdir, ["conflation+filter", "lstm"])
        return exported
    cross = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")["cross_validation"]
    order = ranked([c for c in candidates(cross["figures"], cross.get("fold_frame_accuracy"))
                    if c.name in chosen.candidates])  # those export chose among: within the budget
    best = next(c for c in order if c.name == chosen.name)
    others = [c for c in order if c is not best]
    shown = [(best, "chose")] + [(c, "runner-up") for c in others[:1]]
    shown += [(c, "network alone") for c in others[1:] if c.name == "lstm"]
    for candidate, role in shown:
        figures = candidate.figures
        console.print(f"  {role + ':':<15}{candidate.name:<24} cross-validated {figures['segment_accuracy']:5.1f} / "
                      f"{figures['frame_accuracy']:5.1f} / {figures['edit']:5.1f} (segment / frame / edit), mean "
                      f"{candidate.score[0]:5.1f}", highlight=False)
    console.print(f"chose {chosen.name} of {len(order)} candidates within the budget by {chosen.folds}-fold "
                  "cross-validation on the training split: among those with the network alone's frame accuracy or "
                  "more and within one standard error of the best frame accuracy, the best mean of segment "
                  "accuracy, frame accuracy and edit (the test split unread; docs/choosing.md)", highlight=False)
    test_figures(workdir, [chosen.name, "lstm"])
    return exported


def test_figures(workdir: Path, names: list[str]) -> None:
    """The test split's frame and segment accuracy of ``names`` (nothing when there is no test split)."""
    from mlnseq import eval as evaluation

    said = []
    for name in dict.fromkeys(names):
        try:
            scored = evaluation.run(workdir, evaluation.EvalOptions(method=name)).results[name]
        except BadInput:  # no test split: nothing held out to score
            return
        said.append(f"{name} frame accuracy {scored['frame_accuracy']:.1%}, segment accuracy "
                    f"{scored['segment_accuracy']:.1%}")
    console.print(f"test split (held out of everything above): {'; '.join(said)}", highlight=False)


def _joined() -> inspect.Signature:
    """collect's parameters (without its --workdir) then fit's own, for typer to read."""
    source = [p for n, p in inspect.signature(collect_cli.collect, eval_str=True).parameters.items() if n != "workdir"]
    return inspect.Signature(source + list(inspect.signature(fit_options, eval_str=True).parameters.values()))


fit.__signature__ = _joined()  # type: ignore[attr-defined]
