"""`mlnseq fit`: a user's recogniser from their recordings in one command, the face of `mlnseq.fit`
(stages/pipeline/fit.py). It takes collect's source options as they are (read from collect's signature) and
prints each stage's line as it finishes, then the choice."""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.markup import escape

from mlnseq_cli import collect as collect_cli
from mlnseq_cli.binarize import print_learned
from mlnseq_cli.conflate import summary
from mlnseq_cli.console import DEFAULT, WorkdirOption, console, reported_errors
from mlnseq_cli.progress import epoch_progress
from mlnseq.conflate import ConflateResult
from mlnseq.pipeline import fit as pipeline

SEED_HELP = "Seed of the networks' initial weights and batch order (and fetch's resets and action noise)."


def fit_options(
    spec: Annotated[Optional[Path], typer.Option(help="Your predicate spec \\[default: predicates learned from the training split, written to learned.binarize.toml in the workdir].", dir_okay=False)] = None,
    formulas: Annotated[Optional[Path], typer.Option(help="Your formulas (.mln) \\[default: the formulas learned with the predicates, learned.formulas.mln; with --spec, every predicate value => every class, plus learned transitions between classes].", dir_okay=False)] = None,
    folds: Annotated[Optional[int], typer.Option(help="Cross-validation folds \\[default: one per training episode, at most 5; blocks of frames cut where the task restarts with a single episode].", show_default=False)] = None,
    epochs: Annotated[int, typer.Option(help="The network's passes over the training split.")] = 100,
    latency: Annotated[Optional[float], typer.Option(help="Seconds the recogniser may wait before it decides a frame: fit chooses among the methods, decoders and lags within it \\[default: lag 0, each frame decided as it comes].", show_default=False)] = None,
    lag: Annotated[Optional[int], typer.Option(help="The same budget in frames.", show_default=False)] = None,
    offline: Annotated[bool, typer.Option("--offline", help="No budget: offline decoders (viterbi, posterior) over whole recordings too.")] = False,
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="The model file \\[default: WORKDIR/model.mlnseq, replaced].", dir_okay=False)] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite --output if it exists, and a learned spec or formulas file edited by hand.")] = False,
    executor: Annotated[str, typer.Option(help="Where the logic (binarize, formulas, learn-weights) and the networks (train) run: local (in this process, one after the other), processes (side by side on this machine's cores) or slurm (two cluster jobs, needs --profile); processes and slurm run on Snakemake.")] = pipeline.Executor.LOCAL.value,
    profile: Annotated[Optional[Path], typer.Option(help="With --executor slurm: a Snakemake profile folder (config.yaml): the cluster's partition, resources, status command.", file_okay=False)] = None,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """fit's own options (their signature joins collect's below)."""


def fit(**flags: Any) -> None:
    """Recordings to a model file in one command: collect (the same source options), binarize (predicates and formulas
    learned from the training split by cross-validation, or --spec), formulas (or --formulas), learn-weights, train in
    stream mode with K folds, conflate with every decoder within the latency budget, export --method auto into MODEL;
    prints what it chose and why. Recordings without labels in --source are labelled by aligning them to the labelled
    ones, and ranked in WORKDIR/label_next.csv by what labelling each would teach. Every stage's files stay in WORKDIR."""
    own = {name: flags.pop(name) for name in inspect.signature(fit_options).parameters}
    workdir = own.pop("workdir")
    with reported_errors():
        source = collect_cli.collect_options(**{k: v for k, v in flags.items() if k != "workdir"})
        fitted = pipeline.fit(source, workdir, pipeline.FitOptions(**own, seed=source.seed), Printed())
    for line in fitted.said:
        say(line)
    say(f"[green]fit[/]: {fitted.wrote}")


def say(line: str, warnings: tuple[str, ...] = ()) -> None:
    for warning in warnings:
        console.print(f"[yellow]warning[/]: {escape(warning)}")
    console.print(line, highlight=False)


class Printed(pipeline.Observer):
    """Each stage's line as it finishes."""

    def collected(self, step: pipeline.CollectStep) -> None:
        collect_cli.print_collected(step.path, step.collected)
        for line in step.said:
            say(line)

    def binarized(self, step: pipeline.BinarizeStep) -> None:
        if step.learned:
            print_learned(step.learned, step.spec)
        say(f"[green]binarize[/]: {step.said}")

    def folded(self, step: pipeline.FoldStep) -> None:
        say(f"folds: {step.said}")

    def formulas_written(self, step: pipeline.FormulasStep) -> None:
        say(f"[green]formulas[/]: {step.said}")

    def weights_learned(self, step: pipeline.WeightsStep) -> None:
        say(f"[green]learn-weights[/]: {step.said}", tuple(step.learned.warnings))

    def training(self, epochs: int, folds: int) -> Any:
        return epoch_progress("lstm (stream mode)" + (f", stopped where its {folds} networks without a fold score best "
                                                      "on it (those first)" if folds else ""), epochs)

    def trained(self, step: pipeline.TrainStep) -> None:
        say(f"[green]train[/]: {step.said}", tuple(step.result.trained.warnings))

    def conflated(self, step: ConflateResult) -> None:
        summary(step, step.path.parent)

    def parts_running(self, executor: pipeline.Executor, logs: Path) -> None:
        where = "as SLURM jobs" if executor is pipeline.Executor.SLURM else "as processes side by side"
        say(f"binarize, formulas and learn-weights, and train, {where} (their logs: {logs}) ...")


def _joined() -> inspect.Signature:
    """collect's parameters (without its --workdir) then fit's own, for typer to read."""
    source = [p for n, p in inspect.signature(collect_cli.collect, eval_str=True).parameters.items() if n != "workdir"]
    source = [p.replace(annotation=Annotated[int, typer.Option(help=SEED_HELP)]) if p.name == "seed" else p
              for p in source]
    return inspect.Signature(source + list(inspect.signature(fit_options, eval_str=True).parameters.values()))


fit.__signature__ = _joined()  # type: ignore[attr-defined]
