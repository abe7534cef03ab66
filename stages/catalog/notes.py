"""What a stage says beside its result: a note with a code a caller can select on and a text a user reads."""

from __future__ import annotations

from dataclasses import dataclass

MISSING_INPUT = "missing-input"  # a method left out: its network or the MLN weights are absent
UNIFORM_TRANSITIONS = "uniform-transitions"  # no temporal formula: decoding uses uniform transitions
WEIGHT_NOT_CHOSEN = "weight-not-chosen"  # the network factor's weight kept at 1: nothing to choose it on
FOLD_CLASS_MISSING = "fold-class-missing"  # a fold's fit part lacks a class
CHAIN_RESTARTED = "chain-restarted"  # decoding restarted the chain where no allowed transition reaches a frame


@dataclass(frozen=True)
class Note:
    code: str
    text: str

    def __str__(self) -> str:
        return self.text


def counted(n: int, one: str, many: str | None = None) -> str:
    """``n`` and the noun, singular for one: ``counted(1, "episode")`` is "1 episode"."""
    return f"{n:,} {one if n == 1 else many or one + 's'}"


def texts(notes: list[Note], *codes: str) -> list[str]:
    """The texts of the notes with one of ``codes`` (all notes' when none is given)."""
    return [n.text for n in notes if not codes or n.code in codes]
