"""Commands and groups whose --help lists flags without a type (read by main.py and config.py)."""

from __future__ import annotations

from typing import Any

from typer.core import TyperCommand, TyperGroup


def _bare_flags(params: list[Any]) -> list[Any]:
    """typer 0.29's rich help prints a flag's type, `<bool>`, as if the flag took a value; show none, as typer
    did before and click does."""
    for param in params:
        if getattr(param, "is_flag", False) and param.metavar is None:
            param.metavar = ""
    return params


class FlagCommand(TyperCommand):
    """A command whose --help lists flags without a type."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _bare_flags(super().get_params(ctx))


class FlagGroup(TyperGroup):
    """A group of commands whose --help lists flags without a type."""

    def get_params(self, ctx: Any) -> list[Any]:
        return _bare_flags(super().get_params(ctx))
