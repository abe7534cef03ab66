"""The mlnseq application: registers the stage commands in pipeline order."""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer

from mlnseq_cli import binarize, collect, conflate, evaluate, formulas, learn_weights, train

app = typer.Typer(
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
) -> None:
    """Run the pipeline's stages: collect, binarize, formulas, learn-weights, train, conflate, eval."""
    if verbose:
        os.environ["MLNSEQ_VERBOSE"] = "1"


app.command("collect")(collect.collect)
app.command("binarize")(binarize.binarize)
app.command("formulas")(formulas.formulas)
app.command("learn-weights")(learn_weights.learn_weights)
app.command("train")(train.train)
app.command("conflate")(conflate.conflate)
app.command("eval")(evaluate.evaluate)


def main() -> None:
    """Console entry point; ``--verbose`` is accepted anywhere on the line."""
    args = sys.argv[1:]
    if "--verbose" in args:
        args = ["--verbose"] + [a for a in args if a != "--verbose"]
    app(args=args, prog_name="mlnseq")


if __name__ == "__main__":
    main()
