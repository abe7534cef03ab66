"""One click per phase (--labels of episode,frame,label or episode,time,label rows, mixed with intervals or not):
the clicked frames kept as given, the boundaries between them learned, and bad clicks refused in one line. On the
generated arm's bags (tests/arm_bags.py), whose /phase topic is the truth the clicks are drawn from."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq import collect
from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.labelling import clicks
from mlnseq.sources import SourceOptions, intervals

pytest.importorskip("rosbags")

SEEDS = {f"episode_{k + 1}": 5200 + k for k in range(4)}


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> dict:
    """Four bags, their frames labelled by /phase (the truth) and one click per phase of each, in the middle of
    its phase (``middle.csv``) or a quarter into it (``quarter.csv``)."""
    import arm_bags

    root = tmp_path_factory.mktemp("clicks")
    robot = arm_bags.ROBOTS["panda"]
    for name, seed in SEEDS.items():
        arm_bags.write_bag(root / "bags" / name, robot, seed)
    (root / "middle.csv").write_text("\n".join(arm_bags.clicks(robot, SEEDS)) + "\n")
    (root / "quarter.csv").write_text("\n".join(arm_bags.clicks(robot, SEEDS, 0.25)) + "\n")
    truth = read(root / "bags", label_topic="/phase")
    return {"root": root, "bags": root / "bags", "truth": truth, "rate": robot.rate, "robot": robot}


def read(source: Path, **options) -> collect.Collected:
    return collect.collect(collect.CollectOptions(env="rosbag", source=source, recordings=SourceOptions(**options)))


def accuracy(collected: collect.Collected, truth: collect.Collected) -> float:
    names, true_names = np.asarray(collected.meta["classes"]), np.asarray(truth.meta["classes"])
    return float(np.mean(names[collected.frames["label"].to_numpy()] == true_names[truth.frames["label"].to_numpy()]))


def halfway_accuracy(collected: collect.Collected, truth: collect.Collected) -> float:
    """The labels a click file gives with every boundary halfway between its two clicks (nothing learned)."""
    frames, labels = collected.frames, collected.frames["label"].to_numpy().copy()
    for episode in range(frames["episode"].max() + 1):
        given = sorted((f, c) for e, f, c in collected.meta["clicks"] if e == episode)
        rows = np.flatnonzero(frames["episode"].to_numpy() == episode)
        labels[rows] = intervals.halfway(len(rows), np.array([f for f, _ in given]), [c for _, c in given])
    names = np.asarray(collected.meta["classes"])
    return float(np.mean(names[labels.astype(int)] == np.asarray(truth.meta["classes"])[truth.frames["label"]]))


def test_clicks_label_every_frame_keeping_the_clicked_ones(arm):
    found = read(arm["bags"], labels=arm["root"] / "middle.csv")  # the column `frame`: frames
    assert found.frames.height == arm["truth"].frames.height and found.frames["label"].null_count() == 0
    given = found.meta["clicks"]
    assert len(given) == 4 * 5 and found.meta["clicks_filled"]["boundaries"] == 4 * 4
    assert clicks.filled_said(found.meta["clicks_filled"]).startswith("clicks: 20 clicks, one label each; 16 "
                                                                      "boundaries between them learned (change point")
    frames = found.frames
    for episode, frame, label in given:
        row = frames.filter((pl.col("episode") == episode) & (pl.col("frame") == frame))
        assert row["label"].item() == label
    truth = arm["truth"]
    truth_of = dict(zip(zip(truth.frames["episode"], truth.frames["frame"]), truth.frames["label"]))
    assert all(found.meta["classes"][c] == truth.meta["classes"][truth_of[(e, f)]] for e, f, c in given)


@pytest.mark.parametrize("name", ["middle.csv", "quarter.csv"])
def test_boundaries_are_learned_better_than_halfway(arm, name):
    found = read(arm["bags"], labels=arm["root"] / name)
    learned, halfway = accuracy(found, arm["truth"]), halfway_accuracy(found, arm["truth"])
    assert learned > 0.85 and learned > halfway + 0.01, (learned, halfway)


def change_points_alone(collected: collect.Collected, aligned: bool = False) -> np.ndarray:
    """The labels of each boundary at its span's change point (between the two clicks), ``aligned`` or not: what
    ``clicks.fill`` does without the other recordings' clicks and labels aligned in time."""
    frames, labels = collected.frames, collected.frames["label"].to_numpy().copy()
    features = frames.select(artifacts.feature_columns(frames)).to_numpy().astype(np.float64)
    z = (features - features.mean(axis=0)) / (features.std(axis=0) + 1e-9)
    episodes, positions = frames["episode"].to_numpy(), frames["frame"].to_numpy()
    spans = [(np.flatnonzero((episodes == s.episode) & (positions >= s.first) & (positions <= s.last)), s.before,
              s.after) for s in clicks.free_spans(collected.meta["clicks"])]
    cuts = [clicks.change_point(z[rows]) for rows, _, _ in spans]
    for (rows, before, after), t in zip(spans, clicks.moved_to_their_kind(z, episodes, spans, cuts) if aligned else cuts):
        labels[rows[:t]], labels[rows[t:]] = before, after
    return labels


@pytest.mark.parametrize("name", ["middle.csv", "quarter.csv"])
def test_aligned_boundaries_are_more_right_than_change_points_alone(arm, name):
    found, truth = read(arm["bags"], labels=arm["root"] / name), arm["truth"]
    true_labels = np.array([found.meta["classes"].index(truth.meta["classes"][t]) for t in truth.frames["label"]])
    aligned = float(np.mean(found.frames["label"].to_numpy() == true_labels))
    alone = float(np.mean(change_points_alone(found) == true_labels))
    assert aligned > alone + 0.02, (aligned, alone)


def random_clicks(robot: str, seed: int) -> tuple[pl.DataFrame, list[list[int]], np.ndarray]:
    """Six recordings of the generated arm (frames.parquet rows), a click at a random frame of each phase, and the
    truth."""
    import arm_bags

    signals = [arm_bags.episode_signals(arm_bags.ROBOTS[robot], seed + k) for k in range(6)]
    rng, given = np.random.default_rng(seed), []
    for episode, phases in enumerate(s["phase"] for s in signals):
        for phase in range(len(arm_bags.PHASES)):
            inside = np.flatnonzero(phases == phase)
            given.append([episode, int(inside[int(rng.uniform(0.1, 0.9) * (len(inside) - 1))]), phase])
    return arm_bags.frames_table(signals, ["train"] * 6), given, np.concatenate([s["phase"] for s in signals])


def aligned_change_points(frames: pl.DataFrame, given: list[list[int]], labels: np.ndarray) -> np.ndarray:
    """Each boundary at its span's change point, aligned with those of its kind: fill without the other
    recordings' clicks and labels aligned in time."""
    z = frames.select(artifacts.feature_columns(frames)).to_numpy().astype(np.float64)
    z, episodes, labels = (z - z.mean(axis=0)) / z.std(axis=0), frames["episode"].to_numpy(), labels.copy()
    spans = [(np.flatnonzero(episodes == s.episode)[s.first:s.last + 1], s.before, s.after)
             for s in clicks.free_spans(given)]
    cuts = clicks.moved_to_their_kind(z, episodes, spans, [clicks.change_point(z[rows]) for rows, _, _ in spans])
    for (rows, before, after), t in zip(spans, cuts):
        labels[rows[:t]], labels[rows[t:]] = before, after
    return labels


def test_the_other_recordings_clicks_and_labels_aligned_in_time_place_boundaries_better():
    learned, alone = [], []
    for robot in ("panda", "iiwa", "xarm7"):
        for seed in (5300, 5400):
            frames, given, truth = random_clicks(robot, seed)
            filled, record = clicks.fill(frames, given, artifacts.feature_columns(frames))
            assert record["boundaries"] == 6 * 4 and "agreed" in record["method"]
            learned.append(np.mean(filled["label"].to_numpy() == truth))
            alone.append(np.mean(aligned_change_points(frames, given, truth) == truth))
    assert np.mean(learned) > 0.94 and np.mean(learned) > np.mean(alone) + 0.005, (learned, alone)


def test_a_recording_labelled_on_every_frame_says_where_the_clicked_ones_phases_begin():
    """One training recording labelled on every frame beside five clicked ones: each clicked one's boundaries come
    from it, aligned in time, within the clicks; better than from the clicks alone."""
    beside, alone = [], []
    for robot in ("panda", "iiwa", "xarm7"):
        frames, given, truth = random_clicks(robot, 5500)
        clicked = [c for c in given if c[0] != 0]
        rest = frames["episode"].to_numpy() != 0
        # episode 0: split train, its /phase labels on every frame
        filled, record = clicks.fill(frames, clicked, artifacts.feature_columns(frames))
        assert record["labelled"] == 1 and "labelled on every frame" in record["method"]
        labels = filled["label"].to_numpy()
        assert all(labels[np.flatnonzero(frames["episode"].to_numpy() == e)[f]] == c for e, f, c in clicked)
        beside.append(np.mean(labels[rest] == truth[rest]))
        without, record = clicks.fill(frames.filter(pl.Series(rest)), clicked, artifacts.feature_columns(frames))
        assert "labelled" not in record
        alone.append(np.mean(without["label"].to_numpy() == truth[rest]))
        tested = np.where(rest | (frames["frame"].to_numpy() < 100), "train", "test")  # its end a test split
        assert "labelled" not in clicks.fill(frames.with_columns(split=pl.Series(tested)), clicked,
                                               artifacts.feature_columns(frames))[1]
    assert np.mean(beside) > 0.97 and np.mean(beside) > np.mean(alone) + 0.01, (beside, alone)


def test_clicked_recordings_always_train_and_never_make_a_test_split(arm):
    found = read(arm["bags"], labels=arm["root"] / "middle.csv")  # 4 recordings: collect's 70 % rule would test one
    assert set(found.frames["split"]) == {"train"}
    assert set(arm["truth"].frames["split"]) == {"train", "test"}  # the same recordings labelled by /phase


def test_clicks_in_seconds_mixed_with_intervals(arm, tmp_path):
    rate = arm["rate"]
    lines = (arm["root"] / "middle.csv").read_text().splitlines()
    rows = ["episode,start,end,time,label"]
    for line in lines[1:]:
        episode, frame, label = line.split(",")
        if episode != "episode_1":
            rows.append(f"{episode},,,{int(frame) / rate:.4f},{label}")
    truth = arm["truth"].frames.filter(pl.col("episode") == 0)
    names = np.asarray(arm["truth"].meta["classes"])[truth["label"].to_numpy()]
    change = np.r_[0, np.flatnonzero(names[1:] != names[:-1]) + 1, len(names)]
    rows += [f"episode_1,{a / rate:.4f},{b / rate:.4f},,{names[a]}" for a, b in zip(change, change[1:])]
    (tmp_path / "mixed.csv").write_text("\n".join(rows) + "\n")
    found = read(arm["bags"], labels=tmp_path / "mixed.csv")  # a rosbag's default unit: seconds
    assert len(found.meta["clicks"]) == 3 * 5 and {e for e, _, _ in found.meta["clicks"]} == {1, 2, 3}
    first = found.frames.filter(pl.col("episode") == 0)
    assert list(np.asarray(found.meta["classes"])[first["label"].to_numpy()]) == list(names)  # intervals as given
    assert set(found.frames.filter(pl.col("episode") > 0)["split"]) == {"train"}  # the clicked ones all train
    assert accuracy(found, arm["truth"]) > 0.85


@pytest.mark.parametrize(("line", "needle"), [
    ("episode_2,99999,grasp", r"clicks.csv:\d+: click at 99999 falls outside .*episode_2'? \(0..\d+ frames\)"),
    ("episode_2,{first},place", r"clicks.csv:\d+: a second label at frames \d+ \('place'; .*clicks.csv:\d+ says "),
    ("episode_3,{first},grsap", r"clicks.csv:\d+: class 'grsap' is clicked in episode 'episode_3' only"),
])
def test_bad_clicks_are_refused_in_one_line(arm, tmp_path, line, needle):
    lines = (arm["root"] / "middle.csv").read_text().splitlines()
    first = lines[6].split(",")[1]  # episode_2's first click, in reach
    lines.append(line.format(first=first))
    (tmp_path / "clicks.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(BadInput, match=needle) as refused:
        read(arm["bags"], labels=tmp_path / "clicks.csv")
    assert "\n" not in str(refused.value)


def test_a_click_in_an_episode_with_intervals_is_refused(arm, tmp_path):
    (tmp_path / "both.csv").write_text("episode,start,end,frame,label\nepisode_1,0,10,,reach\n"
                                       "episode_1,,,40,grasp\n")
    with pytest.raises(BadInput, match=r"both.csv:3: a click in an episode that has intervals too"):
        read(arm["bags"], labels=tmp_path / "both.csv", labels_unit="frames")


def test_collect_refuses_a_bad_click_in_one_line_and_writes_nothing(arm, tmp_path):
    from typer.testing import CliRunner

    from mlnseq_cli.main import app

    lines = (arm["root"] / "middle.csv").read_text().splitlines() + ["episode_2,99999,grasp"]
    (tmp_path / "clicks.csv").write_text("\n".join(lines) + "\n")
    done = CliRunner().invoke(app, ["collect", "--env", "rosbag", "--source", str(arm["bags"]), "--labels",
                                    str(tmp_path / "clicks.csv"), "-w", str(tmp_path / "work")])
    assert done.exit_code != 0 and "click at 99999 falls outside" in done.stderr
    assert done.stderr.strip().count("\n") == 0 and not (tmp_path / "work" / "frames.parquet").exists()
