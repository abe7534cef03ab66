"""Fit at a lab's scale: `mlnseq fit` on 50, 200 and 800 generated episodes of the 7-joint arm (tests/arm_bags.py:
xarm7, 60 Hz, 22 channels, about 630 frames an episode; one Parquet table, `--env table`; fit's own split: 30 % of
the episodes held out as its test split) and on the real DESK trials as bags (tests/desk_bags.py, trial 7 held
out), each fit in a process of its own: wall time, CPU time (the fit's and its jobs'), the peak resident memory of
its largest process, the CPU time of training (train: the network and its fold networks) against the rest, and the
held-out frame accuracy of the model fit chose, with the choice.

``BENCH_SCALE_BASELINE=PYTHON`` measures the same fits with another installation of mlnseq beside (its Python, e.g.
an older checkout's venv), each size first with it, then with this one; a baseline fit over
``BENCH_SCALE_BASELINE_MINUTES`` of CPU at an earlier size is not run at the larger ones (said as skipped).

``BENCH_SCALE_EPISODES`` the sizes (default 50,200,800; ``desk`` among them for the DESK bags, run by default
last), ``BENCH_SCALE_EPOCHS`` fit's epochs (default fit's), ``BENCH_SCALE_EXECUTOR`` fit's --executor (default
local), ``BENCH_SCALE_KEEP=DIR`` keeps the workdirs there, ``BENCH_QUICK=1``: 8 episodes at 15 Hz, 2 epochs.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))  # the arm's and DESK's recordings as the tests write them
DESK = REPO.parent / "shared" / "data" / "desk-taurus" / "taurus_kinematics_train.txt"

# Run in the fit's own process (any installation's Python): fit through mlnseq.fit, each stage's end heard, then
# one JSON line of CPU seconds per stage (its jobs' included), wall seconds and the peak memory of any process.
MEASURED = r'''
import json, resource, sys, time
from contextlib import contextmanager
from pathlib import Path
import mlnseq
from mlnseq.collect import CollectOptions, SourceOptions
from mlnseq.pipeline import fit as pipeline

def cpu():
    own, jobs = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + jobs.ru_utime + jobs.ru_stime

def own_cpu():  # training runs in fit's own process (the logic may run beside it in another)
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime

marks = [("start", cpu(), time.perf_counter(), own_cpu())]

class Timed(pipeline.Observer):
    def __getattribute__(self, name):
        if name in ("collected", "binarized", "weights_learned", "trained", "conflated"):
            return lambda step: marks.append((name, cpu(), time.perf_counter(), own_cpu()))
        return object.__getattribute__(self, name)

    @contextmanager
    def training(self, epochs, folds):
        marks.append(("training", cpu(), time.perf_counter(), own_cpu()))
        yield lambda done: None
        marks.append(("training ended", cpu(), time.perf_counter(), own_cpu()))

flags, workdir, own = json.loads(sys.argv[1]), sys.argv[2], json.loads(sys.argv[3])
source = CollectOptions(env=flags["env"], source=Path(flags["source"]), recordings=SourceOptions(**flags["recordings"]))
fitted = pipeline.fit(source, workdir, pipeline.FitOptions(**own), Timed())
marks.append(("end", cpu(), time.perf_counter(), own_cpu()))
peak = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)
test = {name: figures.frame_accuracy for name, figures in fitted.test.items()}
print(json.dumps({"marks": marks, "peak_mb": peak / 1024, "method": fitted.method, "test": test}))
'''


def fit(python: str, source: dict, workdir: Path, epochs: int | None, executor: str, own_path: bool) -> dict:
    """One fit in a process of its own: its stages' CPU marks, wall, peak memory, choice and test figures; not
    ``own_path``: without this process's PYTHONPATH (another installation runs its own code)."""
    own = {"force": True, **({"epochs": epochs} if epochs else {}), **({"executor": executor} if executor != "local"
                                                                     else {})}
    started = time.perf_counter()
    env = {k: v for k, v in os.environ.items() if own_path or k != "PYTHONPATH"}
    done = subprocess.run([python, "-c", MEASURED, json.dumps(source), str(workdir), json.dumps(own)],
                          capture_output=True, text=True, cwd=workdir.parent, env=env)
    if done.returncode:
        raise RuntimeError(f"fit of {workdir.name} failed:\n{done.stderr[-3000:]}")
    measured = json.loads(done.stdout.strip().splitlines()[-1])
    marks = {name: (cpu, wall, own) for name, cpu, wall, own in measured["marks"]}
    training = (marks["training ended"][2] - marks["training"][2]) if "training" in marks else None
    return {**measured, "wall": time.perf_counter() - started, "cpu": marks["end"][0] - marks["start"][0],
            "training": training}


def held_out(python: str, workdir: Path, reading: list[str] | None, result: dict, own_path: bool) -> float:
    """The frame accuracy (%) of the model fit chose: on fit's test split, or on the recordings ``reading`` names."""
    if reading is None:
        return 100 * result["test"][result["method"]]
    import polars as pl

    out = workdir / "heldout.parquet"
    script = Path(python).with_name("mlnseq")
    env = {k: v for k, v in os.environ.items() if own_path or k != "PYTHONPATH"}
    subprocess.run([str(script), "predict", str(workdir / "model.mlnseq"), *reading, "-o", str(out), "--force"],
                   check=True, capture_output=True, env=env)
    table = pl.read_parquet(out)
    classes = [c.removeprefix("p_") for c in table.columns if c.startswith("p_")]
    labels = table["label"]
    truth = labels.to_numpy() if labels.dtype == pl.String else [classes[k] for k in labels.to_numpy()]
    return 100 * float((table["class"].to_numpy() == truth).mean())


def datasets(root: Path, sizes: list[str], quick: bool) -> list[tuple[str, dict, list[str] | None]]:
    """(name, collect's env, source and recording options, predict's arguments for held-out recordings or None) per
    size."""
    import numpy as np

    import arm_bags
    import desk_bags

    made = []
    for size in sizes:
        if size == "desk":
            folder, heldout = desk_bags.write_folders(np.loadtxt(DESK), root / "desk", root / "desk-heldout")
            made.append(("DESK bags (6 trials)", {"env": "rosbag", "source": str(folder),
                                                  "recordings": {"label_topic": "/phase"}},
                         ["--source", str(heldout / "trial_7")]))
        else:
            table = arm_bags.write_table(root / f"arm-{size}.parquet", seed=3, episodes=int(size),
                                         rate=15.0 if quick else None)
            made.append((f"{size} episodes", {"env": "table", "source": str(table), "recordings": {}}, None))
    return made


def cell(result: dict | None, what: str) -> str:
    if result is None:
        return "–"
    if what == "time":
        share = "" if result["training"] is None else f" (train {result['training']:.0f} s)"
        return f"{result['wall']:.0f} s wall, {result['cpu']:.0f} s CPU{share}, {result['peak_mb']:,.0f} MB"
    return f"{result['held_out']:.1f} ({result['method']})"


def main() -> None:
    quick = os.environ.get("BENCH_QUICK") == "1"
    sizes = ["8"] if quick else os.environ.get("BENCH_SCALE_EPISODES", "50,200,800,desk").split(",")
    epochs = 2 if quick else int(os.environ["BENCH_SCALE_EPOCHS"]) if os.environ.get("BENCH_SCALE_EPOCHS") else None
    executor = os.environ.get("BENCH_SCALE_EXECUTOR", "local")
    baseline = os.environ.get("BENCH_SCALE_BASELINE")
    limit = 60 * float(os.environ.get("BENCH_SCALE_BASELINE_MINUTES", "20"))
    pythons = ([("baseline", baseline)] if baseline else []) + [("this", sys.executable)]
    print(f"scale: `mlnseq fit` ({epochs or 'default'} epochs, --executor {executor}); held-out frame accuracy (%) "
          "of the model chosen")
    rows, skipped = [], set()
    keep = os.environ.get("BENCH_SCALE_KEEP")
    with tempfile.TemporaryDirectory() as temporary:
        folder = keep or temporary
        Path(folder).mkdir(parents=True, exist_ok=True)
        for name, args, reading in datasets(Path(folder), sizes, quick):
            results = {}
            for side, python in pythons:
                if side in skipped:
                    results[side] = None
                    continue
                workdir = Path(folder) / f"{side}-{len(rows)}"
                own = side == "this"
                results[side] = fit(python, args, workdir, epochs, executor if own else "local", own)
                results[side]["held_out"] = held_out(python, workdir, reading, results[side], own)
                if side == "baseline" and results[side]["cpu"] > limit:
                    skipped.add(side)  # the larger sizes would take longer still
                print(f"  {name}, {side}: {cell(results[side], 'time')}; {cell(results[side], 'accuracy')}",
                      flush=True)
            rows.append((name, results))
    sides = [side for side, _ in pythons]
    print("| data | " + " | ".join(f"{s}: time, memory | {s}: held-out" for s in sides) + " |")
    print("|---" * (1 + 2 * len(sides)) + "|")
    for name, results in rows:
        print(f"| {name} | " + " | ".join(f"{cell(results.get(s), 'time')} | {cell(results.get(s), 'accuracy')}"
                                        for s in sides) + " |")
    print(f"scale: {len(rows)} size(s) measured" + (f"; baseline skipped past {limit / 60:g} CPU minutes"
                                                     if skipped else ""))


if __name__ == "__main__":
    main()
