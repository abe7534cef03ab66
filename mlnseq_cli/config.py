"""The project file ``mlnseq.toml``: every stage's options in one place, one table per command.

```toml
[collect]
env = "desk"
source = "../shared/data/desk-taurus"

[train]
epochs = 40
```

One file is read, the first that exists of: ``--config FILE``, ``./mlnseq.toml`` (the current folder),
``WORKDIR/mlnseq.toml``. The current folder's wins over the workdir's (a note names the one left unread).
Its values become the commands' defaults, so flags on the command line override them. Relative paths in
it are taken relative to the file's own folder. `mlnseq config show` names the file and prints every
option in force.
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from mlnseq_cli.console import console, reported_errors
from mlnseq_cli.flags import FlagCommand, FlagGroup
from mlnseq.catalog.artifacts import DEFAULT_WORKDIR
from mlnseq.catalog.errors import BadInput

CONFIG_NAME = "mlnseq.toml"


def locate(config: Path | None, workdir: Path | None) -> tuple[Path | None, str]:
    """The project file in force and where it was found: the one named, else the current folder's, else the
    workdir's, else none (with what was looked for)."""
    if config is not None:
        if not config.is_file():
            raise BadInput(f"--config {config} not found")
        return config, "--config"
    here = Path(CONFIG_NAME)
    if here.is_file():
        return here, "the current folder"
    candidate = (workdir or DEFAULT_WORKDIR) / CONFIG_NAME
    if candidate.is_file():
        return candidate, "the workdir"
    return None, f"looked for ./{CONFIG_NAME} and {candidate}"


def unread(path: Path | None, origin: str, workdir: Path | None) -> Path | None:
    """The workdir's project file when the current folder's was read instead of it."""
    other = (workdir or DEFAULT_WORKDIR) / CONFIG_NAME
    if path is not None and origin == "the current folder" and other.is_file() and not other.samefile(path):
        return other
    return None


def find(config: Path | None, workdir: Path | None) -> Path | None:
    """The project file in force (see :func:`locate`), noting on stderr a workdir file it leaves unread."""
    path, origin = locate(config, workdir)
    note_unread(path, unread(path, origin, workdir))
    return path


def note_unread(path: Path | None, other: Path | None) -> None:
    """The note, on stderr, that the workdir's project file ``other`` is left unread for ``path``."""
    if other is not None:
        print(f"note: {other} is not read: {path} in the current folder wins (pass --config to choose)",
              file=sys.stderr)


def _line_of(text: str, section: str, key: str | None = None) -> int:
    """The 1-based line of ``[section]`` (or of ``key`` inside it) in the TOML text."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if re.match(rf"\s*\[\s*{re.escape(section)}\s*\]", line)), 0)
    if key is None:
        return start + 1
    for i in range(start + 1, len(lines)):
        if re.match(r"\s*\[", lines[i]):
            break
        if re.match(rf"\s*{re.escape(key)}\s*=", lines[i]):
            return i + 1
    return start + 1


def load(path: Path, commands: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Read and check the file against the commands' options; return click's ``default_map``."""
    try:
        text = path.read_text(encoding="utf-8")
        document = tomllib.loads(text)
    except OSError as error:
        raise BadInput(f"cannot read {path}: {error.strerror or error}") from error
    except tomllib.TOMLDecodeError as error:
        raise BadInput(f"{path}: {error}") from error
    except RecursionError:  # tomllib recurses once per nested array or table
        raise BadInput(f"{path}: invalid TOML: its arrays or tables are nested too deep to read") from None
    except UnicodeDecodeError as error:
        raise BadInput(f"cannot read {path}: not UTF-8 text ({error})") from None
    default_map: dict[str, dict[str, Any]] = {}
    for section, values in document.items():
        command = commands.get(section)
        if command is None or not isinstance(values, dict):
            raise BadInput(
                f"{path}:{_line_of(text, section)}: unknown table [{section}]; "
                f"tables are the commands {', '.join(commands)}"
            )
        params = {p.name: p for p in command.params if p.name not in ("help",)}
        section_map = {}
        for key, value in values.items():
            name = key.replace("-", "_")
            param = params.get(name)
            if param is None:
                raise BadInput(
                    f"{path}:{_line_of(text, section, key)}: [{section}] has no option {key!r}; "
                    f"options are {', '.join(sorted(n.replace('_', '-') for n in params))}"
                )
            try:
                param.get_runtime_param().coerce(value, param=param, ctx=None)
            except Exception as error:
                message = getattr(error, "message", None) or str(error)
                raise BadInput(f"{path}:{_line_of(text, section, key)}: [{section}] {key}: {message}") from None
            if param.type_descriptor.annotation is Path and not Path(value).is_absolute():
                value = str(path.parent / value)
            section_map[name] = value
        default_map[section] = section_map
    return default_map


def options_in_force(commands: dict[str, Any], default_map: dict[str, dict[str, Any]], source: str) -> list[tuple[str, str, str, str]]:
    """(command, option, value, where it came from) for every option of every command."""
    rows = []
    for name, command in commands.items():
        for param in command.params:
            if param.name in ("help",) or not getattr(param, "opts", None):
                continue
            configured = default_map.get(name, {})
            if param.name in configured:
                value, origin = configured[param.name], source
            else:
                value, origin = param.default, "default"
            if callable(value):
                value = value()
            rows.append((name, param.opts[0], str(value), origin))
    return rows


app = typer.Typer(name="config", help="Inspect the project file (mlnseq.toml).", no_args_is_help=True,
                  rich_markup_mode="rich", cls=FlagGroup)


@app.command("show", cls=FlagCommand)
def show(
    ctx: typer.Context,
    workdir: Annotated[Path, typer.Option("--workdir", "-w", help="Workdir whose mlnseq.toml to read when the current folder has none.")] = DEFAULT_WORKDIR,
) -> None:
    """Print every command's options in force and where each came from (default or the project file)."""
    root_ctx = ctx.find_root()
    group = root_ctx.command
    with reported_errors():
        commands = group.stage_commands(root_ctx)
        path, origin = locate(root_ctx.params.get("config"), workdir)
        default_map = load(path, commands) if path else {}
    console.print(escape(f"project file: {path} (from {origin})" if path else f"project file: none ({origin})"),
                  highlight=False)
    note_unread(path, unread(path, origin, workdir))  # on stderr, as every command says it
    table = Table("command", "option", "value", "from", title="options in force")
    for row in options_in_force(commands, default_map, str(path)):
        table.add_row(*row)
    console.print(table)
