"""REPORT.md: every section in Markdown, its numbers from the tables and claims."""

from __future__ import annotations

import numpy as np

from mlnseq.reporting.claims import claims, deploy_sentence, efficiency_claim, rich_spec_claim, target_checks
from mlnseq.reporting.loading import PAPER_DATASETS, RICH, TEMPORAL, VARIANTS, Run, present
from mlnseq.reporting.tables import (
    ablation_table, datasets_table, decoded_table, deploy_table, efficiency_points, efficiency_table,
    per_class_table, rich_spec_table, stream_table, table_iii, timings_table, wall_seconds, weights_table,
)

SEQUENCE_HEADER = ["segment acc.", "frame acc.", "edit", "F1@50", "network factor weight", "CV segment acc.", "CV edit"]


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    if not rows:
        return "_nothing to show: this run has no such results._\n"
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def render(run: Run, figures: dict[str, str], timelines: dict[str, str] | None = None,
           examples: list[str] | None = None) -> str:
    """REPORT.md: every section, its numbers from ``run``; ``figures`` maps a figure key to its file name,
    ``timelines`` a dataset to what its timeline figure shows, ``examples`` the worked examples' lines."""
    datasets = present(run, PAPER_DATASETS)
    out = _title(run, [d for d in PAPER_DATASETS if d not in datasets])
    out += _paper_tables(run, datasets)
    out += _paper_figures(figures, datasets)
    out += _data_efficiency(run, figures)
    out += _weights_and_specs(run, datasets)
    out += _stream_mode(run)
    out += sequential_logic(run, figures, timelines or {})
    out += examples or []
    out += _timings(run)
    out += _hyper_parameters(run)
    out.append("## Differences from the paper\n")
    out.append("\n".join(f"- {line}" for line in differences(run)) + "\n")
    return "\n".join(out)


def _title(run: Run, missing: list[str]) -> list[str]:
    out = ["# mlnseq: reproduction of Rahman et al., RO-MAN 2021\n",
           "Every number below is read from the artifacts of this run "
           f"({', '.join(sorted(run.datasets))}); nothing is copied from the paper except its own columns.\n"]
    if missing:
        out.append(f"**Not run:** {', '.join(missing)} (its data was not found when `make reproduce` ran).\n")
    return out


def _paper_tables(run: Run, datasets: list[str]) -> list[str]:
    """Table III (segment accuracy beside the paper's), the claims checked on it, and Table IV (per class)."""
    out = ["## Table III: segment accuracy, paper vs mlnseq\n",
           "Segment recognised at half of its frames (the paper's metric), `segment` mode, **last epoch, "
           "mean ± std over seeds** (%). The last column is the best test epoch's frame accuracy per seed, "
           "**optimistic**: it selects on the test split, as the published numbers do.\n",
           markdown_table(["dataset", "method", "paper", "mlnseq (last epoch)", "seeds",
                           "frame accuracy (last epoch)", "best test epoch, as in the paper (optimistic)"],
                          table_iii(run))]
    out.append("### Do the paper's claims hold here?\n")
    out.append("\n".join(f"- {line}" for line in claims(run)) + "\n")

    out.append("## Table IV: per-class segment accuracy\n")
    for dataset in datasets:
        out.append(f"**{dataset}** (%, mean ± std over seeds)\n")
        out.append(markdown_table(["class", "LSTM", "MLN", "combined"], per_class_table(run, dataset)))
    return out


def _paper_figures(figures: dict[str, str], datasets: list[str]) -> list[str]:
    """Fig. 7 and 8 (accuracy per epoch) and the confusion matrices."""
    out = ["## Fig. 7: test accuracy per epoch\n", f"![Fig. 7]({figures['fig7']})\n",
           "Drawn: the LSTM's and PriorLayer's test **frame** accuracy after every epoch (mean, band ± std over "
           "seeds), from the training logs. The MLN has no epochs (flat line). Conflation and the combined "
           "model are computed from the final networks only, so they appear as one point at the last epoch; "
           "their per-epoch curves would need every epoch's network, which is not kept.\n"]
    out.append("## Fig. 8: train vs test accuracy per epoch\n")
    out.append(f"![Fig. 8]({figures['fig8']})\n")
    out.append("PriorLayer's regularisation claim, checked on these curves, is listed under Table III.\n")

    out.append("## Confusion matrices (LSTM and combined)\n")
    for dataset in datasets:
        out.append(f"![confusion {dataset}]({figures['confusion'].format(dataset=dataset)})\n")
    out.append("Segments of the test split, counts summed over seeds, each row normalised to its true class.\n")
    return out


def _data_efficiency(run: Run, figures: dict[str, str]) -> list[str]:
    points = efficiency_points(run)
    out = ["## Data efficiency: where do the logic constraints stop helping?\n",
           f"![data efficiency]({figures['efficiency']})\n"]
    out.append("The same Fetch episodes (collection seed fixed); the first share of them trains, the MLN learns its "
               "weights on that part only, the rest is the test split"
               + (f"; the smallest point is the paper's split ({run.datasets['fetch']['n_train']:,} frames, "
                  "folder `fetch`)" if "fetch" in run.datasets else "")
               + ". Segment accuracy (%), mean ± std over training seeds.\n")
    out.append(markdown_table(["training share", "training frames", "LSTM", "MLN", "combined", "combined − LSTM"],
                              efficiency_table(points)))
    out.append(efficiency_claim(points) + "\n")
    return out


def _weights_and_specs(run: Run, datasets: list[str]) -> list[str]:
    """The strongest learned formulas per class, and Fetch's richer predicate spec against the paper's."""
    out = ["## Learned weights: strongest formulas per class (Table II style)\n"]
    for dataset in datasets:
        out.append(f"**{dataset}** ({run.datasets[dataset]['spec']})\n")
        out.append(markdown_table(["class", "weight", "formula"], weights_table(run, dataset)))

    out.append("## Fetch: richer predicate spec vs the paper's\n")
    rich = run.datasets.get(RICH)
    spec = f" (`{rich['spec']}`)" if rich else ""
    out.append(f"Segment mode, segment accuracy (%), mean ± std over seeds. The rich spec{spec} needs the goal "
               "position, so its frames carry the 6 goal values too: its LSTM row also sees them; the MLN row "
               "isolates what the knowledge itself buys.\n")
    out.append(markdown_table(["method", "paper spec", "rich spec"], rich_spec_table(run) if rich else []))
    verdict = rich_spec_claim(run)
    if verdict:
        out.append(f"Rich minus paper spec: {verdict}.\n")
    return out


def _stream_mode(run: Run) -> list[str]:
    return ["## Stream mode: no segment boundaries at test\n",
            "Networks trained on fixed windows and run over whole episodes (`--mode stream`); segment "
            "accuracy (%), frame accuracy (%), segmental edit score and F1@{10,25,50} (Lea et al.), mean ± std. "
            "`D-tcn`: the same with a causal TCN in place of the LSTM (`train --cell tcn`).\n",
            markdown_table(["dataset", "method", "segment acc.", "frame acc.", "edit", "F1@10", "F1@25", "F1@50"],
                           stream_table(run))]


def _timings(run: Run) -> list[str]:
    wall = wall_seconds(run.timings)
    total = f"{wall:.0f} s from the first stage's start to the last stage's end" if wall is not None else "not recorded"
    return ["## Timings and machine\n",
            f"Stage time (seconds, the latest run of each command; two jobs at a time): {total}.\n",
            markdown_table(["stage", "runs", "total s", "mean s", "longest s"], timings_table(run.timings)),
            markdown_table(["", ""], [[k, v] for k, v in run.machine.items()])]


def _hyper_parameters(run: Run) -> list[str]:
    return ["## Hyper-parameters used\n",
            "Read from the artifacts' metadata: each dataset folder, then every stage's options (several values "
            "where runs differ).\n",
            markdown_table(["dataset folder", "source", "frames", "training frames", "features", "predicate spec",
                            "formulas", "epochs"],
                           datasets_table(run)),
            markdown_table(["stage", "option", "values"],
                           [[stage, name, ", ".join(map(str, values))]
                            for stage, options in run.settings.items() for name, values in options.items()]
                           + [["train", "seeds", ", ".join(map(str, sorted(run.metrics["seed"].unique())))]])]


def differences(run: Run) -> list[str]:
    lines = [
        "Fetch data come from our own scripted controller on Gymnasium-Robotics v4 (FetchPickAndPlace-v4, "
        "MuJoCo), not from the authors' Gym v1 demonstrations, whose test kinematics were not released; the "
        "split is the paper's (first 126 frames train).",
        "DESK test frames carry only the arm distance and the two gripper openings, so on DESK the recurrent "
        "models see those three channels, not the 14 kinematics of the training file.",
        "Headline numbers are the last epoch's in segment mode (the paper's protocol), mean ± std over training "
        "seeds, also in stream mode, where the networks train on the whole training split and, beside them, one "
        "network per fold of it (`train --folds K`): the decoded methods' network factor weight is learned and the "
        "method to deploy chosen on their out-of-fold predictions (docs/choosing.md). No epoch, weight or method is "
        "chosen on the test split. The "
        "published Table III numbers match single best epochs of the authors' test curves (there was no "
        "validation split); the optimistic column above shows what that selection does here.",
        "The figures' per-epoch curves are frame accuracy; Table III is segment accuracy at half a segment.",
    ]
    fetch = run.datasets.get("fetch")
    if fetch is not None:
        lines.append(f"Fetch: {fetch['n_frames']:,} frames ({fetch['n_train']:,} train) from "
                     f"{fetch.get('env_id', 'the simulator')}; episodes that succeeded: "
                     f"{np.mean(fetch.get('episode_success', [np.nan])):.1%}.")
    return lines



def sequential_logic(run: Run, figures: dict[str, str], timelines: dict[str, str]) -> list[str]:
    """Issue 12's sections: the decoded rows, the ablation, the timelines, the method to deploy and the targets."""
    return [*_decoded(run), *_ablation(run), *_timelines(figures, timelines), *_deploy(run), *_targets(run)]


def _decoded(run: Run) -> list[str]:
    out = ["## Sequential logic: decoded methods\n",
           f"Folders `DATASET{TEMPORAL}`: the paper dataset's frames and predicates with `examples/temporal.mln` (the "
           "paper's template plus a learned weight per pair of consecutive classes, `Topic(+c1, p) ^ Next(p, q) => "
           "Topic(+c2, q)`), learned by exact conditional likelihood (cll). Each seed workdir runs the paper "
           "dataset's LSTM of the same mode and seed and a PriorLayer trained on these weights (stream mode only; "
           "segment mode decodes the LSTM, the MLN and their conflation). `conflate --decode all` adds, per "
           "method, **+ filter** (online: each frame from the frames up to it) and **+ Viterbi** (offline: the "
           "most probable path of the episode), over a chain whose per-frame factor is the MLN's (mln, conflation, "
           "combined) plus a weight times the network's log-probabilities, and whose transitions are the learned "
           "temporal formulas. In stream mode that weight is learned per seed by the chain's exact conditional "
           "likelihood on the out-of-fold network log-probabilities of the training split (the values over seeds "
           "are shown); segment mode has no folds (the paper's protocol), so it stays 1. "
           "Test split, mean ± std over seeds: segment accuracy and frame accuracy (%), edit score and F1@50 "
           "(stream mode, and the MLN alone, which sees no boundaries); the last two columns are cross-validated "
           "on the training split (each fold predicted by the networks, MLN weights and network factor weight "
           "fitted without it; stream mode).\n"]
    out.append(markdown_table(["dataset", "mode", "method", *SEQUENCE_HEADER], decoded_table(run)))
    notes = [f"`{folder}` ({mode}): {note}" for (folder, mode), lines in sorted(run.notes.items())
             for note in lines if any(folder == d + s for d in PAPER_DATASETS for s in VARIANTS)]
    if notes:
        out.append("Notes from `conflate`:\n\n" + "\n".join(f"- {n}" for n in notes) + "\n")
    return out


def _ablation(run: Run) -> list[str]:
    out = ["## Ablation: transitions, hard order, conjunctive transitions, network factor weight\n",
           "Stream mode, the methods that need no retraining, each decoded; the same networks in every row of a "
           "method. Variants: **no transitions** — the paper dataset's own folder (`paper.mln`, pll weights), "
           "decoded with uniform transitions (each frame's argmax of its factor); **learned transitions** — "
           f"`DATASET{TEMPORAL}`; **plus hard order** — `DATASET-order`, `examples/DATASET.order.mln`: "
           "temporal.mln plus the order of the task as hard rules (Fetch: reach, grasp, transport, place, a "
           "phase may be skipped but never revisited; DESK: S1 → … → S7 → S1), which forbid every other "
           "transition; **conjunctive transitions** — `DATASET-conjunctive`, `examples/conjunctive.mln`: the "
           "transition template written as `0.0 Topic(+c1, p) ^ Next(p, q) ^ Topic(+c2, q)` (the same chains; "
           "the L2 prior pulls the two forms toward different weights); **network factor weight fixed at 1** — "
           "`DATASET-fixed-weight`, the learned-transitions workdirs decoded with `--network-weight 1`: the "
           "network weight learned (the learned-transitions rows) against fixed at 1.\n"]
    for dataset in present(run, PAPER_DATASETS):
        out.append(f"**{dataset}**\n")
        out.append(markdown_table(["method", "variant", *SEQUENCE_HEADER], ablation_table(run, dataset)))
    return out


def _timelines(figures: dict[str, str], timelines: dict[str, str]) -> list[str]:
    out = ["## Timeline of one test episode\n"]
    for dataset, what in timelines.items():
        out.append(f"![timeline {dataset}]({figures['timeline'].format(dataset=dataset)})\n")
        out.append(f"{dataset}: {what}. Rows: the true labels, the LSTM, and the online and offline methods chosen "
                   "by cross-validation (next section).\n")
    if not timelines:
        out.append("_nothing to show: this run has no decoded stream-mode results._\n")
    return out


def _deploy(run: Run) -> list[str]:
    out = ["## Which decoded method to deploy\n",
           "Stream mode (no segment boundaries at test, as a deployed recogniser sees frames). Candidates: every "
           "decoded method of the no-transitions, learned-transitions, hard-order and conjunctive-transitions "
           "folders. Each is cross-validated on the training split: every fold is predicted by the fold "
           "networks, the fold's MLN weights and a network factor weight learned without it. The online (+ "
           "filter) and offline (+ Viterbi) choices are export --method auto's on the means over seeds: the frames "
           "first (within one standard error of the best cross-validated frame accuracy, fold by fold), then the "
           "best mean of cross-validated segment accuracy, frame accuracy and edit; the test figures (mean ± std) "
           "are shown beside, never used. Ties go to the first in the order no transitions, learned transitions, "
           "hard order, conjunctive, then LSTM, MLN, PriorLayer, Conflation, combined.\n",
           markdown_table(["dataset", "use", "method", "variant (folder)", "CV segment acc.", "CV frame acc.",
                           "CV edit", "CV F1@50", "test segment acc.", "test frame acc.", "test edit",
                           "test F1@50"], deploy_table(run))]
    out += live_section(run)
    sentences = [line for line in (deploy_sentence(run, d) for d in PAPER_DATASETS) if line]
    if sentences:
        out.append("\n".join(f"- {line}" for line in sentences) + "\n")
    return out


def _targets(run: Run) -> list[str]:
    out = ["### Targets (stream mode, test split, every choice by cross-validation on the training split)\n",
           "DESK: the online choice segment accuracy ≥ 74 %, frame accuracy ≥ 64 %; the offline choice edit ≥ 90 "
           "with segment accuracy ≥ 70 %; the stream LSTM segment accuracy ≥ 65 %. Fetch: the online choice "
           "segment accuracy ≥ 85 %, frame accuracy ≥ 70 %; the offline choice edit ≥ 90. The best on test is "
           "shown beside, marked optimistic.\n"]
    checks = target_checks(run)
    out.append("\n".join(f"- {line}" for line in checks) + "\n" if checks
               else "_nothing to check: this run has no decoded stream-mode results._\n")
    return out


def live_section(run: Run) -> list[str]:
    """Issue 24: accuracy against latency, per decoder and lag, and the live choice within its budget."""
    from mlnseq.reporting.latency import FIGURE, LATENCY_HEADER, latency_rows

    rows = latency_rows(run)
    if not rows:
        return []
    figures = [f"![{d}: accuracy against latency]({FIGURE.format(dataset=d)})\n" for d in PAPER_DATASETS
               if any(row[0] == d for row in rows)]
    return ["### Live recognition: accuracy against latency\n",
            "Per decoder and lag (frame t decided once frame t + lag has arrived; Fetch runs at 25 Hz, DESK's rate is "
            "unknown), the method of the deployable folders with the best cross-validated criterion (the mean of "
            "segment accuracy, frame accuracy and edit on the training split's out-of-fold predictions; ties: the "
            "log-likelihood of the true labels), its test figures (means over seeds) and the transitions it emits "
            "on test that the chain forbids. `-legal` decoders take the argmax among the classes allowed after the "
            "one emitted last. summary.json's `live` entry is the choice within 25 frames (DESK) or 1 s (Fetch).\n",
            markdown_table(LATENCY_HEADER, rows), *figures]
