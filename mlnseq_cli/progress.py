"""Training's progress, as train and fit show it: a bar over the epochs on a terminal, else a plain line at each tenth
of them (Make's log)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

from mlnseq_cli.console import console
from mlnseq import train as stage

FOLD_NETWORKS = "fold networks"  # named in the bar's label when they train after its epochs


@contextlib.contextmanager
def epoch_progress(what: str, epochs: int) -> Iterator[stage.Progress]:
    """On a terminal, a progress bar over the epochs; into a pipe or file (Make's log), one plain line at
    each tenth of the epochs."""
    if console.is_terminal:
        columns = (TextColumn("training {task.description}: epoch {task.completed}/{task.total}"), BarColumn(),
                   TextColumn("{task.fields[scores]}"), TimeRemainingColumn())
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task(what, total=epochs, scores="")
            yield lambda done: bar.update(task, completed=done.epoch, total=done.epochs, refresh=True,
                                          scores=_scores(done) + ("; now the fold networks" if done.epoch == done.epochs
                                                                  and FOLD_NETWORKS in what else ""))
        return
    started, said = time.monotonic(), []

    def line(done: stage.EpochDone) -> None:
        if done.epoch == done.epochs or 10 * done.epoch // done.epochs > 10 * (done.epoch - 1) // done.epochs:
            left = (time.monotonic() - started) / done.epoch * (done.epochs - done.epoch)
            then = "now the fold networks" if done.epoch == done.epochs and FOLD_NETWORKS in what else \
                f"{left:.0f} s left"
            scores = _scores(done)
            if not scores and not said:  # said once: the epochs in between are not measured
                scores = "measured after the last epoch (--measure every-epoch: after each)"
                said.append(True)
            console.print(f"training {what}: epoch {done.epoch}/{done.epochs}, {scores + ', ' if scores else ''}{then}",
                          soft_wrap=True, highlight=False)

    yield line


def _scores(done: stage.EpochDone) -> str:
    if done.loss is None:
        return ""  # not measured (--measure last-epoch)
    val = "–" if done.val_accuracy is None else f"{done.val_accuracy:.1%}"
    return f"loss {done.loss:.3f}, train {done.train_accuracy:.1%}, val {val}"
