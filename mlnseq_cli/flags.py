"""Commands and groups whose --help lists flags without a type and option names whole (read by main.py and
config.py)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

from rich.table import Table
from typer import rich_utils
from typer.core import TyperCommand, TyperGroup


def _bare_flags(params: list[Any]) -> list[Any]:
    """typer 0.29's rich help prints a flag's type, `<bool>`, as if the flag took a value; show none, as typer
    did before and click does."""
    for param in params:
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""
    return params


class _WholeNames(Table):
    """typer's help tables with every column but the last (the help text) kept whole: at 80 columns the help
    wraps beside an option's name instead of the name being cut (`--write-lerobot-p…`)."""

    def add_row(self, *renderables: Any, **options: Any) -> None:
        super().add_row(*renderables, **options)
        for column in self.columns[:-1]:
            column.no_wrap = True


@contextlib.contextmanager
def _whole_names() -> Iterator[None]:
    drawn, rich_utils.Table = rich_utils.Table, _WholeNames
    try:
        yield
    finally:
        rich_utils.Table = drawn


class FlagCommand(TyperCommand):
    """A command whose --help lists flags without a type, option names whole."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _bare_flags(super().get_params(ctx))

    def format_help(self, ctx: Any, formatter: Any) -> None:
        with _whole_names():
            super().format_help(ctx, formatter)


class FlagGroup(TyperGroup):
    """A group of commands whose --help lists flags without a type, option names whole."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _bare_flags(super().get_params(ctx))

    def format_help(self, ctx: Any, formatter: Any) -> None:
        with _whole_names():
            super().format_help(ctx, formatter)
