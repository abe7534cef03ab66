"""What `mlnseq binarize --suggest` reads off the frames' columns before it learns predicates from them
(mlnseq.learning.candidates, mlnseq.learning.learned_logic): short predicate names made from the columns,
which channels look like a gripper's opening (named gripper, finger, claw or jaw, or most of their frames at their
two extreme levels), and the 3-D points (columns ending in x, y, z) whose distances are channels too.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

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












def distance_channels(features: list[str], taken: set[str]) -> list[tuple[str, tuple, tuple, str]]:
    """(channel name, first point, second point, predicate name) between the first 3-D points found."""
    found = points(features)[:MAX_DISTANCES + 1]
    short = {prefix: identifier(re.split(r"[/.]", prefix.rstrip("/._"))[-1] or prefix) for prefix, _ in found}
    pairs = [(a, b) for i, a in enumerate(found) for b in found[i + 1:]][:MAX_DISTANCES]
    made = [(f"between_{short[a[0]]}_and_{short[b[0]]}", a[1], b[1], f"{short[a[0]]}_{short[b[0]]}_distance")
            for a, b in pairs]
    return [d for d in made if d[0] not in taken]






def unique(name: str, taken: set[str]) -> str:
    base, k = name, 2
    while name in taken:
        name, k = f"{base}_{k}", k + 1
    taken.add(name)
    return name

