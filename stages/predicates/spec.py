"""The predicate spec: its types and its TOML parser (every error names the file, line and key).

A spec (TOML, see ``stages/specs/*.binarize.toml``) declares derived channels and predicates. Channels:

- ``[[channel]] kind = "distance"``: Euclidean distance between two 3-D points (``from``, ``to``: three
  columns each), optionally rounded to ``decimals``.

Predicates (paper section IV), each a one-hot group of columns named ``<predicate>_<value>``:

- ``bins`` (C1): static thresholds on a channel; ``edges`` ascending, ``values`` one name per bin;
  bin i holds ``edges[i-1] <= x < edges[i]`` (a threshold is one edge, two values).
- ``change`` (C2, eq. 9): x minus the previous x against a dead band ``threshold``:
  increase (> threshold), decrease (< -threshold), else static; with ``window`` W (default 1), x minus the x W
  frames before (the episode's first frame where it has fewer).
- ``gripper``: open (x > ``open_above``), else closed (x < ``closed_below``), else opening / closing by a
  change beyond ``threshold``, else static. ``previous_scale`` multiplies the previous value before that
  change test (default 1; the DESK spec sets 100, see ``stages/specs/desk.binarize.toml``).
- ``pair``: the conjunction of two earlier predicates (``of``), one value per combination, first-major.

stages/predicates/rules.py evaluates a spec (each rule once, for whole episodes and one frame at a time).
"""

from __future__ import annotations

import importlib.resources
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput

NAME = re.compile(r"[a-z][a-z0-9_]*\Z")
VALUE = re.compile(r"[a-z0-9][a-z0-9_]*\Z")
MAX_WINDOW = 10_000  # frames a change predicate may look back
MAX_COLUMNS = 10_000  # predicate columns a spec may make (binarize --max-columns); a pair multiplies two predicates'


def default_spec_path(source: str) -> Path:
    """The built-in spec of a frames source, shipped in the package: ``stages/specs/<source>.binarize.toml``."""
    return Path(importlib.resources.files("mlnseq") / "specs" / f"{source}.binarize.toml")


@dataclass(frozen=True)
class Distance:
    """A derived channel: the Euclidean distance between the points ``start`` and ``end``."""

    name: str
    start: tuple[str, str, str]
    end: tuple[str, str, str]
    decimals: int | None = None
    lines: dict[str, int] = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class Bins:
    name: str
    channel: str
    edges: tuple[float, ...]
    values: tuple[str, ...]
    lines: dict[str, int] = field(default_factory=dict, compare=False)


@dataclass(frozen=True)
class Change:
    name: str
    channel: str
    threshold: float
    lines: dict[str, int] = field(default_factory=dict, compare=False)
    values: ClassVar[tuple[str, ...]] = ("static", "increase", "decrease")
    window: int = 1  # frames: x minus the x this many frames before


@dataclass(frozen=True)
class Gripper:
    name: str
    channel: str
    open_above: float
    closed_below: float
    threshold: float
    previous_scale: float = 1.0
    lines: dict[str, int] = field(default_factory=dict, compare=False)
    values: ClassVar[tuple[str, ...]] = ("open", "closed", "opening", "closing", "static")


@dataclass(frozen=True)
class Pair:
    name: str
    first: str
    second: str
    values: tuple[str, ...]
    lines: dict[str, int] = field(default_factory=dict, compare=False)


Predicate = Bins | Change | Gripper | Pair


@dataclass(frozen=True)
class PredicateSpec:
    """A parsed spec: derived channels, then predicates in column order; ``text`` as read."""

    path: Path
    text: str
    channels: tuple[Distance, ...]
    predicates: tuple[Predicate, ...]
    hints: dict[str, str] = field(default_factory=dict, compare=False)  # entry name -> what to do if a column is absent

    def columns(self) -> dict[str, list[str]]:
        """Each predicate's column names, in order."""
        return {p.name: [f"{p.name}_{v}" for v in p.values] for p in self.predicates}

    def where(self, entry: Distance | Predicate, key: str) -> str:
        """``file:line`` of one key of an entry, for error messages."""
        return f"{self.path}:{entry.lines.get(key, entry.lines.get('', 1))}"


KIND_KEYS = {
    "bins": {"channel", "edges", "values"},
    "change": {"channel", "threshold", "window"},
    "gripper": {"channel", "open_above", "closed_below", "threshold", "previous_scale"},
    "pair": {"of"},
}
CHANNEL_KEYS = {"distance": {"from", "to", "decimals"}}


def _key_lines(text: str, section: str, index: int) -> dict[str, int]:
    """Line numbers of the keys of the ``index``-th ``[[section]]`` table ('' is its header line)."""
    lines: dict[str, int] = {}
    seen = -1
    inside = False
    for number, line in enumerate(text.splitlines(), start=1):
        array = re.match(r"\s*\[\[\s*([A-Za-z0-9_\-]+)\s*\]\]", line)
        if array or re.match(r"\s*\[\s*[A-Za-z0-9_\-.\"]+\s*\]\s*(#.*)?$", line):
            inside = False
            if array and array.group(1) == section:
                seen += 1
                inside = seen == index
                if inside:
                    lines[""] = number
            continue
        key = re.match(r"\s*\"?([A-Za-z0-9_\-]+)\"?\s*=", line)
        if inside and key and key.group(1) not in lines:
            lines[key.group(1)] = number
    return lines


class _Entry:
    """One ``[[section]]`` table being checked, with the lines of its keys for error messages."""

    def __init__(self, path: Path, text: str, section: str, index: int, table: Any):
        self.path = path
        self.lines = _key_lines(text, section, index)
        name = table.get("name") if isinstance(table, dict) else None
        self.label = f"[[{section}]] {name!r}" if isinstance(name, str) else f"[[{section}]] #{index + 1}"
        if not isinstance(table, dict):
            raise self.error("", "must be a table")
        self.table = table

    def error(self, key: str, message: str) -> BadInput:
        line = self.lines.get(key, self.lines.get("", 1))
        where = f"key '{key}' of " if key else ""
        return BadInput(f"{self.path}:{line}: {where}{self.label}: {message}")

    def require(self, key: str) -> Any:
        if key not in self.table:
            raise self.error("", f"missing key '{key}'")
        return self.table[key]

    def name(self, taken: set[str]) -> str:
        value = self.require("name")
        if not isinstance(value, str) or not NAME.match(value):
            raise self.error("name", f"must be a lowercase identifier [a-z][a-z0-9_]*, got {value!r}")
        if value in taken:
            raise self.error("name", f"{value!r} is defined twice")
        return value

    def number(self, key: str, default: float | None = None, *, positive: bool = False) -> float:
        value = self.require(key) if default is None or key in self.table else default
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
            raise self.error(key, f"must be a finite number, got {value!r}")
        if value < 0 or (positive and value == 0):
            raise self.error(key, f"must be {'above' if positive else 'at least'} 0, got {value!r}")
        return float(value)

    def window(self, key: str = "window", most: int = MAX_WINDOW) -> int:
        value = self.table.get(key, 1)
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= most:
            raise self.error(key, f"must be a whole number of frames from 1 to {most:,}, got {value!r}")
        return value

    def text(self, key: str) -> str:
        value = self.require(key)
        if not isinstance(value, str) or not value:
            raise self.error(key, f"must be a column name (a string), got {value!r}")
        return value

    def strings(self, key: str, length: int | None = None) -> tuple[str, ...]:
        value = self.require(key)
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise self.error(key, f"must be a list of strings, got {value!r}")
        if length is not None and len(value) != length:
            raise self.error(key, f"must list {length} names, got {len(value)}")
        return tuple(value)

    def check_keys(self, allowed: set[str]) -> None:
        for key in self.table:
            if key not in allowed | {"name", "kind"}:
                raise self.error(key, f"unknown key; allowed: {', '.join(sorted(allowed | {'name', 'kind'}))}")


def _channel(entry: _Entry, taken: set[str]) -> Distance:
    name = entry.name(taken)
    kind = entry.require("kind")
    if not isinstance(kind, str) or kind not in CHANNEL_KEYS:
        raise entry.error("kind", f"unknown channel kind {kind!r}; known: {', '.join(CHANNEL_KEYS)}")
    entry.check_keys(CHANNEL_KEYS[kind] | {"hint"})
    decimals = entry.table.get("decimals")
    if decimals is not None and (isinstance(decimals, bool) or not isinstance(decimals, int) or decimals < 0):
        raise entry.error("decimals", f"must be a whole number of at least 0, got {decimals!r}")
    return Distance(name, entry.strings("from", 3), entry.strings("to", 3), decimals, entry.lines)


def _check_columns(entry: _Entry, key: str, count: int, used: int, limit: int) -> None:
    """Refuse a predicate whose columns would take the spec past ``limit`` before they are made."""
    if used + count > limit:
        raise entry.error(key, f"makes {count:,} columns, which with the {used:,} above it pass --max-columns "
                               f"{limit:,}: use fewer values, or raise --max-columns")


def _predicate(entry: _Entry, defined: dict[str, Predicate], used: int = 0, limit: int = MAX_COLUMNS) -> Predicate:
    name = entry.name(set(defined))
    kind = entry.require("kind")
    if not isinstance(kind, str) or kind not in KIND_KEYS:
        raise entry.error("kind", f"unknown predicate kind {kind!r}; known: {', '.join(KIND_KEYS)}")
    entry.check_keys(KIND_KEYS[kind] | {"hint"})
    if kind == "bins":
        edges = entry.require("edges")
        if (not isinstance(edges, list) or not edges
                or any(isinstance(e, bool) or not isinstance(e, (int, float)) or not np.isfinite(e) for e in edges)):
            raise entry.error("edges", f"must be a non-empty list of finite numbers, got {edges!r}")
        if any(b <= a for a, b in zip(edges, edges[1:])):
            raise entry.error("edges", f"must be strictly ascending, got {edges}")
        values = entry.strings("values", len(edges) + 1)
        _check_columns(entry, "values", len(values), used, limit)
        if not all(VALUE.match(v) for v in values) or len(set(values)) != len(values):
            raise entry.error("values", f"must be distinct lowercase names [a-z0-9][a-z0-9_]*, got {list(values)}")
        return Bins(name, entry.text("channel"), tuple(float(e) for e in edges), values, entry.lines)
    if kind == "change":
        return Change(name, entry.text("channel"), entry.number("threshold"), entry.lines, window=entry.window())
    if kind == "gripper":
        open_above, closed_below = entry.number("open_above"), entry.number("closed_below")
        if closed_below > open_above:
            raise entry.error("closed_below", f"must not exceed open_above ({open_above:g}), got {closed_below:g}")
        return Gripper(
            name, entry.text("channel"), open_above, closed_below, entry.number("threshold"),
            entry.number("previous_scale", 1.0, positive=True), entry.lines,
        )
    first, second = entry.strings("of", 2)
    for part in (first, second):
        if part not in defined:
            raise entry.error("of", f"{part!r} is not a predicate defined above it")
    if first == second:
        raise entry.error("of", f"names {first!r} twice; a pair joins two different predicates")
    _check_columns(entry, "of", len(defined[first].values) * len(defined[second].values), used, limit)
    values = tuple(f"{a}_{b}" for a in defined[first].values for b in defined[second].values)
    return Pair(name, first, second, values, entry.lines)


def _top_line(text: str, key: str) -> int:
    """The line where a top-level key or table first appears (1 if not found)."""
    pattern = re.compile(rf"\s*\[*\s*\"?{re.escape(key)}\"?\s*[\]=.]")
    return next((n for n, line in enumerate(text.splitlines(), 1) if pattern.match(line)), 1)


def parse_spec(text: str, path: Path, max_columns: int = MAX_COLUMNS) -> PredicateSpec:
    """Parse and check a spec's text; every error names the file, line and key."""
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        found = re.search(r"at line (\d+)", str(error))
        raise BadInput(f"{path}:{found.group(1) if found else 1}: invalid TOML: {error}") from None
    for key, value in document.items():
        if key not in ("channel", "predicate"):
            raise BadInput(f"{path}:{_top_line(text, key)}: unknown key '{key}': a spec holds "
                           "[[channel]] and [[predicate]] tables")
        if not isinstance(value, list):
            raise BadInput(f"{path}:{_top_line(text, key)}: key '{key}' must be written as [[{key}]] tables")
    if not document.get("predicate"):
        raise BadInput(f"{path}:1: missing key 'predicate': the spec declares no [[predicate]] table")

    channels: list[Distance] = []
    hints: dict[str, str] = {}
    for index, table in enumerate(document.get("channel", [])):
        entry = _Entry(path, text, "channel", index, table)
        channels.append(_channel(entry, {c.name for c in channels}))
        if "hint" in table:
            hints[channels[-1].name] = str(table["hint"])
    defined: dict[str, Predicate] = {}
    for index, table in enumerate(document["predicate"]):
        entry = _Entry(path, text, "predicate", index, table)
        predicate = _predicate(entry, defined, sum(len(p.values) for p in defined.values()), max_columns)
        defined[predicate.name] = predicate
        if "hint" in table:
            hints[predicate.name] = str(table["hint"])

    spec = PredicateSpec(Path(path), text, tuple(channels), tuple(defined.values()), hints)
    seen: dict[str, str] = {}
    for predicate in spec.predicates:
        for column in spec.columns()[predicate.name]:
            if column in seen or column in artifacts.KEY_COLUMNS:
                raise BadInput(
                    f"{spec.where(predicate, 'name')}: key 'name' of [[predicate]] {predicate.name!r}: "
                    f"its column {column!r} is also a column of {seen.get(column, 'the keys')!r}; rename one"
                )
            seen[column] = predicate.name
    return spec


def load_spec(path: Path, max_columns: int = MAX_COLUMNS) -> PredicateSpec:
    """Read and parse a spec file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise BadInput(f"spec {path} not found: pass --spec FILE") from None
    except (OSError, UnicodeDecodeError) as error:
        raise BadInput(f"cannot read spec {path}: {error}") from error
    try:
        return parse_spec(text, path, max_columns)
    except RecursionError:  # tomllib recurses once per nested array or table
        raise BadInput(f"{path}: invalid TOML: its arrays or tables are nested too deep to read") from None
