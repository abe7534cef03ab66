"""A starter predicate spec from the frames at hand (`mlnseq binarize --suggest`).

Every threshold comes from the training split (never the test split): per feature a ``bins`` predicate at its
terciles (low / mid / high) and a ``change`` predicate whose dead band is the median frame-to-frame change;
a feature that looks like a gripper (named so, or mostly at its two extreme levels) gets a ``gripper``
predicate instead, and two grippers a ``pair``; two 3-D points (columns ending in x, y, z) get the distance
between them as a channel. The text is commented TOML that ``parse_spec`` accepts as it is.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput

GRIPPER_WORDS = re.compile(r"gripper|finger|claw|jaw")
NOT_A_LEVEL = re.compile(r"vel|speed|acc|effort|force|torque|current")  # rates and loads, not an opening
NOT_A_POINT = re.compile(r"rot|quat|orient|ang|vel|acc|rel|force|torque|effort")  # triples that are not positions
AXIS = re.compile(r"^(?P<prefix>.*?)[/_.]?(?P<axis>[xyz])$", re.IGNORECASE)
GENERIC_FIELDS = {"data", "value"}  # a message's field that names nothing: std_msgs/Float64's data
END_SHARE = 0.7  # a gripper spends at least this share of frames near its two extreme levels
MAX_DISTANCES = 3  # distance channels between the first points found


@dataclass(frozen=True)
class Channel:
    """One channel's training values and its change between consecutive frames of an episode."""

    column: str
    name: str  # the predicate name made from the column
    values: np.ndarray
    changes: np.ndarray  # |x - previous x| within episodes


def number(value: float) -> str:
    """A threshold as TOML writes it, six significant digits."""
    text = f"{float(value):.6g}"
    return text if any(c in text for c in ".en") else text + ".0"


def identifier(column: str) -> str:
    text = re.sub(r"[^a-z0-9]+", "_", column.lower()).strip("_")
    return text if re.match(r"[a-z]", text) else f"c_{text}" if text else "channel"


def names_for(columns: list[str]) -> dict[str, str]:
    """Short unique predicate names: each column's last path part, more parts where two would collide."""
    parts = {c: [p for p in re.split(r"[/.]", c) if p] or [c] for c in columns}
    parts = {c: p[:-1] if len(p) > 1 and p[-1] in GENERIC_FIELDS else p for c, p in parts.items()}
    depth = {c: 1 for c in columns}
    while True:
        named = {c: identifier("_".join(parts[c][-depth[c]:])) for c in columns}
        clashes = [c for c in columns if list(named.values()).count(named[c]) > 1 and depth[c] < len(parts[c])]
        if not clashes:
            break
        for c in clashes:
            depth[c] += 1
    taken: set[str] = set()
    for c in columns:  # still equal (names that differ only in punctuation): number them
        base, k = named[c], 2
        while named[c] in taken:
            named[c], k = f"{base}_{k}", k + 1
        taken.add(named[c])
    return named


def looks_like_gripper(channel: Channel) -> bool:
    """An opening (never negative, not a rate nor an axis of a point): named so (gripper, finger, claw, jaw), or
    unnamed but mostly at its two extreme levels."""
    name = channel.column.lower()
    low, high = np.quantile(channel.values, [0.02, 0.98])
    if high <= low or channel.values.min() < 0 or NOT_A_LEVEL.search(name) or AXIS.match(channel.column):
        return False
    near = (channel.values - low) / (high - low)
    at_ends, at_low, at_high = np.mean((near < 0.15) | (near > 0.85)), np.mean(near < 0.15), np.mean(near > 0.85)
    by_data = at_ends >= END_SHARE and min(at_low, at_high) >= 0.1
    return by_data or bool(GRIPPER_WORDS.search(name))


def points(columns: list[str]) -> list[tuple[str, tuple[str, str, str]]]:
    """3-D points: (prefix, (x, y, z) columns) for columns named PREFIXx, PREFIXy, PREFIXz (also _x, /x)."""
    axes: dict[str, dict[str, str]] = {}
    for column in columns:
        match = AXIS.match(column)
        if match and match["prefix"] and not NOT_A_POINT.search(match["prefix"].lower()):
            axes.setdefault(match["prefix"], {})[match["axis"].lower()] = column
    return [(prefix, (a["x"], a["y"], a["z"])) for prefix, a in axes.items() if set(a) == {"x", "y", "z"}]


def channel_data(frames: pl.DataFrame, column: str, name: str, train: np.ndarray, first: np.ndarray) -> Channel:
    values = frames[column].cast(pl.Float64).to_numpy()
    change = np.abs(np.diff(values, prepend=values[:1]))
    keep = train & ~first & np.isfinite(change)
    return Channel(column, name, values[train & np.isfinite(values)], change[keep])


def bins_block(channel: Channel, name: str) -> list[str]:
    edges = sorted({float(number(e)) for e in np.quantile(channel.values, [1 / 3, 2 / 3])})
    values = ["low", "mid", "high"] if len(edges) == 2 else ["low", "high"]
    return ["", f"# {channel.column}: its level, at the terciles of the training split",
            "[[predicate]]", f'name = "{name}"', 'kind = "bins"', f'channel = "{channel.column}"',
            f"edges = [{', '.join(number(e) for e in edges)}]", f"values = {toml_list(tuple(values))}"]


def change_block(channel: Channel, name: str) -> list[str]:
    threshold = float(np.median(channel.changes)) if channel.changes.size else 0.0
    return ["", f"# {channel.column}: rising / falling beyond the median change between frames ({number(threshold)})",
            "[[predicate]]", f'name = "{name}"', 'kind = "change"', f'channel = "{channel.column}"',
            f"threshold = {number(threshold)}"]


def gripper_block(channel: Channel, name: str) -> list[str]:
    low, high = np.quantile(channel.values, [0.02, 0.98])
    span = high - low
    closed, opened, threshold = low + 0.25 * span, high - 0.25 * span, 0.05 * span
    return ["", f"# {channel.column} looks like a gripper: {np.mean(channel.values > opened):.0%} of training frames "
            f"above {number(opened)} (open), {np.mean(channel.values < closed):.0%} below {number(closed)} (closed);",
            "# between them a change beyond 5 % of its range is opening or closing",
            "[[predicate]]", f'name = "{name}"', 'kind = "gripper"', f'channel = "{channel.column}"',
            f"open_above = {number(opened)}", f"closed_below = {number(closed)}", f"threshold = {number(threshold)}"]


def suggest_spec(frames: pl.DataFrame, source: str = "") -> str:
    """A commented predicate spec for ``frames`` (its thresholds from the training split), as TOML text.

    Active: grippers (and the pair of the first two) and the change of each distance between two 3-D points; where
    the frames have neither, the change of every feature. Written but commented out, to switch on by hand: the
    other features' changes and every channel's levels (bins), which depend on where a recording happens and, over
    a few episodes, overfit (measured on DESK bags by cross-validation: docs/first-day.md)."""
    features = artifacts.feature_columns(frames)
    if frames.height == 0 or not features:
        raise BadInput("frames.parquet holds no frames or no features to suggest predicates for; "
                       "rerun `mlnseq collect`")
    frames = frames.sort("episode", "frame", maintain_order=True)
    splits = frames["split"].to_numpy()
    train = splits == "train" if (splits == "train").any() else np.ones(frames.height, dtype=bool)
    episode = frames["episode"].to_numpy()
    first = np.r_[True, episode[1:] != episode[:-1]]
    distances = distance_channels(features, set(frames.columns))
    derived = frames.with_columns(
        (sum((pl.col(s) - pl.col(e)) ** 2 for s, e in zip(start, end)) ** 0.5).alias(name)
        for name, start, end, _ in distances)
    names = names_for(features)
    names.update({d[0]: unique(d[3], set(names.values())) for d in distances})
    channels = [channel_data(derived, c, names[c], train, first) for c in features + [d[0] for d in distances]]
    channels = [c for c in channels if c.values.size and c.values.min() < c.values.max()]
    grippers = [c for c in channels if c.column in features and looks_like_gripper(c)]
    core = bool(grippers or distances)
    lines = [f"# A starter predicate spec suggested by `mlnseq binarize --suggest` for frames of source {source!r}",
             f"# ({int(train.sum()):,} training frames, {len(features)} features). Every threshold comes from the "
             "training split;", "# edit freely, then `mlnseq binarize --spec THIS_FILE`. Keys: docs/predicates.md.",
             "# Blocks commented out (# [[predicate]]) are written for you to switch on: remove their '# '."]
    for name, start, end, _ in distances:
        lines += ["", f"# the distance between two points ({', '.join(start)}) and ({', '.join(end)})",
                  "[[channel]]", f'name = "{name}"', 'kind = "distance"', f"from = {toml_list(start)}",
                  f"to = {toml_list(end)}"]
    taken = set(names.values())
    for channel in channels:
        if channel in grippers:
            lines += gripper_block(channel, channel.name)
            continue
        active = channel.column not in features or not core
        lines += commented(change_block(channel, unique(f"{channel.name}_change", taken)), not active)
        lines += commented(bins_block(channel, channel.name), True)
    if len(grippers) >= 2:
        pair = unique("grippers", taken)
        lines += ["", f"# both grippers at once: {grippers[0].name} and {grippers[1].name}", "[[predicate]]",
                  f'name = "{pair}"', 'kind = "pair"', f'of = ["{grippers[0].name}", "{grippers[1].name}"]']
    return "\n".join(lines) + "\n"


def distance_channels(features: list[str], taken: set[str]) -> list[tuple[str, tuple, tuple, str]]:
    """(channel name, first point, second point, predicate name) between the first 3-D points found."""
    found = points(features)[:MAX_DISTANCES + 1]
    short = {prefix: identifier(re.split(r"[/.]", prefix.rstrip("/._"))[-1] or prefix) for prefix, _ in found}
    pairs = [(a, b) for i, a in enumerate(found) for b in found[i + 1:]][:MAX_DISTANCES]
    made = [(f"between_{short[a[0]]}_and_{short[b[0]]}", a[1], b[1], f"{short[a[0]]}_{short[b[0]]}_distance")
            for a, b in pairs]
    return [d for d in made if d[0] not in taken]


def toml_list(names: tuple[str, ...]) -> str:
    return "[" + ", ".join(f'"{n}"' for n in names) + "]"


def commented(block: list[str], off: bool) -> list[str]:
    """A block as written, or commented out line by line (its own comments kept as they are)."""
    return [line if not off or not line or line.startswith("#") else f"# {line}" for line in block]


def unique(name: str, taken: set[str]) -> str:
    base, k = name, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name


def edited(path: Path, workdir: Path) -> bool:
    """Whether a suggested spec at ``path`` was edited by hand: it is neither the spec the workdir's predicates were
    last made from nor what its frames suggest now (an unreadable workdir: edited, to be safe)."""
    import json

    import pyarrow.parquet as pq

    if not path.exists():
        return False
    text = path.read_text(encoding="utf-8")
    try:  # the recorded spec as written, stale or not
        made = json.loads(pq.read_schema(workdir / artifacts.PREDICATES).metadata[artifacts.META_KEY]).get("spec", {})
        if made.get("path") == str(path.resolve()) and made.get("text") == text:
            return False
    except Exception:  # no predicates yet, or not ours
        pass
    try:
        frames = workdir / artifacts.FRAMES
        return text != suggest_spec(pl.read_parquet(frames), artifacts.read_metadata(frames).get("source", ""))
    except Exception:  # no frames, or not ours: nothing says the file is a suggestion
        return True
