"""Choosing a method, a decoder and a lag within a latency budget, on the cross-validated figures conflate records
(never on test), and the recordings' frame rate that turns a lag into seconds.

Candidates: every method conflate cross-validated, undecoded (lag 0) and with every decoder at every lag it was
scored at, within the budget (offline decoders only without one). Where the chain has hard rules (a transition
factor of -inf), only decoders that keep them are candidates (the -legal forms and viterbi). The choice (``best``):
the frames first, then their order. Among the candidates whose cross-validated frame accuracy is at least the
network alone's (where it is a candidate), those whose frame accuracy is within one standard error of the best
one's (the error of their per-fold differences from it: a one-standard-error rule) are near the best; among them
the best mean of the cross-validated segment accuracy, frame accuracy and edit score, ties broken by the
out-of-fold log-likelihood of the true labels. Segment accuracy alone moves in steps of 2-8 points on the few
dozen segments of a training split, and the edit score punishes a few flickering frames that cost little
frame accuracy; the mean of the three follows what a live user reads once the frames are as good as they get.
Without per-fold figures (a workdir conflated before they were recorded) every candidate at or above the network
alone's frame accuracy is near the best.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from mlnseq.catalog.decoders import DEFAULT_LAGS, ONLINE, Decoder, Decoding, parse_decoding
from mlnseq.catalog.errors import BadInput
from mlnseq.catalog.methods import Method

CRITERION = ("segment_accuracy", "frame_accuracy", "edit")


def rate_of(frames_meta: dict[str, Any]) -> float | None:
    """Frames per second of a workdir's recordings, as collect recorded it: the reading's rate (bags), the source's
    own rate (the Fetch simulation's steps), or None."""
    reading = frames_meta.get("reading") or {}
    for rate in (reading.get("rate") if isinstance(reading, dict) else None, frames_meta.get("rate_hz")):
        if isinstance(rate, (int, float)) and not isinstance(rate, bool) and rate > 0:
            return float(rate)
    return None


def criterion(figures: dict[str, float]) -> float:
    """The mean of the cross-validated segment accuracy, frame accuracy and edit score (-inf where one is missing)."""
    accuracy = sum(figures.get(k, math.nan) for k in CRITERION) / len(CRITERION)
    return accuracy if accuracy == accuracy else -math.inf


@dataclass(frozen=True)
class Candidate:
    name: str  # as predictions name it: conflation+smooth-legal@5
    method: str
    decoding: Decoding
    figures: dict[str, float]
    fold_frames: tuple[float, ...] = ()  # cross-validated frame accuracy (%) per fold, where conflate recorded it

    @property
    def score(self) -> tuple[float, float]:
        return (criterion(self.figures), self.figures.get("log_likelihood", -math.inf))

    def record(self) -> dict[str, Any]:
        return {"name": self.name, "method": self.method, "decoder": self.decoding.decoder.value,
                "lag_frames": self.decoding.lag, "criterion": self.score[0], "log_likelihood": self.score[1],
                "cv": self.figures}


def candidates(figures: dict[str, dict[str, float]], fold_frames: dict[str, list[float]] | None = None
               ) -> list[Candidate]:
    """Every cross-validated method of a predictions table's metadata, with its decoding and, where given, its
    frame accuracy per fold."""
    out = []
    for name, values in figures.items():
        method, plus, decode = name.partition("+")
        decoding = parse_decoding(decode, "decoding") if plus else Decoding(Decoder.NONE)
        out.append(Candidate(name, method, decoding, values, tuple((fold_frames or {}).get(name, ()))))
    return out


def budget_frames(lag: int | None, latency_s: float | None, rate_hz: float | None, where: str) -> int | None:
    """The budget in frames from --lag or --latency (None: no budget); --latency needs a known rate."""
    if lag is not None and latency_s is not None:
        raise BadInput("give --lag FRAMES or --latency SECONDS, not both")
    if lag is not None:
        if lag < 0:
            raise BadInput(f"--lag {lag}: a lag is at least 0 frames")
        return lag
    if latency_s is None:
        return None
    if not latency_s >= 0:
        raise BadInput(f"--latency {latency_s:g}: a latency is at least 0 seconds")
    if rate_hz is None:
        raise BadInput(f"--latency: the frame rate of {where}'s recordings is not known; give the budget as --lag "
                       "FRAMES instead")
    return int(math.floor(latency_s * rate_hz + 1e-9))


def within(candidate: Candidate, budget: int | None, decoder: Decoder | None, hard_rules: bool) -> bool:
    """Whether a candidate fits: its lag within ``budget`` frames (None: any, offline included), the decoder asked
    (None: any), and the hard rules kept where the chain has them."""
    decoding = candidate.decoding
    if decoder is not None and decoding.decoder is not decoder:
        return False
    if hard_rules and decoding.decoder is not Decoder.NONE and not decoding.decoder.legal:
        return False
    if hard_rules and decoding.decoder is Decoder.NONE:
        return False  # per-frame classes ignore the rules
    if budget is None:
        return True
    return not decoding.decoder.offline and (decoding.lag or 0) <= budget


def choose(figures: dict[str, dict[str, float]], budget: int | None, decoder: Decoder | None = None,
           hard_rules: bool = False, where: str = "the workdir", fold_frames: dict[str, list[float]] | None = None
           ) -> tuple[Candidate, list[Candidate]]:
    """The best candidate (``best``), and all those that fitted; none fits: a BadInput saying why."""
    fitting = [c for c in candidates(figures, fold_frames) if within(c, budget, decoder, hard_rules)]
    if not fitting:
        what = f"{decoder.value} " if decoder is not None else ""
        limit = "" if budget is None else f" within {budget} frame(s)"
        raise BadInput(f"no cross-validated {what}candidate in {where}{limit}"
                       + (" that keeps its hard rules" if hard_rules else "")
                       + (": run `mlnseq conflate --decode all` (`mlnseq fit --offline` conflates offline decoders too)"
                          if decoder is not None and decoder.offline else
                          ": run `mlnseq conflate --decode all` (with --lags including smaller lags) or allow more"))
    return best(fitting), fitting


def best(fitting: list[Candidate]) -> Candidate:
    """The frames first, then their order: among the candidates at or above the network alone's cross-validated
    frame accuracy (the undecoded network among ``fitting``; where it is not among them, all), those near the best
    frame accuracy (``near_best``), and among these the best criterion. The floor: a method chosen for its segments
    or order never loses frames to the network alone, whose fold networks are weaker than the one refit."""
    networks = [c for c in fitting if c.method == "lstm" and c.decoding.decoder is Decoder.NONE]
    floor = max((frames(c) for c in networks), default=-math.inf)
    kept = [c for c in fitting if frames(c) >= floor] or fitting
    return max(near_best(kept), key=lambda c: c.score)


def ranked(fitting: list[Candidate]) -> list[Candidate]:
    """The candidates in the order ``best`` takes them: the choice, then the choice among the rest, and so on."""
    left, order = list(fitting), []
    while left:
        order.append(best(left))
        left.remove(order[-1])
    return order


def near_best(kept: list[Candidate]) -> list[Candidate]:
    """The candidates whose cross-validated frame accuracy is within one standard error of the best one's: the
    standard error of their per-fold differences from it (a one-standard-error rule: a difference the folds do not
    show apart from their spread decides nothing). Without per-fold figures, all of ``kept``."""
    top = max(kept, key=frames)
    if len(top.fold_frames) < 2:
        return kept
    return [c for c in kept if frames(c) >= frames(top) - standard_error(c.fold_frames, top.fold_frames)]


def standard_error(ours: tuple[float, ...], theirs: tuple[float, ...]) -> float:
    """The standard error of the mean per-fold difference (0 where the folds differ in number or are too few)."""
    if len(ours) != len(theirs) or len(ours) < 2:
        return 0.0
    difference = [a - b for a, b in zip(ours, theirs)]
    mean = sum(difference) / len(difference)
    variance = sum((d - mean) ** 2 for d in difference) / (len(difference) - 1)
    return math.sqrt(variance / len(difference))


def frames(candidate: Candidate) -> float:
    value = candidate.figures.get("frame_accuracy", math.nan)
    return value if value == value else -math.inf


# --- fit's budget, what conflate scores within it, and the choice said back -----------------------------------
FALLBACK = (Method.CONFLATION, Decoding(Decoder.FILTER))  # without folds nothing is chosen: network and MLN, filtered


def fit_budget(lag: int | None, latency_s: float | None, offline: bool, rate_hz: float | None) -> int | None:
    """fit's budget in frames: None offline (no budget), else --lag or --latency at ``rate_hz``, else 0 (each frame
    decided as it comes)."""
    if offline:
        return None
    return 0 if lag is None and latency_s is None else budget_frames(lag, latency_s, rate_hz, "the source")


def scored_within(budget: int | None, hard_rules: bool) -> tuple[tuple[Decoder, ...], tuple[int, ...]]:
    """The decoders and lags conflate scores for a budget: undecoded, the online decoders (all, offline too, without
    a budget), the -legal forms only where the chain has hard rules (without, they decode as the free forms); at
    conflate's default lags within the budget and at the budget itself."""
    decoders = tuple(d for d in Decoder if (hard_rules or d.free is d)
                     and (budget is None or d is Decoder.NONE or d in ONLINE))
    return decoders, DEFAULT_LAGS if budget is None else tuple(sorted({n for n in DEFAULT_LAGS if n <= budget}
                                                                      | {budget}))


STEADIER_FRAMES = 0.5  # points of cross-validated frame accuracy a steadier candidate gives up at most
STEADIER_EDIT = 10.0  # points of cross-validated edit score it gains at least


@dataclass(frozen=True)
class Standing:
    """A choice as fit says it: the choice, the runner-up and the network alone (where neither of them), with their
    cross-validated figures, ranked as ``best`` takes them among ``among`` candidates; and ``steadier``, where one
    flickers far less for a fraction of a point of frames (``steadier``)."""

    chosen: Candidate
    runner_up: Candidate | None
    network_alone: Candidate | None
    among: int
    steadier: Candidate | None = None


def steadier(order: list[Candidate], chosen: Candidate) -> Candidate | None:
    """The first of ``order`` (as ``best`` ranks them) other than ``chosen`` whose cross-validated frame accuracy is
    within STEADIER_FRAMES points of the choice's and whose edit score is STEADIER_EDIT points higher: for live use,
    where a flickering class is read as a new phase, the better trade; None where there is none."""
    edit = chosen.figures.get("edit", math.nan)
    return next((c for c in order if c is not chosen and frames(c) >= frames(chosen) - STEADIER_FRAMES
                 and c.figures.get("edit", -math.inf) >= edit + STEADIER_EDIT), None)


def standing(cross_validation: dict[str, Any], chosen: str, among: Any) -> Standing:
    """export's choice ``chosen`` among the names ``among``, read back from a predictions table's cross-validated
    figures (``cross_validation`` of its metadata)."""
    names = set(among)
    order = ranked([c for c in candidates(cross_validation["figures"], cross_validation.get("fold_frame_accuracy"))
                    if c.name in names])
    best_one = next(c for c in order if c.name == chosen)
    others = [c for c in order if c is not best_one]
    alone = next((c for c in others[1:] if c.method == Method.NETWORK and c.decoding.decoder is Decoder.NONE), None)
    return Standing(best_one, others[0] if others else None, alone, len(order), steadier(order, best_one))


AUTO = "auto"  # export --method auto: the method, decoder and lag with the best cross-validated figures
SCORED_ALWAYS = ("none", "filter", "viterbi")  # decoders export runs without asking conflate whether it scored them


@dataclass(frozen=True)
class Picked:
    """What export writes: the method and its decoding (chosen by cross-validation with --method auto), the lag in
    seconds, the recordings' rate and the chains' start distribution (log, per class; decoded methods)."""

    method: str
    decoding: Decoding
    chosen: Any  # model.manifest.Chosen or None
    latency_s: float | None
    rate_hz: float | None
    start: list[float] | None


def pick(workdir: Any, method: str, decode: str, lag: int | None, latency_s: float | None,
         frames_meta: dict[str, Any]) -> Picked:
    """export's method and decoding: ``--method auto`` chooses within the budget (--lag or --latency), else
    ``--decode`` with ``--lag`` (a lagged decoder conflate must have scored)."""
    from mlnseq.catalog.methods import decoded_name

    rate = rate_of(frames_meta)
    decoder = Decoder(decode)
    chosen = None
    if method == AUTO:
        chosen, method, decoding = _auto(workdir, decoder, budget_frames(lag, latency_s, rate, str(workdir)))
    else:
        if latency_s is not None and decoder.lagged:
            lag = budget_frames(None, latency_s, rate, str(workdir))
        if decoder.lagged and lag is None:
            raise BadInput(f"--decode {decoder.value} waits a number of frames: give --lag FRAMES "
                           "(or --latency SECONDS)")
        decoding = Decoding(decoder, lag)
        if decoder.value not in SCORED_ALWAYS:
            name = decoded_name(method, decoding.name)
            if name not in _scored(workdir, f"--decode {decoding.name}").get("methods", []):
                raise BadInput(f"--decode {decoding.name}: {workdir} has no {name} predictions; run `mlnseq conflate "
                               f"--decode {decoder.value}" + (f" --lags {decoding.lag}`" if decoder.lagged else "`")
                               + " first")
    offline = decoding.decoder.offline
    start = None if decoding.decoder is Decoder.NONE else start_distribution(workdir).tolist()
    return Picked(str(method), decoding, chosen, None if offline else decoding.latency_s(rate), rate, start)


def _auto(workdir: Any, decoder: Decoder, budget: int | None) -> tuple[Any, str, Decoding]:
    """``--method auto``: the candidate with the best criterion within the budget, and its record."""
    from mlnseq.catalog.methods import Method
    from mlnseq.model.manifest import Chosen

    meta = _scored(workdir, f"--method {AUTO}")
    cross_validation = meta.get("cross_validation") or {}
    figures = cross_validation.get("figures") or {}
    if not figures:
        raise BadInput(f"--method {AUTO}: {workdir} holds no cross-validated figures; train its networks with "
                       f"folds (`mlnseq train --folds K`, and `mlnseq learn-weights --folds K`), then run "
                       f"`mlnseq conflate --decode all`")
    best, fitting = choose(figures, budget, None if decoder is Decoder.NONE else decoder,
                           bool(meta.get("hard_rules")), str(workdir), cross_validation.get("fold_frame_accuracy"))
    chosen = Chosen(Method(best.method), best.name, best.figures, best.score[0],
                    {c.name: c.figures for c in fitting}, cross_validation["folds"]["k"], budget)
    return chosen, best.method, best.decoding


def _scored(workdir: Any, option: str) -> dict[str, Any]:
    from mlnseq.catalog import artifacts

    path = workdir / artifacts.PREDICTIONS
    if not path.exists():
        raise BadInput(f"{option} reads the figures conflate records: {path} not found; run `mlnseq conflate "
                       "--decode all` first")
    return artifacts.read_metadata(path, "predictions")


def start_distribution(workdir: Any) -> Any:
    """The chains' start distribution (log [C]) from the training split's episodes, as conflate fits it."""
    import numpy as np
    import polars as pl

    from mlnseq.catalog import artifacts
    from mlnseq.fusion.decoding import training_start

    frames = artifacts.labelled(pl.read_parquet(workdir / artifacts.FRAMES, columns=["episode", "label", "split"]))
    meta = artifacts.read_metadata(workdir / artifacts.FRAMES, "frames")
    return training_start(frames["label"].to_numpy().astype(np.int64), frames["episode"].to_numpy(),
                          frames["split"].to_numpy(), len(meta["classes"]))
