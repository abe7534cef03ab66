"""REPORT.md: every section in Markdown, its numbers from the tables and claims."""

from __future__ import annotations

import numpy as np

from stages.report.claims import claims, efficiency_claim, rich_spec_claim
from stages.report.loading import PAPER_DATASETS, RICH, Run, present
from stages.report.tables import (
    datasets_table, efficiency_points, efficiency_table, per_class_table, rich_spec_table, stream_table,
    table_iii, timings_table, wall_seconds, weights_table,
)


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    if not rows:
        return "_nothing to show: this run has no such results._\n"
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell).replace("|", "\\|") for cell in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def render(run: Run, figures: dict[str, str]) -> str:
    """REPORT.md: every section, its numbers from ``run``; ``figures`` maps a figure key to its file name."""
    points = efficiency_points(run)
    datasets = present(run, PAPER_DATASETS)
    missing = [d for d in PAPER_DATASETS if d not in datasets]
    wall = wall_seconds(run.timings)
    out = ["# mlnseq: reproduction of Rahman et al., RO-MAN 2021\n",
           "Every number below is read from the artifacts of this run "
           f"({', '.join(sorted(run.datasets))}); nothing is copied from the paper except its own columns.\n"]
    if missing:
        out.append(f"**Not run:** {', '.join(missing)} (its data was not found when `make reproduce` ran).\n")

    out.append("## Table III: segment accuracy, paper vs mlnseq\n")
    out.append("Segment recognised at half of its frames (the paper's metric), `segment` mode, **last epoch, "
               "mean ± std over seeds** (%). The last column is the best test epoch's frame accuracy per seed, "
               "**optimistic**: it selects on the test split, as the published numbers do.\n")
    out.append(markdown_table(["dataset", "method", "paper", "mlnseq (last epoch)", "seeds",
                               "frame accuracy (last epoch)", "best test epoch, as in the paper (optimistic)"],
                              table_iii(run)))
    out.append("### Do the paper's claims hold here?\n")
    out.append("\n".join(f"- {line}" for line in claims(run)) + "\n")

    out.append("## Table IV: per-class segment accuracy\n")
    for dataset in datasets:
        out.append(f"**{dataset}** (%, mean ± std over seeds)\n")
        out.append(markdown_table(["class", "LSTM", "MLN", "combined"], per_class_table(run, dataset)))

    out.append("## Fig. 7: test accuracy per epoch\n")
    out.append(f"![Fig. 7]({figures['fig7']})\n")
    out.append("Drawn: the LSTM's and PriorLayer's test **frame** accuracy after every epoch (mean, band ± std over "
               "seeds), from the training logs. The MLN has no epochs (flat line). Conflation and the combined "
               "model are computed from the final networks only, so they appear as one point at the last epoch; "
               "their per-epoch curves would need every epoch's network, which is not kept.\n")
    out.append("## Fig. 8: train vs test accuracy per epoch\n")
    out.append(f"![Fig. 8]({figures['fig8']})\n")
    out.append("PriorLayer's regularisation claim, checked on these curves, is listed under Table III.\n")

    out.append("## Confusion matrices (LSTM and combined)\n")
    for dataset in datasets:
        out.append(f"![confusion {dataset}]({figures['confusion'].format(dataset=dataset)})\n")
    out.append("Segments of the test split, counts summed over seeds, each row normalised to its true class.\n")

    out.append("## Data efficiency: where do the logic constraints stop helping?\n")
    out.append(f"![data efficiency]({figures['efficiency']})\n")
    out.append("The same Fetch episodes (collection seed fixed); the first share of them trains, the MLN learns its "
               "weights on that part only, the rest is the test split"
               + (f"; the smallest point is the paper's split ({run.datasets['fetch']['n_train']:,} frames, "
                  "folder `fetch`)" if "fetch" in run.datasets else "")
               + ". Segment accuracy (%), mean ± std over training seeds.\n")
    out.append(markdown_table(["training share", "training frames", "LSTM", "MLN", "combined", "combined − LSTM"],
                              efficiency_table(points)))
    out.append(efficiency_claim(points) + "\n")

    out.append("## Learned weights: strongest formulas per class (Table II style)\n")
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

    out.append("## Stream mode: no segment boundaries at test\n")
    out.append("Networks trained on fixed windows and run over whole episodes (`--mode stream`); segment "
               "accuracy (%), frame accuracy (%), segmental edit score and F1@{10,25,50} (Lea et al.), mean ± std.\n")
    out.append(markdown_table(["dataset", "method", "segment acc.", "frame acc.", "edit", "F1@10", "F1@25", "F1@50"],
                              stream_table(run)))

    out.append("## Timings and machine\n")
    total = f"{wall:.0f} s from the first stage's start to the last stage's end" if wall is not None else "not recorded"
    out.append(f"Stage time (seconds, the latest run of each command; two jobs at a time): {total}.\n")
    out.append(markdown_table(["stage", "runs", "total s", "mean s", "longest s"], timings_table(run.timings)))
    out.append(markdown_table(["", ""], [[k, v] for k, v in run.machine.items()]))

    out.append("## Hyper-parameters used\n")
    out.append("Read from the artifacts' metadata: each dataset folder, then every stage's options (several values "
               "where runs differ).\n")
    out.append(markdown_table(["dataset folder", "source", "frames", "training frames", "features", "predicate spec",
                               "epochs"],
                              datasets_table(run)))
    out.append(markdown_table(["stage", "option", "values"],
                              [[stage, name, ", ".join(map(str, values))]
                               for stage, options in run.settings.items() for name, values in options.items()]
                              + [["train", "seeds", ", ".join(map(str, sorted(run.metrics["seed"].unique())))]]))

    out.append("## Differences from the paper\n")
    out.append("\n".join(f"- {line}" for line in differences(run)) + "\n")
    return "\n".join(out)


def differences(run: Run) -> list[str]:
    lines = [
        "Fetch data come from our own scripted controller on Gymnasium-Robotics v4 (FetchPickAndPlace-v4, "
        "MuJoCo), not from the authors' Gym v1 demonstrations, whose test kinematics were not released; the "
        "split is the paper's (first 126 frames train).",
        "DESK test frames carry only the arm distance and the two gripper openings, so on DESK the recurrent "
        "models see those three channels, not the 14 kinematics of the training file.",
        "Headline numbers are the last epoch's, mean ± std over training seeds; no epoch is chosen on the test "
        "split. The published Table III numbers match single best epochs of the authors' test curves (there "
        "was no validation split); the optimistic column above shows what that selection does here.",
        "The figures' per-epoch curves are frame accuracy; Table III is segment accuracy at half a segment.",
    ]
    fetch = run.datasets.get("fetch")
    if fetch is not None:
        lines.append(f"Fetch: {fetch['n_frames']:,} frames ({fetch['n_train']:,} train) from "
                     f"{fetch.get('env_id', 'the simulator')}; episodes that succeeded: "
                     f"{np.mean(fetch.get('episode_success', [np.nan])):.1%}.")
    return lines

