"""The learned predicates written as a spec (`WORKDIR/learned.binarize.toml`) that `binarize --spec` reads as it is,
each predicate under a comment saying how its thresholds were chosen and, per value, its support (the share of
training frames where it holds) and what it separates (the classes it holds in most); and the digest line that
tells a spec written so from one edited by hand."""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Sequence

import numpy as np

from mlnseq.learning.candidates import Candidate
from mlnseq.predicates.spec import Bins, Change, Distance, Gripper

DIGEST = "mlnseq-learned: sha256 "  # the last header line, after the comment mark: the digest of every other line


def number(value: float) -> str:
    """A threshold as TOML writes it, six significant digits."""
    text = f"{float(value):.6g}"
    return text if any(c in text for c in ".en") else text + ".0"


def separates(codes: np.ndarray, labels: np.ndarray, classes: Sequence[str], n_values: int) -> list[str]:
    """Per value: its share of the training frames, the classes it holds in at least half of (else the one it
    holds in most), and the largest share among the other classes."""
    said = []
    for value in range(n_values):
        on = codes == value
        shares = np.array([on[labels == k].mean() if (labels == k).any() else 0.0 for k in range(len(classes))])
        marked = [k for k in np.argsort(-shares, kind="stable") if shares[k] >= 0.5] or [int(np.argmax(shares))]
        others = np.delete(shares, marked)
        said.append(f"{on.mean():.0%} of training frames; " + ", ".join(f"{classes[k]} {shares[k]:.0%}" for k in marked)
                    + (f" (other classes at most {others.max():.0%})" if others.size else ""))
    return said


def how(candidate: Candidate) -> str:
    """How a candidate's thresholds were chosen, in words."""
    p = candidate.predicate
    if isinstance(p, Gripper):
        return (f"a gripper: open above {number(p.open_above)} (its full opening less a tenth of its range), closed "
                f"below {number(p.closed_below)} (the cut of best information gain under that), between them opening "
                f"or closing beyond {number(p.threshold)} per frame (the dead band of best gain, below its motion)")
    if isinstance(p, Change):
        return (f"its change over {p.window} frame{'s' if p.window > 1 else ''} beyond {number(p.threshold)} (the "
                "window and dead band of best information gain)")
    assert isinstance(p, Bins)
    return f"its level, cut at {', '.join(number(e) for e in p.edges)} (decision stumps: best information gain)"


def briefly(candidate: Candidate) -> str:
    """A candidate in one short line: ``width: a gripper, open above 0.075, closed below 0.032, moving beyond ...``."""
    p = candidate.predicate
    if isinstance(p, Gripper):
        said = (f"a gripper, open above {p.open_above:.3g}, closed below {p.closed_below:.3g}, moving beyond "
                f"{p.threshold:.3g} per frame")
    elif isinstance(p, Change):
        said = f"its change over {p.window} frame{'s' if p.window > 1 else ''} beyond {p.threshold:.3g}"
    else:
        said = f"its level, cut at {', '.join(f'{e:.3g}' for e in p.edges)}"
    return f"{p.name.replace('_', ' ')} ({candidate.channel}): {said}"


NEGATIVE_GAIN = (" (below 0: alone, it predicts the held-out frames' classes worse than the class frequencies do; "
                 "kept for what it adds beside the other predicates)")


def predicate_block(candidate: Candidate, labels: np.ndarray | None, train: np.ndarray | None,
                    classes: Sequence[str]) -> list[str]:
    import textwrap

    p = candidate.predicate
    said = f"{candidate.channel}: {how(candidate)}; out-of-fold gain {candidate.oof:.3f} nats per frame" + (
        NEGATIVE_GAIN if candidate.oof < 0 else "")
    lines = ["", *(f"# {line}" for line in textwrap.wrap(said, 114, break_on_hyphens=False))]
    if labels is not None:
        lines += [f"#   {value}: {said}" for value, said in zip(p.values, separates(
            candidate.codes[train], labels[train], classes, len(p.values)))]
    lines += ["[[predicate]]", f'name = "{p.name}"', f'kind = "{"bins" if isinstance(p, Bins) else candidate.kind}"',
              f'channel = "{p.channel}"']
    if isinstance(p, Bins):
        values = ", ".join(f'"{v}"' for v in p.values)
        lines += [f"edges = [{', '.join(number(e) for e in p.edges)}]", f"values = [{values}]"]
    elif isinstance(p, Gripper):
        lines += [f"open_above = {number(p.open_above)}", f"closed_below = {number(p.closed_below)}",
                  f"threshold = {number(p.threshold)}"]
    else:
        lines += [f"threshold = {number(p.threshold)}"] + ([f"window = {p.window}"] if p.window > 1 else [])
    return lines


def plain(predicates: Sequence[Candidate], distances: Sequence[Distance]) -> str:
    """A spec of ``predicates`` without comments (the learned predicates learned again without one fold)."""
    lines = []
    for d in distances:
        lines += ["[[channel]]", f'name = "{d.name}"', 'kind = "distance"',
                  f"from = [{', '.join(json.dumps(c) for c in d.start)}]",
                  f"to = [{', '.join(json.dumps(c) for c in d.end)}]"]
    for candidate in predicates:
        lines += [line for line in predicate_block(candidate, None, None, ()) if not line.startswith("#")]
    return "\n".join(lines) + "\n"


def render(predicates: Sequence[Candidate], distances: Sequence[Distance], labels: np.ndarray, train: np.ndarray,
           classes: Sequence[str], header: Sequence[str]) -> str:
    """The spec's text: ``header`` (comment lines), the distance channels, the predicates; then its digest."""
    lines = [f"# {line}" for line in header]
    for d in distances:
        lines += ["", f"# the distance between the points ({', '.join(d.start)}) and ({', '.join(d.end)})",
                  "[[channel]]", f'name = "{d.name}"', 'kind = "distance"',
                  f"from = [{', '.join(json.dumps(c) for c in d.start)}]",
                  f"to = [{', '.join(json.dumps(c) for c in d.end)}]"]
    for candidate in predicates:
        lines += predicate_block(candidate, labels, train, classes)
    body = "\n".join(lines) + "\n"
    return with_digest(body)


def with_digest(text: str, mark: str = "#") -> str:
    """``text`` with its digest line after its leading comment lines (``mark``: how a comment starts)."""
    lines = text.splitlines()
    at = next((i for i, line in enumerate(lines) if not line.startswith(mark)), len(lines))
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    return "\n".join([*lines[:at], f"{mark} {DIGEST}{digest}", *lines[at:]]) + "\n"


def untouched(text: str, mark: str = "#") -> bool:
    """Whether ``text`` is a learned file as written (its digest line matches the rest)."""
    found = re.search(rf"(?m)^{re.escape(mark)} {re.escape(DIGEST)}([0-9a-f]+)\n", text)
    if not found:
        return False
    rest = text[:found.start()] + text[found.end():]
    return hashlib.sha256(rest.encode()).hexdigest()[:16] == found.group(1)
