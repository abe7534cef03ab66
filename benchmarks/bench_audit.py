"""`mlnseq audit` measured: which recordings went wrong, found among clean ones, against the signals a user has today,
side by side on the same recordings: the episode's length (its distance from the labelled recordings' median, and
"overly short"), the model's mean confidence (1 - its mean top probability, as predict decodes), and the phase-order
rule (predict's phases, runs of one class of at least 0.5 s, differ from the labelled orders): AUROC, the share of
failed recordings among the top k (k = the number failed), clean and slow or hesitant ones suspect, each failed
one's first reason in the phase where it went wrong, and `stream --monitor` alerting before the end, and on clean.

- ``arm-*``: `mlnseq fit --holdout none --seed S` on 6 clean labelled bags of the generated arm (tests/arm_bags.py),
  audited on 30 clean recordings of later seeds, 6 of each failed kind of tests/arm_failures.py and 10 slow and 10
  hesitant clean ones, as one table. Developed on ``dev`` (drop, miss, pause); rounds one (seeds 101, 103, 107;
  regrasp, abort, open, repeat, reach) and two (109, 113, 127; slip, bump, early) held out once, seen since; round
  three (131, 137, 139; hold, fumble, drag) held out until its figures (docs/benchmarks.md).
- ``desk``: each DESK trial (tests/desk_bags.py) held out from a fit on the 6 others; it, cut short, with a stretch
  removed and with a stretch played twice, audited. ``speed``: 1,000 recordings of 600 frames, audit beside predict.

``BENCH_AUDIT`` names the rows (dev, panda, iiwa, xarm7, panda-2, iiwa-2, xarm7-2, panda-3, iiwa-3, xarm7-3, desk,
speed; default all); ``BENCH_SEEDS`` the networks' seeds (0,1,2); ``BENCH_EPOCHS`` fit's epochs (100);
``BENCH_QUICK=1``: the dev row, 4 bags at 15 Hz, 3 epochs, seed 0, fewer recordings, a 12-recording speed row.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))  # the recordings' generators: one definition of them
SHARED = REPO.parent / "shared" / "data"
DEV_KINDS = ("drop", "miss", "pause")
FIRST_KINDS = ("regrasp", "abort", "open", "repeat", "reach")  # held out in the first round, seen since
SECOND_KINDS = ("slip", "bump", "early")  # held out in the second round, seen since
THIRD_KINDS = ("hold", "fumble", "drag")  # held out in the third round
KINDS = DEV_KINDS + FIRST_KINDS + SECOND_KINDS + THIRD_KINDS
ARMS = {  # row: robot, seed, the kinds it was held out with (the first two rounds' arms: seen since, as their kinds)
    "dev": ("panda", 0, DEV_KINDS), "panda": ("panda", 101, FIRST_KINDS), "iiwa": ("iiwa", 103, FIRST_KINDS),
    "xarm7": ("xarm7", 107, FIRST_KINDS), "panda-2": ("panda", 109, SECOND_KINDS),
    "iiwa-2": ("iiwa", 113, SECOND_KINDS), "xarm7-2": ("xarm7", 127, SECOND_KINDS),
    "panda-3": ("panda", 131, THIRD_KINDS), "iiwa-3": ("iiwa", 137, THIRD_KINDS),
    "xarm7-3": ("xarm7", 139, THIRD_KINDS)}
ROUNDS = {"second": ("panda-2", "iiwa-2", "xarm7-2"), "third": ("panda-3", "iiwa-3", "xarm7-3")}
METHODS = ("audit", "length", "short", "confidence", "order")
ORDER_RUN_S = 0.5  # the phase-order rule leaves out runs shorter than this (the decoder's flicker)
TARGETS = {"auroc": 0.97, "top_k": 0.90, "clean": 1 / 30}


def quick() -> bool:
    return os.environ.get("BENCH_QUICK") == "1"


def arm_rate() -> float | None:
    """The arm recordings' frame rate: 15 Hz in the quick run (fewer frames to fit and audit), else the robot's."""
    return 15.0 if quick() else None


def mlnseq(*args: object) -> subprocess.CompletedProcess:
    script = Path(sys.executable).parent / "mlnseq"
    command = [str(script)] if script.exists() else [sys.executable, "-m", "mlnseq_cli.main"]
    done = subprocess.run(command + [str(a) for a in args], capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"mlnseq {' '.join(map(str, args))} failed:\n{done.stderr[-3000:]}")
    return done


def seeds() -> list[int]:
    return [0] if quick() else [int(s) for s in os.environ.get("BENCH_SEEDS", "0,1,2").split(",")]


def fit(source: list[str], workdir: Path, seed: int = 0) -> Path:
    """`mlnseq fit` on every labelled recording (none held out for a test: the audit learns from them all)."""
    epochs = "3" if quick() else os.environ.get("BENCH_EPOCHS", "100")
    mlnseq("fit", *source, "--holdout", "none", "--epochs", epochs, "--seed", seed, "-w", workdir)
    return workdir / "model.mlnseq"


@dataclass
class Recordings:
    """What a row audits: a table (or a folder of bags), the read options, each recording's kind and the phase it
    went wrong in (None: clean), and the labelled recordings' median length."""

    reading: list[str]
    kinds: dict[str, str]
    wrong: dict[str, str | None]
    median: float


def arm_recordings(root: Path, robot: str, seed: int) -> tuple[list[str], Recordings]:
    """The arm's labelled bags (fit's source) and the recordings to audit."""
    import numpy as np

    import arm_bags
    import arm_failures

    rate = arm_rate()
    bags, _ = arm_bags.write_folders(root / "bags", robot, seed, 4 if quick() else 6, 0, rate)
    clean, failed, odd = (4, 2, 2) if quick() else (30, 6, 10)
    seeds_ = [seed * 1000 + 500 + k for k in range(clean)]
    made = (arm_failures.failures(robot, ("clean",), seeds_, rate)
            + arm_failures.failures(robot, KINDS, seeds_[:failed], rate)
            + arm_failures.failures(robot, ("slow", "hesitant"), seeds_[:odd], rate))
    names = [f"{r.kind}_{r.seed}" for r in made]
    arm_failures.table(made, robot, names).write_parquet(root / "recordings.parquet")
    lengths = [len(arm_bags.episode_signals(arm_bags.at_rate(robot, rate), seed * 1000 + k)["phase"]) for k in range(6)]
    source = ["--env", "rosbag", "--source", str(bags), "--label-topic", "/phase"]
    return source, Recordings(["--env", "table", "--source", str(root / "recordings.parquet"), "--episode-column",
                               "episode", "--time-column", "time"], dict(zip(names, (r.kind for r in made))),
                              dict(zip(names, (r.wrong for r in made))), float(np.median(lengths)))


def auroc(positive: list[float], negative: list[float]) -> float:
    import numpy as np

    p, n = np.asarray(positive, dtype=float)[:, None], np.asarray(negative, dtype=float)[None]
    return float((p > n).mean() + 0.5 * (p == n).mean())


def top_k(scores: dict[str, float], failed: set[str]) -> float:
    """The expected share of failed recordings among the k highest scores (ties broken at random)."""
    k = len(failed)
    ranked = sorted(scores.values(), reverse=True)
    if not k:
        return float("nan")
    edge = ranked[k - 1]
    above = [n for n, s in scores.items() if s > edge]
    tied = [n for n, s in scores.items() if s == edge]
    slots = k - len(above)
    return (sum(n in failed for n in above) + slots * sum(n in failed for n in tied) / len(tied)) / k


def signals(model: Path, data: Recordings, root: Path) -> tuple[dict[str, dict[str, float]], dict]:
    """Each method's score per recording, and audit's table rows by episode."""
    import numpy as np
    import polars as pl

    mlnseq("audit", model, *data.reading, "-o", root / "audit.csv", "--force")
    audit = {row["episode"]: row for row in pl.read_csv(root / "audit.csv").iter_rows(named=True)}
    mlnseq("predict", model, *data.reading, "-o", root / "predictions.parquet", "--force")
    predicted = pl.read_parquet(root / "predictions.parquet")
    probabilities = [c for c in predicted.columns if c.startswith("p_")]
    orders, rate = labelled_orders(model)
    scores = {m: {} for m in METHODS}
    for (name,), part in predicted.group_by("episode", maintain_order=True):
        name = str(name)
        runs = phases(part["class"].to_list(), int(ORDER_RUN_S * rate))
        scores["audit"][name] = audit[name]["score"]
        scores["length"][name] = abs(part.height - data.median)
        scores["short"][name] = -part.height
        scores["confidence"][name] = 1 - float(np.mean(part.select(probabilities).to_numpy().max(axis=1)))
        scores["order"][name] = float(runs not in orders)
    return scores, audit


def profile_of(model: Path):
    """The model file's audit profile."""
    from mlnseq.auditing.profile import Profile
    from mlnseq.model import model_file

    return Profile.read(model_file.read_model(model)["audit.json"], model)


def labelled_orders(model: Path) -> tuple[set[tuple[str, ...]], float]:
    """The labelled recordings' orders of phases, as the model's audit profile holds them, and their rate."""
    profile = profile_of(model)
    return {tuple(profile.classes[k] for k in order) for order in profile.orders}, profile.rate


def phases(classes: list[str], shortest: int) -> tuple[str, ...]:
    """The phase-order rule's phases: runs of one class, those shorter than ``shortest`` frames left out."""
    runs: list[list] = []
    for name in classes:
        if runs and runs[-1][0] == name:
            runs[-1][1] += 1
        else:
            runs.append([name, 1])
    kept = [name for name, frames in runs if frames >= shortest]
    return tuple(name for k, name in enumerate(kept) if k == 0 or name != kept[k - 1])


def figures(data: Recordings, scores: dict, audit: dict, alerts: dict, kinds: tuple[str, ...]) -> dict:
    """The row's figures over the clean recordings and the failed ones of ``kinds``."""
    clean = [n for n, kind in data.kinds.items() if kind == "clean"]
    failed = [n for n, kind in data.kinds.items() if kind in kinds]
    odd = [n for n, kind in data.kinds.items() if kind in ("slow", "hesitant")]
    out = {"failed": len(failed), "clean": len(clean)}
    for method in METHODS:
        values = scores[method]
        out[method] = {"auroc": auroc([values[n] for n in failed], [values[n] for n in clean]),
                       "top_k": top_k({n: values[n] for n in failed + clean}, set(failed))}
    suspect = {n for n, row in audit.items() if row["verdict"] == "suspect"}
    flagged = {n for n, v in scores["order"].items() if v}
    out["audit"] |= {"clean_flagged": sum(n in suspect for n in clean), "odd_flagged": sum(n in suspect for n in odd),
                     "odd": len(odd), "phase": sum(audit[n]["phase"] == data.wrong[n] for n in failed),
                     "alerted": sum(alerts[n] is True for n in failed), "clean_alerts": sum(alerts[n] is not None
                                                                                               for n in clean)}
    out["order"] |= {"clean_flagged": sum(n in flagged for n in clean), "odd_flagged": sum(n in flagged for n in odd)}
    return out


def arm_rows(name: str, root: Path) -> list[dict]:
    """One row per network seed: the arm fitted with it, its recordings audited (`stream --monitor` too)."""
    import polars as pl

    robot, seed, kinds = ARMS[name]
    source, data = arm_recordings(root, robot, seed)
    rows = []
    for fit_seed in seeds():
        model = fit(source, root / f"work-{fit_seed}", fit_seed)
        scores, audit = signals(model, data, root)
        alerts = alerted(model, pl.read_parquet(root / "recordings.parquet").write_ndjson(), data)
        rows.append({"row": f"arm-{name}" if name != "dev" else "arm-panda-dev", "name": name, "robot": robot,
                     "seed": seed, "fit_seed": fit_seed, "kinds": figures(data, scores, audit, alerts, kinds),
                     "all": figures(data, scores, audit, alerts, KINDS), "model": str(model),
                     "trust": trust(model)})
    return rows


def trust(model: Path) -> dict:
    """The audit's decoding's frame accuracy out of fold, and how many training recordings its allowances flag."""
    calibration = profile_of(model).calibration
    return {"accuracy": calibration.accuracy, "flagged": calibration.flagged, "recordings": calibration.recordings}


def desk_rows(root: Path) -> list[dict]:
    """Each DESK trial held out from a fit on the other six; it and its cut and spliced copies audited; a row per
    network seed."""
    import numpy as np

    import desk_bags

    trials = desk_bags.trials(np.loadtxt(SHARED / "desk-taurus" / "taurus_kinematics_train.txt"))
    trials = [*trials[:6], np.concatenate(trials[6:])]
    rng = np.random.default_rng(0)
    folds, kinds = range(1 if quick() else len(trials)), {}
    for held in folds:
        for k, trial in enumerate(t for j, t in enumerate(trials) if j != held):
            desk_bags.write_bag(root / f"fold-{held}" / "bags" / f"trial_{k}", trial)
        for kind, cut in desk_cuts(trials[held], rng).items():
            desk_bags.write_bag(root / f"fold-{held}" / "new" / f"{kind}_{held}", cut)
            kinds[f"{kind}_{held}"] = kind
    rows = []
    for fit_seed in seeds():
        merged, audits, alerts, accuracy = {m: {} for m in METHODS}, {}, {}, []
        for held in folds:
            fold = root / f"fold-{held}"
            model = fit(["--env", "rosbag", "--source", str(fold / "bags"), "--label-topic", "/phase"],
                        fold / f"work-{fit_seed}", fit_seed)
            lengths = [len(t) for j, t in enumerate(trials) if j != held]
            data = Recordings(["--source", str(fold / "new")],
                              {n: k for n, k in kinds.items() if n.endswith(f"_{held}")}, {}, float(np.median(lengths)))
            scores, audit = signals(model, data, fold)
            for method in METHODS:
                merged[method] |= scores[method]
            audits |= audit
            alerts |= live_bags(model, fold / "new", data)
            accuracy.append(trust(model)["accuracy"])
        result = figures(Recordings([], kinds, {}, 0.0), merged, audits, alerts, ("cut", "removed", "twice"))
        result["audit"].pop("phase")
        rows.append({"row": "desk", "name": "desk", "fit_seed": fit_seed, "kinds": result,
                     "trust": {"accuracy": float(np.mean(accuracy)), "folds": accuracy}})
    return rows


def desk_cuts(trial, rng) -> dict:
    """A trial as it is, cut short at 40 to 70 %, with a middle stretch (a fifth) removed, and played twice."""
    import numpy as np

    n = len(trial)
    end = int(n * rng.uniform(0.4, 0.7))
    start = int(n * rng.uniform(0.3, 0.5))
    width = n // 5
    return {"clean": trial, "cut": trial[:end], "removed": np.concatenate([trial[:start], trial[start + width:]]),
            "twice": np.concatenate([trial[:start + width], trial[start:]])}


def live_bags(model: Path, folder: Path, data: Recordings) -> dict:
    """`stream --monitor` fed each bag's frames as JSON lines (the frames predict reads from it)."""
    import polars as pl

    frames = pl.concat([bag_frames(model, folder / name).with_columns(pl.lit(name).alias("episode"))
                        for name in data.kinds])
    return alerted(model, frames.write_ndjson(), data)


def bag_frames(model: Path, bag: Path):
    """A bag's frames by the model's feature names, read as predict reads them."""
    from mlnseq.recognition import reading

    read = reading.read(model, bag, reading.ReadOptions())
    return read.frames.select(read.model.features)


def alerted(model: Path, lines: str, data: Recordings) -> dict[str, bool | None]:
    """Per recording of ``lines`` (JSON frames) through `stream --monitor`: True where it alerted before its last
    frame line, False where only at its end, None where never."""
    done = subprocess.run([str(Path(sys.executable).parent / "mlnseq"), "stream", str(model), "--monitor"],
                          input=lines, capture_output=True, text=True, check=True)
    out = [json.loads(line) for line in done.stdout.splitlines()]
    last = {str(line["episode"]): k for k, line in enumerate(out) if "alert" not in line}
    found: dict[str, bool | None] = dict.fromkeys(data.kinds)
    for k, line in enumerate(out):
        name = str(line["episode"])
        if "alert" in line and found[name] is None:
            found[name] = k < last[name]
    return found


def speed_row(root: Path, model: Path) -> dict:
    """1,000 recordings of 600 frames: audit beside predict, wall and CPU seconds (children's rusage)."""
    import numpy as np

    import arm_failures

    count = 12 if quick() else 1000
    kinds = ("clean", *KINDS)
    seeds = list(range(900_000, 900_000 + count // len(kinds) + 1))
    made = arm_failures.failures("panda", kinds, seeds, arm_rate())[:count]  # at the dev row's model's rate
    for recording in made:  # each 600 frames: cut, or its last frame held
        for key, values in recording.signals.items():
            extra = max(600 - len(values), 0)
            recording.signals[key] = np.concatenate([values[:600], values[-1:].repeat(extra, axis=0)])
    names = [f"r{k}" for k in range(len(made))]
    arm_failures.table(made, "panda", names).write_parquet(root / "speed.parquet")
    reading = ["--env", "table", "--source", root / "speed.parquet", "--episode-column", "episode", "--time-column",
               "time"]
    out = {"recordings": len(made), "frames": 600 * len(made)}
    for name, args in (("predict", ["-o", root / "speed.predictions.parquet"]), ("audit", ["-o", root / "speed.csv"])):
        wall, cpu = timed([name, model, *reading, *args, "--force"])
        out[name] = {"wall_s": wall, "cpu_s": cpu}
    return out


def timed(args: list) -> tuple[float, float]:
    before, started = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    mlnseq(*args)
    wall, after = time.perf_counter() - started, resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def printed(row: dict) -> None:
    trusted = row.get("trust", {}).get("accuracy")
    said = "" if trusted is None else f"; its decoding {trusted:.1%} right out of fold"
    for part in [p for p in ("kinds", "all") if p in row]:
        figures_, what = row[part], {"kinds": "its kinds", "all": "every kind"}[part]
        print(f"{row['row']} seed {row.get('fit_seed', 0)} ({what}: {figures_['failed']} failed, {figures_['clean']} "
              f"clean{said})")
        for method in METHODS:
            f, extra = figures_[method], ""
            if "clean_flagged" in f:
                extra = f"  clean suspect {f['clean_flagged']}/{figures_['clean']}, slow/hesitant {f['odd_flagged']}"
            if "alerted" in f:
                extra += (f"/{f['odd']}; first reason's phase {f.get('phase', '-')}/{figures_['failed']}; live: "
                          f"alerted before the end {f['alerted']}/{figures_['failed']}, on clean {f['clean_alerts']}")
            print(f"  {method:10s} AUROC {f['auroc']:.3f}  top-k {f['top_k']:.1%}{extra}", flush=True)


def main() -> None:
    wanted = os.environ.get("BENCH_AUDIT", "dev" if quick() else ",".join([*ARMS, "desk", "speed"])).split(",")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-audit-") as tmp:
        root = Path(tmp)
        models = {}
        for name in [n for n in wanted if n in ARMS]:
            for row in arm_rows(name, root / name):
                models.setdefault(name, Path(row["model"]))
                rows.append(row)
                printed(row)
        if "desk" in wanted:
            for row in desk_rows(root / "desk"):
                rows.append(row)
                printed(row)
        if "speed" in wanted or quick():
            model = models.get("dev") or Path(arm_rows("dev", root / "dev")[0]["model"])
            speed = speed_row(root, model)
            print(f"speed: {speed['recordings']:,} recordings of 600 frames: audit {speed['audit']['wall_s']:.1f} s "
                  f"wall, {speed['audit']['cpu_s']:.1f} s CPU; predict {speed['predict']['wall_s']:.1f} s wall, "
                  f"{speed['predict']['cpu_s']:.1f} s CPU", flush=True)
    for round_, names in ROUNDS.items():
        summary(round_, [r for r in rows if r.get("name") in names])
    print(f"audit: {len(rows)} row(s) measured")


def summary(round_: str, rows: list[dict]) -> None:
    """A held-out round's figures against issue 63's targets: the mean and range over its arms and seeds."""
    if not rows:
        return
    held = [r["kinds"] for r in rows]
    for key in ("auroc", "top_k"):
        values = [h["audit"][key] for h in held]
        print(f"{round_} round, held-out kinds, {len(held)} fits: audit {key} mean {sum(values) / len(values):.3f} "
              f"(range {min(values):.3f}-{max(values):.3f}), target {TARGETS[key]}")
    total = lambda key: sum(h["audit"][key] for h in held)  # noqa: E731
    failed, clean = sum(h["failed"] for h in held), sum(h["clean"] for h in held)
    worst = max(h["audit"]["clean_flagged"] for h in held)
    print(f"{round_} round: clean suspect {total('clean_flagged')}/{clean} (at most {worst} of 30 in one fit), first "
          f"reason's phase {total('phase')}/{failed}, live before the end {total('alerted')}/{failed}, live on clean "
          f"{total('clean_alerts')}")


if __name__ == "__main__":
    main()
