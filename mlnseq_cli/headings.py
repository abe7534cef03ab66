"""Short column headings, so that tables with a column per class fit 80 columns."""

from __future__ import annotations


def short_names(classes: list[str], room: int = 40) -> list[str]:
    """Column headings for the classes: their first words where those are distinct and fit ``room`` characters
    together (a space each), else c0, c1, ..."""
    first = [name.split()[0] if name.split() else name for name in classes]
    fits = len(set(first)) == len(first) and all(len(f) < room // max(len(first), 1) for f in first)
    return first if fits else [f"c{k}" for k in range(len(classes))]


def legend(headings: list[str], classes: list[str]) -> list[str]:
    """Lines naming the classes behind headings that are not their first words (none when they are)."""
    if headings == [name.split()[0] if name.split() else name for name in classes]:
        return []
    return [f"{heading} = {name}" for heading, name in zip(headings, classes)]
