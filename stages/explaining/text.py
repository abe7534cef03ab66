"""Explanations as text a person reads, within 80 columns: the terms largest first, the small ones summed in one
line, the hard rules that removed classes, and a segment's terms and its end."""

from __future__ import annotations

import textwrap

from mlnseq.explaining.segments import Segment
from mlnseq.explaining.terms import Explanation, Term, TermKind

WIDTH = 80
SHOWN = 12  # terms listed one by one at most
SMALL = 0.005  # a term below this share of the largest is summed with the others
NUMBER = 9  # columns of a contribution
INDENT = " " * (NUMBER + 12)


def _wrapped(first: str, text: str, indent: str = INDENT) -> list[str]:
    return textwrap.wrap(text, WIDTH, initial_indent=first, subsequent_indent=indent, break_on_hyphens=False) or [first]


def _detail(term: Term) -> str:
    if term.kind is not TermKind.FORMULA:
        return term.text + ("" if term.line is None else f" [line {term.line}]")
    where = "" if term.line is None else f"line {term.line}, "
    truth = "" if term.truth is None else f", truth {term.truth[0]} vs {term.truth[1]}"
    return f"{term.text} [{where}w {term.weight:.3g}{truth}]"


def term_lines(terms: list[Term], total: float | None = None) -> list[str]:
    """The numbered terms, largest first, the small ones summed; then the total."""
    numbered = sorted((t for t in terms if t.contribution is not None), key=lambda t: -abs(t.contribution))
    largest = abs(numbered[0].contribution) if numbered else 0.0
    shown = [t for t in numbered[:SHOWN] if abs(t.contribution) >= SMALL * largest]
    rest = numbered[len(shown):]
    lines = []
    for term in shown:
        lines += _wrapped(f"{term.contribution:+{NUMBER}.3f}  {str(term.kind):<9} ", _detail(term))
    if rest:
        lines.append(f"{sum(t.contribution for t in rest):+{NUMBER}.3f}  {len(rest)} smaller term"
                     f"{'s' if len(rest) > 1 else ''}")
    if total is not None:
        lines += [f"{'-' * NUMBER}", f"{total:+{NUMBER}.3f}  the margin"]
    return lines


def table(found: Explanation) -> list[str]:
    """One explanation, as `mlnseq explain` prints it."""
    when = "" if found.time is None else f", time {found.time:g}"
    head = f"episode {found.episode}, frame {found.frame}{when}: {found.chosen}"
    if found.versus is None:
        lines = _wrapped("", head + " (no other class was possible)", "  ")
    elif found.margin is None:
        lines = _wrapped("", head + f" over {found.versus}, which a hard rule removed", "  ")
    else:
        lines = _wrapped("", head + f" over {found.versus} by {found.margin:.3f} (log-ratio)", "  ")
    lines += _wrapped("", f"decided by {found.decoder}; the terms add up to the margin:", "  ")
    lines += term_lines(list(found.terms), found.margin)
    removed = [t for t in found.terms if t.kind is TermKind.HARD_RULE]
    if removed:
        lines.append("removed by hard rules:")
        for term in removed:
            lines += _wrapped("  ", term.text, "    ")
    for note in found.notes:
        lines += _wrapped("note: ", note, "  ")
    return lines


def segment_table(segment: Segment) -> list[str]:
    """A segment, as `mlnseq explain --segment K` prints it."""
    first, last = segment.frames
    lines = _wrapped("", f"episode {segment.episode}, segment {segment.index}: {segment.chosen}, frames {first}-{last}",
                     "  ")
    lines.append("held by (each term's mean over its frames, against each frame's runner-up):")
    lines += term_lines(list(segment.held))
    if segment.ended is None:
        lines.append("ended with the episode")
        return lines
    lines.append("")
    lines += _wrapped("", f"ended at frame {segment.ended.frame}, where {segment.ended.chosen} took over:", "  ")
    return lines + table(segment.ended)
