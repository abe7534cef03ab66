"""The mlnseq application: the commands in pipeline order (``COMMANDS``) and the command line's own machinery: the
global options accepted anywhere on the line, the project file loaded before a command runs, a usage error said in
one line.

A command's module, and the stage behind it with its libraries (torch, MuJoCo, matplotlib), is imported
only when that command runs or shows its own help; `mlnseq --help` lists the commands by the summaries
below and imports none of them.
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import importlib
import os
import sys
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any, NamedTuple, Optional

import typer
from typer.core import TyperCommand

from mlnseq_cli.flags import FlagCommand, FlagGroup


class Command(NamedTuple):
    module: str  # in mlnseq_cli
    function: str  # the typer command function, or a typer.Typer for a group of commands
    summary: str  # its line in `mlnseq --help`; `mlnseq COMMAND --help` shows the docstring


COMMANDS = {
    "collect": Command("collect", "collect", "Make or import a dataset's frames: WORKDIR/frames.parquet."),
    "binarize": Command("binarize", "binarize", "Turn frames into boolean predicates: WORKDIR/predicates.parquet."),
    "formulas": Command("formulas", "formulas", "Write the domain knowledge as WORKDIR/formulas.mln."),
    "learn-weights": Command("learn_weights", "learn_weights",
                             "Learn the formulas' weights on the training split: WORKDIR/weights.parquet."),
    "train": Command("train", "train", "Fit a network (--cell lstm, gru or tcn), alone or with the MLN PriorLayer: "
                     "WORKDIR/models/."),
    "conflate": Command("conflate", "conflate",
                        "Run every trained model and the MLN on all frames and combine them: "
                        "WORKDIR/predictions.parquet."),
    "fit": Command("fit", "fit", "Your recordings to a model file in one command: every stage, with folds, choosing by "
                   "cross-validation."),
    "eval": Command("eval", "evaluate", "Score the predictions on the test split: WORKDIR/metrics.parquet."),
    "report": Command("report", "report", "The paper's tables and figures from a `make reproduce` run: REPORT.md."),
    "export": Command("export", "export", "Gather a trained method into one model file: WORKDIR/METHOD.mlnseq."),
    "info": Command("info", "info", "Print what a model file holds."),
    "predict": Command("predict", "predict", "Recognise new recordings with a model file: per-frame classes."),
    "explain": Command("explain", "explain", "Why a model decided what it did at a frame: its margin, term by term."),
    "audit": Command("audit", "audit", "Which recordings went wrong: each one's verdict, score and reasons, ranked."),
    "review": Command("review", "review", "See a model's phases over the recordings in the browser, explain any "
                      "moment, save corrections as labels."),
    "stream": Command("stream", "stream", "Recognise live frames from stdin, one JSON line out per frame."),
    "ros": Command("ros", "ros", "A ROS 2 (DDS) or ROS 1 node recognising the model's topics live: the activity on a "
                   "topic."),
    "echo": Command("echo", "echo", "Print a ROS 2 topic's messages as `rostopic echo -p` rows, for `mlnseq stream`."),
    "sweep": Command("sweep", "sweep", "Run a grid of options x seeds through Snakemake, locally or on SLURM: "
                     "OUT/results.parquet."),
    "config": Command("config", "app", "Inspect the project file (mlnseq.toml)."),
}
GLOBAL_FLAGS = ("--verbose",)
GLOBAL_OPTIONS = ("--config",)


class MlnseqGroup(FlagGroup):
    """Imports a command when it is asked for, accepts the global options anywhere on the line and loads the
    project file before a command runs."""

    listing = False  # while the group's own help is drawn: commands by their summaries, none imported

    def list_commands(self, ctx: Any) -> list[str]:
        return list(COMMANDS)

    def get_command(self, ctx: Any, name: str) -> Any:
        if name not in COMMANDS:
            return None
        if self.listing:
            return TyperCommand(name, help=COMMANDS[name].summary)
        return _load(name)

    def format_help(self, ctx: Any, formatter: Any) -> None:
        self.listing = True
        try:
            super().format_help(ctx, formatter)
        finally:
            self.listing = False

    def shell_complete(self, ctx: Any, incomplete: str) -> list[Any]:
        self.listing = True  # command names and summaries, none imported
        try:
            return super().shell_complete(ctx, incomplete)
        finally:
            self.listing = False

    def resolve_command(self, ctx: Any, args: list[str]) -> Any:
        name = args[0] if args else ""
        if name and name not in COMMANDS and not name.startswith("-") and not ctx.resilient_parsing:
            # typer suggests from its own table of commands, empty here: suggest from the lazy list
            matches = difflib.get_close_matches(name, list(COMMANDS))
            if matches:
                ctx.fail(f"No such command {name!r}. Did you mean {', '.join(map(repr, matches))}?")
        return super().resolve_command(ctx, args)

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        front, rest, i = [], [], 0
        while i < len(args):
            if args[i] in GLOBAL_FLAGS:
                front.append(args[i])
            elif args[i] in GLOBAL_OPTIONS and i + 1 < len(args):
                front += args[i : i + 2]
                i += 1
            elif args[i].split("=", 1)[0] in GLOBAL_OPTIONS:
                front.append(args[i])
            else:
                rest.append(args[i])
            i += 1
        return super().parse_args(ctx, front + rest)

    def invoke(self, ctx: Any) -> Any:
        args = [*ctx._protected_args, *ctx.args]
        if args and args[0] in COMMANDS and args[0] != "config":
            from mlnseq_cli import config as project_config
            from mlnseq_cli.console import reported_errors

            with reported_errors():
                path = project_config.find(ctx.params.get("config"), _workdir_in(args[1:]))
                if path is not None:
                    ctx.default_map = project_config.load(path, self.stage_commands(ctx))
        try:
            return super().invoke(ctx)
        except ImportError as error:  # a command whose module imports an optional library at its top
            from mlnseq.catalog.errors import missing_extra
            from mlnseq_cli.console import fail, verbose

            missing = missing_extra(error)
            if missing is None:
                raise
            if verbose():
                traceback.print_exc(file=sys.stderr)
            raise fail(str(missing), missing.exit_code) from None

    def main(self, *args: Any, **kwargs: Any) -> Any:
        with one_line_usage_errors():
            return super().main(*args, **kwargs)

    def stage_commands(self, ctx: Any) -> dict[str, Any]:
        return {name: self.get_command(ctx, name) for name in self.list_commands(ctx) if name != "config"}


@contextlib.contextmanager
def one_line_usage_errors() -> Iterator[None]:
    """A usage error (an unknown command or option, a value of the wrong type) as one line on stderr, as every
    other error: `error: No such option: --bogus (mlnseq train --help lists the options)`, exit 2."""
    from typer import rich_utils

    def one_line(error: Any) -> None:
        if type(error).__name__ == "NoArgsIsHelpError":  # `mlnseq` alone: its help, as typer prints it
            return
        context = getattr(error, "ctx", None)
        listed = "commands" if hasattr(getattr(context, "command", None), "list_commands") else "options"
        where = f" ({context.command_path} --help lists the {listed})" if context is not None else ""
        message = " ".join(error.format_message().split())
        print(f"error: {message}{where}", file=sys.stderr)

    drawn, rich_utils.rich_format_error = rich_utils.rich_format_error, one_line
    try:
        yield
    finally:
        rich_utils.rich_format_error = drawn


@functools.cache
def _load(name: str) -> Any:
    """The click command of one entry of COMMANDS, its module imported now."""
    command = COMMANDS[name]
    target = getattr(importlib.import_module(f"mlnseq_cli.{command.module}"), command.function)
    if isinstance(target, typer.Typer):
        return typer.main.get_group(target)
    single = typer.Typer(add_completion=False, pretty_exceptions_enable=False, rich_markup_mode="rich")
    single.command(name, cls=FlagCommand)(target)
    return typer.main.get_command(single)


def _workdir_in(args: list[str]) -> Optional[Path]:
    for i, arg in enumerate(args):
        if arg in ("--workdir", "-w") and i + 1 < len(args):
            return Path(args[i + 1])
        if arg.startswith("--workdir="):
            return Path(arg.split("=", 1)[1])
    return None


app = typer.Typer(
    cls=MlnseqGroup,
    name="mlnseq",
    help="Sequential activity recognition with logic constraints (LSTM + Markov Logic Network). The words the "
         "commands print (network factor weight, mln-mode, folds, edit, F1@50, lag ...) are explained in "
         "docs/glossary.md.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)


def _print_version(asked: bool) -> None:
    if not asked:
        return
    from importlib import metadata

    try:
        print(f"mlnseq {metadata.version('mlnseq')}")
    except metadata.PackageNotFoundError:
        print("error: mlnseq is not installed (run `make setup`), so it has no version", file=sys.stderr)
        raise typer.Exit(1) from None
    raise typer.Exit()


@app.callback()
def root(
    verbose: Annotated[bool, typer.Option("--verbose", help="Show a traceback before an error's line (the exit code stays).")] = False,
    config: Annotated[
        Optional[Path], typer.Option("--config", help="Project file of options \\[default: ./mlnseq.toml, else WORKDIR/mlnseq.toml].")
    ] = None,
    version: Annotated[
        bool, typer.Option("--version", help="Print mlnseq's version and exit.", is_eager=True, callback=_print_version)
    ] = False,
) -> None:
    """Run the pipeline's stages: collect, binarize, formulas, learn-weights, train, conflate, eval, report; then
    export a trained method and recognise new recordings (predict) or live frames (stream)."""
    if verbose:
        os.environ["MLNSEQ_VERBOSE"] = "1"


def main() -> None:
    """Console entry point."""
    app(prog_name="mlnseq")


if __name__ == "__main__":
    main()
