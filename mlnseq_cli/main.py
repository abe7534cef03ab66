"""The mlnseq application: registers the stage commands in pipeline order."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.table import Table
from typer.core import TyperGroup

from mlnseq_cli import config as project_config
from mlnseq_cli.console import console, reported_errors

from mlnseq_cli import binarize, collect, conflate, export, formulas, info, learn_weights, predict, report, stream, train
from mlnseq_cli import eval as eval_command

GLOBAL_FLAGS = ("--verbose",)
GLOBAL_OPTIONS = ("--config",)


class MlnseqGroup(TyperGroup):
    """Accepts the global options anywhere on the line and loads the project file before a command runs."""

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
        command = self.get_command(ctx, args[0]) if args else None
        if command is not None and args[0] != "config":
            with reported_errors():
                path = project_config.find(ctx.params.get("config"), _workdir_in(args[1:]))
                if path is not None:
                    ctx.default_map = project_config.load(path, self.stage_commands(ctx))
        return super().invoke(ctx)

    def stage_commands(self, ctx: Any) -> dict[str, Any]:
        return {name: self.get_command(ctx, name) for name in self.list_commands(ctx) if name != "config"}


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
    help="Sequential activity recognition with logic constraints (LSTM + Markov Logic Network).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode="rich",
)


@app.callback()
def root(
    verbose: Annotated[bool, typer.Option("--verbose", help="Show a traceback on errors.")] = False,
    config: Annotated[
        Optional[Path], typer.Option("--config", help="Project file of options \\[default: WORKDIR/mlnseq.toml].")
    ] = None,
) -> None:
    """Run the pipeline's stages: collect, binarize, formulas, learn-weights, train, conflate, eval, report."""
    if verbose:
        os.environ["MLNSEQ_VERBOSE"] = "1"


app.command("collect")(collect.collect)
app.command("binarize")(binarize.binarize)
app.command("formulas")(formulas.formulas)
app.command("learn-weights")(learn_weights.learn_weights)
app.command("train")(train.train)
app.command("conflate")(conflate.conflate)
app.command("eval")(eval_command.evaluate)
app.command("report")(report.report)
app.command("export")(export.export)
app.command("info")(info.info)
app.command("predict")(predict.predict)
app.command("stream")(stream.stream)


config_app = typer.Typer(help="Inspect the project file (mlnseq.toml).", no_args_is_help=True)
app.add_typer(config_app, name="config")


@config_app.command("show")
def config_show(
    ctx: typer.Context,
    workdir: Annotated[Path, typer.Option("--workdir", "-w", help="Workdir whose mlnseq.toml to read.")] = project_config.DEFAULT_WORKDIR,
) -> None:
    """Print every command's options in force and where each came from (default or the project file)."""
    root_ctx = ctx.find_root()
    group = root_ctx.command
    with reported_errors():
        commands = group.stage_commands(root_ctx)
        path = project_config.find(root_ctx.params.get("config"), workdir)
        default_map = project_config.load(path, commands) if path else {}
    table = Table("command", "option", "value", "from", title=f"options in force ({path or 'no project file'})")
    for row in project_config.options_in_force(commands, default_map, str(path)):
        table.add_row(*row)
    console.print(table)


def main() -> None:
    """Console entry point."""
    app(prog_name="mlnseq")


if __name__ == "__main__":
    main()
