"""Live recognition in the report (issue 24): per paper dataset, accuracy against latency (every decoder at every
lag conflate scored, its best method by cross-validation, with its test figures), and the choices within a
latency budget that reports/summary.json records: ``live`` (DESK: 25 frames, Fetch: 1 s), ``online`` (lag 0)
and ``offline`` (no budget). Choices read the cross-validated figures only (stages/choosing/latency.py's
choice, on means over seeds); the test figures stand beside them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.decoders import Decoder
from mlnseq.choosing import latency
from mlnseq.reporting.loading import PAPER_DATASETS, TCN, VARIANTS, Run
from mlnseq.reporting.tables import (ABSENT, CV_METRICS, DEPLOY_VARIANTS, by_pair, cv_stats, fold_frames_of,
                                     sequence_stats)

BUDGETS = {"desk": (25, None), "fetch": (None, 1.0)}  # the live budget: frames, or seconds at the known rate
FOLDERS = (*DEPLOY_VARIANTS, TCN)
SHOWN = ("segment_accuracy", "frame_accuracy", "edit")
CHOSEN_BY = "CV frame accuracy (within one standard error of the best), then the mean of CV segment, frame, edit"


@dataclass(frozen=True)
class Scored:
    """A decoded method of one folder: cross-validated and test means over seeds, test forbidden transitions."""

    folder: str
    candidate: latency.Candidate
    test: dict[str, float | None]
    forbidden: float | None  # mean over seeds, on test
    hard_rules: bool

    def record(self, rate: float | None) -> dict[str, Any]:
        decoding = self.candidate.decoding
        lag = decoding.lag if not decoding.decoder.offline else None
        latency = None if decoding.decoder.offline else decoding.latency_s(rate) if decoding.lag else 0.0
        return {"method": self.candidate.name, "folder": self.folder, "decoder": decoding.decoder.value,
                "lag_frames": lag, "latency_s": latency,
                "cv": {**{k: self.candidate.figures.get(k) for k in (*SHOWN, "f1_50", "log_likelihood")},
                       "forbidden_transitions": self.candidate.figures.get("forbidden_transitions")},
                "test": {**self.test, "forbidden_transitions": self.forbidden}}


def _forbidden_and_rules(run: Run, folder: str) -> tuple[dict[str, float], bool]:
    """Per method, the forbidden transitions on test (mean over seeds), and whether the chain has hard rules."""
    counts: dict[str, list[int]] = {}
    rules = False
    for path in sorted((run.runs / folder / "stream").glob(f"seed-*/{artifacts.PREDICTIONS}")) if run.runs else []:
        meta = artifacts.read_metadata(path, "predictions")
        rules |= bool(meta.get("hard_rules"))
        for name, count in (meta.get("forbidden_transitions") or {}).items():
            counts.setdefault(name, []).append(count)
    return {name: float(np.mean(values)) for name, values in counts.items()}, rules


def _value_means(table: pl.DataFrame) -> dict[tuple[str, str], float]:
    """(dataset, method) -> the mean of its rows' values."""
    grouped: dict[tuple[str, str], list[float]] = {}
    for key, value in zip(zip(table["dataset"].to_list(), table["method"].to_list()), table["value"].to_list()):
        grouped.setdefault(key, []).append(value)
    return {key: float(pl.Series(values).mean()) for key, values in grouped.items()}


def scored(run: Run, dataset: str) -> list[Scored]:
    """Every cross-validated method of the dataset's deployable folders (stream mode)."""
    cv = {CV_METRICS[m]: by_pair(table) for m, table in cv_stats(run).items()}
    test = {CV_METRICS[m]: by_pair(table) for m, table in sequence_stats(run).items()}
    extra = {k: _value_means(run.cv.filter((run.cv["mode"] == "stream") & (run.cv["metric"] == k)))
             for k in ("log_likelihood", "forbidden_transitions")}
    out = []
    for suffix in FOLDERS:
        folder = dataset + suffix
        names = [name for (where, name) in cv["segment_accuracy"] if where == folder]
        if not names:
            continue
        forbidden, rules = _forbidden_and_rules(run, folder)
        for name in names:
            figures = {metric: means.get((folder, name), ABSENT)[0] for metric, means in cv.items()}
            figures.update({key: means[folder, name] for key, means in extra.items() if (folder, name) in means})
            tested = {metric: means.get((folder, name), ABSENT)[0] for metric, means in test.items()}
            if tested["segment_accuracy"] is None:
                continue
            (candidate,) = latency.candidates({name: figures}, fold_frames_of(run, folder, [name]))
            out.append(Scored(folder, candidate, tested, forbidden.get(name), rules))
    return out


def choose(candidates: list[Scored], budget: int | None, offline: bool = False) -> Scored | None:
    """The best by the cross-validated criterion within ``budget`` frames (hard rules kept where a folder has
    them); ``offline``: among the offline decoders only."""
    fitting = [s for s in candidates if latency.within(s.candidate, budget, None, s.hard_rules)
               and (not offline or s.candidate.decoding.decoder.offline)]
    if not fitting:
        return None
    chosen = latency.best([s.candidate for s in fitting])  # export --method auto's choice
    return next(s for s in fitting if s.candidate is chosen)


def rate_of(run: Run, dataset: str) -> float | None:
    """The frame rate of a dataset's recordings (its own folder's frames, or a variant's: they link the same)."""
    for folder in (dataset, *(dataset + suffix for suffix in FOLDERS)):
        if folder in run.datasets:
            return latency.rate_of(run.datasets[folder])
    return None


def live_budget(run: Run, dataset: str) -> int | None:
    frames, seconds = BUDGETS.get(dataset, (None, None))
    rate = rate_of(run, dataset)
    return frames if frames is not None else (None if rate is None else int(math.floor(seconds * rate + 1e-9)))


def live_summary(run: Run, dataset: str, entry: dict[str, Any]) -> dict[str, Any]:
    """summary.json's entries of a dataset: where conflate scored the lagged decoders, ``live`` (the choice within the
    dataset's budget), ``online`` (lag 0) and ``offline`` (the offline decoders) chosen by the CV criterion among
    every decoder; otherwise ``online`` and ``offline`` as tables.summary chose them, given their decoder, lag and
    forbidden transitions."""
    candidates, rate = scored(run, dataset), rate_of(run, dataset)
    out = dict(entry)
    if any(s.candidate.decoding.decoder.lagged for s in candidates):  # conflate --decode all: choose by the criterion
        for use, budget, offline in (("live", live_budget(run, dataset), False), ("online", 0, False),
                                     ("offline", None, True)):
            best = choose(candidates, budget, offline)
            if best is not None:
                out[use] = {**best.record(rate), "budget_frames": budget, "variant": VARIANTS.get(
                    best.folder.removeprefix(dataset), best.folder), "chosen_by": CHOSEN_BY}
        return out
    for use in ("online", "offline"):
        if use in out:
            decode = out[use]["method"].partition("+")[2] or "none"
            forbidden, _ = _forbidden_and_rules(run, out[use]["folder"]) if run.runs else ({}, False)
            out[use] = {**out[use], "decoder": decode.partition("@")[0],
                        "lag_frames": 0 if use == "online" else None,
                        "forbidden_transitions": forbidden.get(out[use]["method"])}
    return out


def latency_rows(run: Run) -> list[list[str]]:
    """Per paper dataset, decoder and lag: the method the criterion picks there, its cross-validated criterion and
    its test figures (means over seeds), the forbidden transitions it emits on test."""
    rows = []
    for dataset in PAPER_DATASETS:
        candidates, rate = scored(run, dataset), rate_of(run, dataset)
        by: dict[tuple[str, int | None], list[Scored]] = {}
        for s in candidates:
            decoding = s.candidate.decoding
            if decoding.decoder is not Decoder.NONE:
                by.setdefault((decoding.decoder.value, decoding.lag), []).append(s)
        order = sorted(by, key=lambda key: (key[0], -1 if key[1] is None else key[1]))
        for (decoder, lag), group in ((key, by[key]) for key in order):
            best = max(group, key=lambda s: s.candidate.score)
            seconds = "offline" if lag is None else ("?" if rate is None and lag else f"{(lag or 0) / (rate or 1):.2f}")
            rows.append([dataset, decoder, "whole" if lag is None else str(lag), seconds,
                         f"{best.candidate.name} (`{best.folder}`)", f"{best.candidate.score[0]:.1f}",
                         *(_cell(best.test[m]) for m in SHOWN),
                         "–" if best.forbidden is None else f"{best.forbidden:.0f}"])
    return rows


def _cell(value: float | None) -> str:
    return "–" if value is None or value != value else f"{value:.1f}"


LATENCY_HEADER = ["dataset", "decoder", "lag (frames)", "latency (s)", "method chosen by CV (folder)",
                  "CV criterion", "test segment", "test frame", "test edit", "test forbidden"]


def with_live(run: Run, summary: dict[str, Any]) -> dict[str, Any]:
    """summary.json (tables.summary) with each dataset's live entry and its online/offline decoders."""
    return {dataset: live_summary(run, dataset, entry) for dataset, entry in summary.items()}


FIGURE = "latency_{dataset}.png"


def latency_points(run: Run, dataset: str) -> dict[str, list[tuple[int, float, float]]]:
    """Per online decoder, (lag, test segment accuracy, test edit) of the method CV picks at each lag."""
    by: dict[tuple[str, int], list[Scored]] = {}
    for s in scored(run, dataset):
        decoding = s.candidate.decoding
        if decoding.decoder is not Decoder.NONE and not decoding.decoder.offline:
            by.setdefault((decoding.decoder.value, decoding.lag or 0), []).append(s)
    points: dict[str, list[tuple[int, float, float]]] = {}
    for (decoder, lag), group in sorted(by.items()):
        best = max(group, key=lambda s: s.candidate.score)
        family = decoder.replace("filter", "smooth")  # the filter is smoothing at lag 0
        points.setdefault(family, []).append((lag, best.test["segment_accuracy"] or math.nan,
                                              best.test["edit"] or math.nan))
    return {k: sorted(v) for k, v in points.items()}


def figure_latency(run: Run, dataset: str):
    """Test segment accuracy and edit against the lag, per decoder (the method CV picks at each lag), or None."""
    from mlnseq.reporting.figures import pyplot

    points = latency_points(run, dataset)
    if not points:
        return None
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for family, values in points.items():
        lags = [max(lag, 0.5) for lag, _, _ in values]  # lag 0 drawn at 0.5 on the log axis
        style = "--" if family.endswith("-legal") else "-"
        for ax, column in zip(axes, (1, 2)):
            ax.plot(lags, [v[column] for v in values], marker="o", linestyle=style, label=family)
    rate = rate_of(run, dataset)
    unit = f"lag (frames; {rate:g} per second)" if rate else "lag (frames; lag 0 at 0.5)"
    for ax, name in zip(axes, ("test segment accuracy (%)", "test edit")):
        ax.set(xscale="log", xlabel=unit, ylabel=name)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{dataset}: accuracy against latency (each point: the method cross-validation picks)")
    fig.tight_layout()
    return fig
