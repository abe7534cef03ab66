"""Label less, measured: `mlnseq fit` on ROS 2 bags of the generated 7-joint arm (tests/arm_bags.py), 6 recordings
to learn from and held-out recordings of later seeds no stage reads, by frame accuracy on the held-out ones:

- ``all 6``: every recording labelled (/phase): 6 labelled recordings are enough for fit to keep a test split, so 4
  of them train;
- ``all 6 train``: the same with ``--holdout none``: all 6 train, as every recording does below 5 labelled ones;
- ``L alone``: L of them labelled (1, 2, 3) and nothing else in --source;
- ``L + unlabelled``: the same L labelled and the other 6 - L in the same --source without /phase: fit labels them by
  alignment to the labelled ones (mlnseq.labelling.alignment) and learns from all 6;
- ``clicks``: all 6 with one click per phase (a frame drawn at random within each phase) instead of /phase;
- ``1 + clicks``: the first labelled on every frame (intervals) and the other 5 with the same clicks, in one file;
- ``next`` and ``any``: from 1 labelled + 5 unlabelled, the recording label_next.csv ranks first labelled as well
  (the other 4 still unlabelled in --source), against the mean of labelling each of the 5;
- ``clicks next`` and ``clicks any``: from all 6 clicked, the recording label_next.csv ranks first labelled on every
  frame (the other 5 still clicked, as ``1 + clicks``), against the mean of labelling each of the 6 so.

``BENCH_LABELS_ARMS``: robot:seed pairs (default panda:83,iiwa:89,xarm7:97: seeds never used while developing);
``BENCH_EPOCHS`` fit's epochs (100); ``BENCH_SEEDS`` the networks' seeds (``fit --seed``; default 0,1,2: each cell
the mean over them, with its range); ``BENCH_HELDOUT`` held-out bags per arm (6); ``BENCH_QUICK=1``: panda:0, 3
recordings at 15 Hz, 1 held out, 2 epochs, seed 0, the columns 1 + unlabelled and next (the clicks' columns repeat
them with clicks), only the first ranked labelled next (for tests/test_benchmarks.py).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

from benchmarks.bench_first_day import REPO, frame_accuracy, run

sys.path.insert(0, str(REPO / "tests"))


def settings() -> dict:
    quick = os.environ.get("BENCH_QUICK") == "1"
    arms = os.environ.get("BENCH_LABELS_ARMS", "panda:0" if quick else "panda:83,iiwa:89,xarm7:97")
    return {"arms": [(a.split(":")[0], int(a.split(":")[1])) for a in arms.split(",")], "quick": quick,
            "episodes": 3 if quick else 6, "heldout": 1 if quick else int(os.environ.get("BENCH_HELDOUT", "6")),
            "epochs": "2" if quick else os.environ.get("BENCH_EPOCHS", "100"), "labelled": (1,) if quick else (1, 2, 3),
            "seeds": [0] if quick else [int(s) for s in os.environ.get("BENCH_SEEDS", "0,1,2").split(",")],
            "rate": 15.0 if quick else None}


def seeded(config: dict, seed: int) -> dict:
    """``config`` whose fits seed their networks with ``seed`` (fit's --epochs and --seed, as ``fit`` takes them)."""
    return {**config, "epochs": f"{config['epochs']} --seed {seed}"}


def spread(values: list[float]) -> str:
    """The mean of ``values``, with their range where there are several."""
    low, high = min(values), max(values)
    return f"{np.mean(values):.1f}" + ("" if low == high else f" ({low:.1f}-{high:.1f})")


def bags(root: Path, robot: str, seed: int, n: int, heldout: int, rate: float | None = None) -> dict:
    """``n`` bags with /phase (``all``), the same without it (``bare``), held-out ones, and one click per phase;
    ``rate``: another frame rate than the robot's."""
    import arm_bags

    arm, rng = arm_bags.at_rate(robot, rate), np.random.default_rng(seed)  # rng: where each click falls
    names = {f"episode_{k + 1}": seed * 1000 + k for k in range(n)}
    for name, s in names.items():
        arm_bags.write_bag(root / "all" / name, arm, s)
        arm_bags.write_bag(root / "bare" / name, arm, s, phases=False)
    for k in range(heldout):
        arm_bags.write_bag(root / "heldout" / f"heldout_{k + 1}", arm, seed * 1000 + 500 + k)
    clicked, spans = {}, {}  # per recording: (frame, label) of each click; (first, last, label) of each phase
    for name, s in names.items():
        phase = arm_bags.episode_signals(arm, s)["phase"]
        frames = [np.flatnonzero(phase == index) for index in range(len(arm_bags.PHASES))]
        clicked[name] = [(f[int(rng.uniform(0.1, 0.9) * (len(f) - 1))], label) for f, label in zip(frames,
                                                                                                    arm_bags.PHASES)]
        spans[name] = [(f[0], f[-1], label) for f, label in zip(frames, arm_bags.PHASES)]
    lines = [f"{name},{frame},{label}" for name, found in clicked.items() for frame, label in found]
    (root / "clicks.csv").write_text("\n".join(["episode,frame,label", *lines]) + "\n")
    data = {"root": root, "names": list(names), "clicked": clicked, "spans": spans}
    mixed_file(data, list(names)[0], root / "mixed.csv")
    return data


def mixed_file(data: dict, labelled: str, path: Path) -> Path:
    """A labels file: ``labelled`` on every frame (intervals), the other recordings by their clicks."""
    rows = [f"{name},{first},{last},,{label}" for name in data["names"] if name == labelled
            for first, last, label in data["spans"][name]]
    rows += [f"{name},,,{frame},{label}" for name in data["names"] if name != labelled
             for frame, label in data["clicked"][name]]
    path.write_text("\n".join(["episode,start,end,frame,label", *rows]) + "\n")
    return path


def source(data: dict, labelled: list[str], others: bool, name: str) -> Path:
    """A folder of the ``labelled`` bags with /phase and, when ``others``, the rest without."""
    folder = data["root"] / name
    for episode in data["names"]:
        if episode in labelled or others:
            shutil.copytree(data["root"] / ("all" if episode in labelled else "bare") / episode, folder / episode)
    return folder


def fit(folder: Path, work: Path, epochs: str, *extra: str) -> Path:
    """``epochs``: fit's --epochs and --seed (``seeded``)."""
    run(["fit", "--env", "rosbag", "--source", str(folder), "--label-topic", "/phase", "--epochs", *epochs.split(),
         "-w", str(work), *extra])
    return work / "model.mlnseq"


def held_out(model: Path, data: dict) -> float:
    return frame_accuracy(model, ["--source", str(data["root"] / "heldout")], model.with_suffix(".parquet"))[0]


def first_against_any(work: Path, quick: bool, accuracy_of: Callable[[str], float]) -> tuple[float, float, str]:
    """(held-out accuracy labelling the recording WORK's label_next.csv ranks first, the mean over labelling each it
    ranks, the first's reason); ``accuracy_of``: the accuracy with a recording, by name, labelled."""
    import polars as pl

    from mlnseq.catalog import artifacts

    ranked = pl.read_csv(work / artifacts.LABEL_NEXT)
    candidates = ranked["episode"].to_list()[:1 if quick else None]
    accuracy = {candidate: accuracy_of(candidate) for candidate in candidates}
    return accuracy[candidates[0]], float(np.mean(list(accuracy.values()))), ranked["reason"][0]


def beside_unlabelled(data: dict, epochs: str, candidate: str) -> float:
    """The first recording and ``candidate`` labelled, the others without labels in --source."""
    folder = source(data, [data["names"][0], candidate], True, f"next-{candidate}")
    return held_out(fit(folder, data["root"] / f"w-next-{candidate}", epochs), data)


def beside_clicked(data: dict, epochs: str, candidate: str) -> float:
    """``candidate`` labelled on every frame, the others clicked, as ``1 + clicks``."""
    labels = mixed_file(data, candidate, data["root"] / f"mixed-{candidate}.csv")
    return held_out(fit(data["root"] / "bare", data["root"] / f"w-clicks-next-{candidate}", epochs, "--labels",
                        str(labels), "--labels-unit", "frames"), data)


def measure(robot: str, seed: int, config: dict, root: Path) -> dict:
    data = bags(root, robot, seed, config["episodes"], config["heldout"], config["rate"])
    epochs, row = config["epochs"], {}
    quick = config["quick"]  # the columns the others repeat with other inputs are left out
    if not quick:
        everything = source(data, data["names"], False, "src-all")
        row["all"] = held_out(fit(everything, root / "w-all", epochs), data)
        row["all train"] = held_out(fit(everything, root / "w-all-train", epochs, "--holdout", "none"), data)
    for count in config["labelled"]:
        for others, column, name in ((False, "alone", "alone"), (True, "+ unlabelled", "with-unlabelled")):
            if others or not quick:
                folder = source(data, data["names"][:count], others, f"src-{count}-{name}")
                row[f"{count} {column}"] = held_out(fit(folder, root / f"w-{count}-{name}", epochs), data)
    if not quick:
        clicks = fit(data["root"] / "bare", root / "w-clicks", epochs, "--labels", str(data["root"] / "clicks.csv"))
        row["clicks"] = held_out(clicks, data)
        mixed = fit(data["root"] / "bare", root / "w-1-clicks", epochs, "--labels", str(data["root"] / "mixed.csv"),
                    "--labels-unit", "frames")
        row["1 + clicks"] = held_out(mixed, data)
    unlabelled, clicked = partial(beside_unlabelled, data, epochs), partial(beside_clicked, data, epochs)
    row["next"], row["any"], row["next reason"] = first_against_any(root / "w-1-with-unlabelled", quick, unlabelled)
    if not quick:
        row["clicks next"], row["clicks any"], _ = first_against_any(root / "w-clicks", quick, clicked)
    return row


def main() -> None:
    config = settings()
    runs: dict[str, list[dict]] = {}  # per arm, a row per network seed
    with tempfile.TemporaryDirectory(prefix="bench-labels-") as tmp:
        for robot, seed in config["arms"]:
            for network_seed in config["seeds"]:
                row = measure(robot, seed, seeded(config, network_seed), Path(tmp) / f"{robot}-{seed}-{network_seed}")
                runs.setdefault(f"{robot}:{seed}", []).append(row)
                print(f"{robot}:{seed}, networks' seed {network_seed}: {row}", flush=True)
    columns = [c for c in ["all", "all train", *[f"{k} {w}" for k in config["labelled"] for w in ("alone",
               "+ unlabelled")], "clicks", "1 + clicks", "next", "any", "clicks next", "clicks any"]
               if all(c in row for rows in runs.values() for row in rows)]
    rows = {name: {c: float(np.mean([r[c] for r in seeds])) for c in columns} for name, seeds in runs.items()}
    print(f"\nlabels: frame accuracy (%) on {config['heldout']} held-out recordings per arm, fit --epochs "
          f"{config['epochs']}, {config['episodes']} recordings to learn from; each the mean over the networks' seeds "
          f"{', '.join(map(str, config['seeds']))} (lowest-highest)")
    print("| arm | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    for name, seeds in runs.items():
        print(f"| {name} | " + " | ".join(spread([r[c] for r in seeds]) for c in columns) + " |")
    means = {c: float(np.mean([row[c] for row in rows.values()])) for c in columns}
    print("| mean | " + " | ".join(f"{means[c]:.1f}" for c in columns) + " |")
    said = []
    for first, mean, what in (("next", "any", "label_next's first"), ("clicks next", "clicks any", "all clicked, "
                                                                      "label_next's first labelled on every frame")):
        if first not in columns:
            continue
        gains = [row[first] - row[mean] for row in rows.values()]
        said.append(f"{what} against the mean of any: {np.mean(gains):+.1f} points (per arm "
                    f"{', '.join(f'{g:+.1f}' for g in gains)})")
    print(f"labels: {len(rows)} arm(s) measured; {'; '.join(said)}")
