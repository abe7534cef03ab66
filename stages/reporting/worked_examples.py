"""The report's worked examples: per paper dataset, a test segment the MLN's method got right and the network alone
got wrong, and one it got wrong, each explained term by term (stages/explaining/explainer.py) as `mlnseq explain`
prints it: the segment's middle frame against the class the network said (or the true class), and what held the
segment. Read from the dataset's learned-transitions folder (D-temporal, stream mode, its first seed): its workdir's
networks, MLN and the network weight and start distribution conflate decoded it with."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.catalog.methods import Method, network_of, parse_method
from mlnseq.mln import chain
from mlnseq.mln.factors import MLNFactors, parse_weights
from mlnseq.mln.formula_sources import annotated, formulas_of, read_written, written_lines
from mlnseq.fusion.decoding import decode as decoded_by, decoding_of
from mlnseq.explaining.frames import explain
from mlnseq.explaining.explainer import Explainer, Keys, Scores, Scoring
from mlnseq.explaining.segments import held_by
from mlnseq.explaining.text import table, term_lines
from mlnseq.fusion.fuse import EPSILON, chain_of
from mlnseq.choosing.workdir_inputs import read_workdir
from mlnseq.timeline import sequences

METHOD = "combined+filter"  # the method explained: PriorLayer and the MLN, decoded online
FOLDER = "{dataset}-temporal"


@dataclass(frozen=True)
class Decided:
    """A workdir's method decided again as conflate decided it, with what an explanation reads."""

    explainer: Explainer
    scores: Scores
    keys: Keys
    labels: np.ndarray
    network: np.ndarray  # the network alone's classes, from the predictions
    test: np.ndarray  # bool: the test split


def decided(workdir: Path) -> Decided | None:
    """The workdir's METHOD as conflate decoded it (None where it was not)."""
    predictions_path = workdir / artifacts.PREDICTIONS
    if not predictions_path.exists():
        return None
    meta = artifacts.read_metadata(predictions_path, "predictions")
    if METHOD not in meta.get("methods", []):
        return None
    method, decode = parse_method(METHOD)
    network = network_of(method)
    inputs = read_workdir(workdir, (network,))
    mln, trained = inputs.mln, inputs.networks[network]
    weights_path = workdir / artifacts.WEIGHTS
    weights, formulas_path = mln.weights, formulas_of(weights_path, artifacts.read_metadata(weights_path, "weights"))
    if formulas_path is not None:
        weights = annotated(weights, written_lines(formulas_path.read_text(encoding="utf-8"), formulas_path))
    counted = [not (w == 0.0 and not h) for w, h in weights.select("weight", "hard").iter_rows()]
    written = tuple(row for row, kept in zip(read_written(weights), counted) if kept)
    weight = (meta.get("network_weights", {}).get(METHOD, {}).get("weight") or meta.get("network_weight_option")
              or 1.0)
    start = None if meta.get("start") is None else np.asarray(meta["start"], dtype=np.float64)
    factors = chain_of(method, MLNFactors.from_weights(mln.weights, mln.columns, inputs.classes), mln.evidence,
                       chain.chain_starts(inputs.data.episodes, trained.parts), trained.log_probs, float(weight), start)
    found = decoded_by(factors, decode)
    scoring = Scoring(Method(method), decoding_of(decode), tuple(inputs.classes), tuple(mln.columns),
                      tuple(parse_weights(mln.weights, mln.columns, inputs.classes)), written, str(network),
                      float(weight), start, epsilon=EPSILON)
    scores = Scores(mln.evidence, trained.log_probs, None, factors, found.path, found.probabilities, decode)
    table_ = pl.read_parquet(predictions_path, columns=["episode", "frame", artifacts.pred_column("lstm")])
    keys = Keys(table_["episode"].to_list(), table_["frame"].to_numpy())
    return Decided(Explainer(scoring), scores, keys, inputs.data.labels,
                   table_[artifacts.pred_column("lstm")].to_numpy(), inputs.data.splits == "test")


def _picked(run: Decided) -> list[tuple[str, slice]]:
    """(what, the true segment) of the longest test segment METHOD got right and the network wrong, and of the longest
    it got wrong (a segment is got right when half of its frames are)."""
    test = np.flatnonzero(run.test)
    found: dict[str, slice] = {}
    for span in sequences.runs(np.asarray(run.keys.episode)[test], run.labels[test]):
        rows = test[span]
        right = (run.scores.path[rows] == run.labels[rows]).mean() >= 0.5
        network = (run.network[rows] == run.labels[rows]).mean() >= 0.5
        kind = "right" if right and not network else ("wrong" if not right else None)
        if kind and (kind not in found or len(rows) > found[kind].stop - found[kind].start):
            found[kind] = slice(int(rows[0]), int(rows[-1]) + 1)
    return [(kind, found[kind]) for kind in ("right", "wrong") if kind in found]


def _run_around(run: Decided, row: int) -> slice:
    """The decided segment (a run of one decided class within an episode) holding ``row``."""
    path, episodes = run.scores.path, run.keys.episode
    first, last = row, row
    while first > 0 and path[first - 1] == path[row] and episodes[first - 1] == episodes[row]:
        first -= 1
    while last + 1 < len(path) and path[last + 1] == path[row] and episodes[last + 1] == episodes[row]:
        last += 1
    return slice(first, last + 1)


def _example(run: Decided, kind: str, rows: slice, dataset: str) -> list[str]:
    """One worked example: the true segment, a frame of it explained (the middle one of those the method got right
    and the network wrong, or of those it got wrong), then what held its decided segment and what ended it."""
    classes, labels, path = run.explainer.scoring.classes, run.labels, run.scores.path
    span = np.arange(rows.start, rows.stop)
    chosen = span[(path[span] == labels[span]) & (run.network[span] != labels[span])] if kind == "right" \
        else span[path[span] != labels[span]]
    frame = int(chosen[len(chosen) // 2])
    truth, said = classes[labels[frame]], classes[int(run.network[frame])]
    versus = int(run.network[frame]) if kind == "right" else int(labels[frame])
    first, last = run.keys.at(rows.start)[1], run.keys.at(rows.stop - 1)[1]
    heading = ("a segment the MLN got right and the network alone wrong" if kind == "right"
               else "a segment the MLN got wrong")
    [found] = explain(run.explainer, run.scores, [frame], versus, run.keys)
    around = _run_around(run, frame)
    held = held_by(explain(run.explainer, run.scores, list(range(around.start, around.stop)), None, run.keys))
    against = f"the network's {said}" if kind == "right" else f"the true {truth}"
    out = [f"### {dataset}: {heading}\n",
           f"Test episode {run.keys.episode[rows.start]}, frames {first}-{last}, truly {truth}: {METHOD} decided "
           f"{(path[span] == labels[span]).mean():.0%} of its frames right, the LSTM alone "
           f"{(run.network[span] == labels[span]).mean():.0%}. Frame {run.keys.at(frame)[1]}, against {against}:\n",
           "```", *table(found), "```\n",
           f"What held {classes[path[frame]]} there (frames {run.keys.at(around.start)[1]}-"
           f"{run.keys.at(around.stop - 1)[1]}; each term's mean over them, against each frame's runner-up):\n",
           "```", *term_lines(list(held)[:6]), "```\n"]
    if around.stop < len(path) and run.keys.episode[around.stop] == run.keys.episode[frame]:
        [ended] = explain(run.explainer, run.scores, [around.stop], int(path[frame]), run.keys)
        out += [f"What ended it at frame {ended.frame} ({ended.chosen} over {ended.versus} by {ended.margin:.3f}):\n",
                "```", *term_lines(ended.largest(4)), "```\n"]
    return out


def worked_examples(runs: Path, datasets: list[str], seeds: dict[str, int]) -> list[str]:
    """The report's section: each dataset's examples (none where its learned-transitions folder was not decoded)."""
    out = ["## Why: worked examples\n",
           f"Each explanation is `mlnseq explain`'s for {METHOD} over the dataset's learned-transitions workdir "
           "(stream mode, its first seed): the margin of the frame's class over another as the sum of its terms "
           "(formulas, the network, the frames before), exact to rounding ([docs/explain.md](../docs/explain.md)).\n"]
    for dataset in datasets:
        folder = FOLDER.format(dataset=dataset)
        if folder not in seeds:
            continue
        run = decided(Path(runs) / folder / "stream" / f"seed-{seeds[folder]}")
        if run is None:
            continue
        for kind, rows in _picked(run):
            out += _example(run, kind, rows, dataset)
    return out if len(out) > 2 else []
