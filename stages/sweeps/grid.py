"""The sweep file (TOML) and its grid: read, checked against the stages' options, expanded into configs.

```toml
[sweep]
workdir = "mlnseq-work"       # the dataset's workdir: frames, predicates, weights and fold weights
seeds = [0, 1]

[grid]                        # option names of train, conflate and export, each with a list of values
cell = ["lstm", "tcn"]
epochs = [5]
export.method = ["auto"]      # a name two stages share is qualified: train.method, export.method
```

A bare key names a train option, else a conflate option, else an export option (``mln_mode`` goes to conflate
and export, ``decode`` to export: conflate always predicts every decoding so that each has figures). The key
``formulas`` lists .mln files, each learned with the dataset's folds (stages/sweeps/workflow.py).
"""

from __future__ import annotations

import enum
import hashlib
import itertools
import json
import re
import tomllib
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from mlnseq.catalog.errors import BadInput

STAGES = ("train", "conflate", "export")


class StageOptions(dict):
    """The options dataclass of each stage in STAGES (each with a default for every field and validate() raising
    BadInput), and in ``flags`` the fields its command takes as options: a grid key is one of those, since the
    workflow runs the commands. Given by the caller (pipeline/sweep.py's SWEPT: the one library that may import the
    stages)."""

    def __init__(self, options: Mapping[str, type], flags: Mapping[str, Iterable[str]]) -> None:
        super().__init__(options)
        self.flags = {stage: frozenset(names) for stage, names in flags.items()}

FIXED = {"train": ("seed",), "conflate": ("decode",), "export": ("output", "force")}  # set by the sweep itself
SHARED_BARE = {"mln_mode": ("conflate", "export"), "decode": ("export",)}  # bare keys with their own stages
# What the sweep runs unless the grid says otherwise: stream networks whose folds follow the MLN's fold
# weights, and the deployed method chosen by cross-validation among the online decoders.
DEFAULTS = {"train": {"mode": "stream"}, "conflate": {}, "export": {"method": "auto", "decode": "filter"}}
SWEEP_KEYS = ("workdir", "seeds")
FORMULAS = "formulas"  # a grid key of .mln files: each is written (formulas --spec) and learned (learn-weights --folds)
MAX_CONFIGS = 1000


@dataclass(frozen=True)
class Config:
    """One cell of the grid: its name and the options of each stage (seed apart)."""

    name: str
    values: dict[str, Any]  # grid key as written -> value
    options: dict[str, Any]  # stage -> its options dataclass
    formulas: Path | None = None  # the grid's formulas file: None, the dataset's weights


@dataclass(frozen=True)
class Sweep:
    """A sweep file, read and checked."""

    path: Path
    workdir: Path
    seeds: tuple[int, ...]
    keys: tuple[str, ...]  # grid keys as written (qualified where qualified)
    configs: tuple[Config, ...]


def allowed_keys(stages: StageOptions) -> dict[str, tuple[str, ...]]:
    """Every grid key -> the stages it sets."""
    keys: dict[str, tuple[str, ...]] = {}
    for stage in STAGES:
        for f in fields(stages[stage]):
            if f.name in FIXED[stage] or f.name not in stages.flags[stage]:
                continue
            keys[f"{stage}.{f.name}"] = (stage,)
            keys.setdefault(f.name, SHARED_BARE.get(f.name, (stage,)))
    return keys


def line_of(text: str, key: str) -> int | None:
    """The line of ``key`` (its last part) in the sweep file's text, for messages; None if not found."""
    last = re.escape(key.rsplit(".", 1)[-1])
    for number, line in enumerate(text.splitlines(), 1):
        if re.match(rf'\s*(?:[\w"]+\.)?"?{last}"?\s*=', line):
            return number
    return None


def where(path: Path, text: str, key: str) -> str:
    line = line_of(text, key)
    return f"{path}{'' if line is None else f' line {line}'}"


def read(path: Path, stages: StageOptions) -> Sweep:
    """Read and check the sweep file; every error names the file, the line and the key."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text)
    except FileNotFoundError:
        raise BadInput(f"sweep file {path} not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise BadInput(f"cannot read sweep file {path}: {error}") from None
    except tomllib.TOMLDecodeError as error:
        raise BadInput(f"{path} is not valid TOML: {error}") from None
    unknown = sorted(set(data) - {"sweep", "grid"})
    if unknown:
        raise BadInput(f"{where(path, text, unknown[0])}: unknown table [{unknown[0]}]; a sweep file has [sweep] "
                       "and [grid]")
    head = data.get("sweep")
    if not isinstance(head, dict) or "workdir" not in head:
        raise BadInput(f"{path}: no [sweep] table with workdir = \"DATASET-WORKDIR\" and seeds = [0, 1]")
    for key in head:
        if key not in SWEEP_KEYS:
            raise BadInput(f"{where(path, text, key)}: unknown [sweep] key {key!r}: choose one of "
                           f"{', '.join(SWEEP_KEYS)}")
    seeds = head.get("seeds", [0])
    if not isinstance(seeds, list) or not seeds or not all(type(s) is int and s >= 0 for s in seeds) \
            or len(set(seeds)) != len(seeds):
        raise BadInput(f"{where(path, text, 'seeds')}: seeds must be a list of distinct whole numbers >= 0, "
                       f"got {seeds!r}")
    workdir = Path(str(head["workdir"]))
    if not workdir.is_absolute():
        workdir = path.parent / workdir
    grid = flatten(data.get("grid", {}), path, text, stages)
    return Sweep(path, workdir, tuple(seeds), tuple(grid), tuple(expand(grid, path, text, stages)))


def flatten(table: Any, path: Path, text: str, stages: StageOptions) -> dict[str, list[Any]]:
    """The [grid] table as key -> values, ``export.method = [..]`` (a nested table in TOML) as "export.method"."""
    if not isinstance(table, dict):
        raise BadInput(f"{where(path, text, 'grid')}: [grid] must be a table of option = [values]")
    allowed = allowed_keys(stages)
    grid: dict[str, list[Any]] = {}
    for key, value in table.items():
        items = [(f"{key}.{k}", v) for k, v in value.items()] if isinstance(value, dict) and key in STAGES \
            else [(key, value)]
        for name, values in items:
            if name not in allowed and name != FORMULAS:
                raise BadInput(f"{where(path, text, name)}: unknown grid key {name!r}: no stage takes "
                               f"--{name.rsplit('.', 1)[-1].replace('_', '-')}; choose {FORMULAS} (.mln files) or an "
                               f"option of train, conflate or export: {options_named(allowed)} (qualify a shared "
                               "name: train.method, export.method)")
            if not isinstance(values, list) or not values:
                raise BadInput(f"{where(path, text, name)}: grid key {name!r} needs a non-empty list of values, "
                               f"e.g. {name} = [{json.dumps(values)}]")
            if len(set(map(repr, values))) != len(values):
                raise BadInput(f"{where(path, text, name)}: grid key {name!r} lists a value twice: {values!r}")
            if name == FORMULAS:
                for value in values:
                    if not isinstance(value, str) or not formulas_path(path, value).is_file():
                        raise BadInput(f"{where(path, text, name)}: grid key {name!r}: {value!r} is not a formulas "
                                       "file (.mln; a path relative to the sweep file, or absolute)")
            grid[name] = values
    return grid


def options_named(allowed: dict[str, tuple[str, ...]]) -> str:
    """The grid keys by stage, as a message lists them: "train's cell, epochs ...; conflate's ..."."""
    return "; ".join(f"{stage}'s {', '.join(k.split('.', 1)[1] for k in allowed if k.startswith(stage + '.'))}"
                     for stage in STAGES)


def formulas_path(sweep_file: Path, value: str) -> Path:
    path = Path(value)
    return path if path.is_absolute() else sweep_file.parent / path


def expand(grid: dict[str, list[Any]], path: Path, text: str, stages: StageOptions) -> list[Config]:
    """Every combination of the grid's values, in the file's order, each checked as the stages check options."""
    allowed = allowed_keys(stages)
    for key, values in grid.items():
        for value in values:
            for stage in allowed.get(key, ()):
                option_value(stages[stage], key.rsplit(".", 1)[-1], value, where(path, text, key), key)
    varying = [k for k, v in grid.items() if len(v) > 1]
    configs = []
    for combo in itertools.product(*grid.values()):
        values = dict(zip(grid, combo))
        options = {}
        for stage in STAGES:
            chosen = dict(DEFAULTS[stage])
            for key, value in values.items():
                if stage in allowed.get(key, ()):
                    name = key.rsplit(".", 1)[-1]
                    chosen[name] = option_value(stages[stage], name, value, "")
            options[stage] = replace(stages[stage](), **chosen)
        spec = formulas_path(path, values[FORMULAS]).resolve() if FORMULAS in values else None
        shown = {k: Path(values[k]).stem if k == FORMULAS else values[k] for k in varying}
        configs.append(Config(config_name(shown), values, options, spec))
    names = [c.name for c in configs]
    if len(set(names)) != len(names):  # two values that read the same in a folder name
        configs = [replace(c, name=hashed(c.values)) for c in configs]
    for config in configs:
        for stage in STAGES:
            try:
                config.options[stage].validate()
            except BadInput as error:
                shown = ", ".join(f"{k} = {v!r}" for k, v in config.values.items())
                raise BadInput(f"{path}: the grid's config {shown} is refused by {stage}: {error}") from None
    return configs


def option_value(options: type, name: str, value: Any, place: str, key: str = "") -> Any:
    """``value`` as the option ``name`` of the stage whose dataclass is ``options`` takes it; a wrong type or value
    names ``place`` and the choices. Without ``place``, the value is only converted."""
    try:
        value = converted(typing.get_type_hints(options)[name], value)
        if place:
            replace(options(), **{name: value}).validate()
    except (ValueError, BadInput) as error:
        raise BadInput(f"{place}: grid key {key or name!r} value {value!r}: {error}") from None
    return value


def converted(hint: Any, value: Any) -> Any:
    """A TOML value as a field of type ``hint`` holds it (an enum member, a float, a tuple, None for "auto"); a
    value of the wrong kind raises ValueError saying what to write."""
    kinds = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
    enums = [k for k in kinds if isinstance(k, type) and issubclass(k, enum.Enum)]
    for kind in enums:
        if value in [m.value for m in kind]:
            return kind(value)
    if enums and str not in kinds:
        raise ValueError(f"choose one of {', '.join(str(m.value) for k in enums for m in k)}")
    if value == "auto" and type(None) in kinds and str not in kinds:
        return None  # conflate's network_weight: auto, the weight learned
    if bool in kinds:
        if type(value) is not bool:
            raise ValueError("use true or false")
    elif int in kinds and float not in kinds:
        if type(value) is not int:
            raise ValueError("use a whole number")
    elif float in kinds:
        if type(value) not in (int, float):
            raise ValueError("use a number" + (' or "auto"' if type(None) in kinds else ""))
        return float(value)
    elif typing.get_origin(hint) is tuple or tuple in kinds:
        return tuple(value) if isinstance(value, list) else tuple(str(value).split(","))
    elif str in kinds and not isinstance(value, str):
        raise ValueError("use a quoted name")
    return value


def config_name(values: dict[str, Any]) -> str:
    """A folder name for a config: its varying keys and values (``cell-tcn_epochs-5``), or a digest if too long."""
    if not values:
        return "default"
    name = "_".join(re.sub(r"[^A-Za-z0-9.+]+", "-", f"{k}-{v}") for k, v in values.items())
    return name if len(name) <= 100 else hashed(values)


def hashed(values: dict[str, Any]) -> str:
    return "config-" + hashlib.sha256(repr(sorted(values.items())).encode()).hexdigest()[:12]


def flags(stage: str, options: Any) -> list[str]:
    """The command-line flags that give ``options`` of ``stage`` where they differ from the stage's defaults."""
    defaults = type(options)()
    out: list[str] = []
    for f in fields(options):
        value = getattr(options, f.name)
        if f.name in FIXED[stage] or value == getattr(defaults, f.name):
            continue
        flag = "--" + f.name.replace("_", "-")
        if isinstance(value, bool):
            out.append(flag if value else f"--no-{f.name.replace('_', '-')}")
            continue
        if isinstance(value, enum.Enum):
            value = value.value
        elif value is None:
            value = "auto"
        elif isinstance(value, tuple):
            value = ",".join(map(str, value))
        out += [flag, str(value)]
    return out
