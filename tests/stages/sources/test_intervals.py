"""Labels as intervals (--labels, every source) and JIGSAWS trials: the same frames as a labelled CSV."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq import collect, sources
from mlnseq.sources.desk import CLASSES as DESK_CLASSES
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import SourceOptions, jigsaws
from mlnseq.sources.recording import Labels, TableColumns
from mlnseq.sources.table import collect_frames

TRIALS = {"A": 400, "B": 300}


@pytest.fixture(scope="module")
def desk(shared_data) -> np.ndarray:
    """The 14 DESK kinematics channels and the label of the first 700 frames."""
    return np.loadtxt(shared_data / "desk-taurus" / "taurus_kinematics_train.txt")[:sum(TRIALS.values())]


def runs(labels: np.ndarray) -> list[tuple[int, int, int]]:
    """(first, last, label) of each run of one label."""
    edges = [0, *(np.flatnonzero(np.diff(labels)) + 1).tolist(), len(labels)]
    return [(a, b - 1, int(labels[a])) for a, b in zip(edges, edges[1:])]


@pytest.fixture(scope="module")
def lab(desk, tmp_path_factory) -> Path:
    """One recording, written as a labelled CSV, as an unlabelled CSV with intervals in frames and in
    seconds (20 Hz), and as a JIGSAWS task folder."""
    folder = tmp_path_factory.mktemp("lab")
    rows, frames_rows, seconds_rows = [], ["episode,start,end,label"], ["episode\tstart\tend\tlabel"]
    (folder / "task" / "kinematics" / "AllGestures").mkdir(parents=True)
    (folder / "task" / "transcriptions").mkdir()
    start = 0
    for trial, n in TRIALS.items():
        part = desk[start:start + n]
        start += n
        table = pl.DataFrame({"trial": [trial] * n, "t": np.arange(n) * 0.05,
                              "phase": [DESK_CLASSES[int(k)] for k in part[:, -1]]})
        rows.append(table.hstack(pl.DataFrame({f"k{i + 1}": np.tile(part[:, :14], 6)[:, i] for i in range(76)})))
        transcript = []
        for first, last, label in runs(part[:, -1]):
            frames_rows.append(f"{trial},{first},{last},{DESK_CLASSES[label]}")
            seconds_rows.append(f"{trial}\t{first * 0.05:.2f}\t{(last + 1) * 0.05:.2f}\t{DESK_CLASSES[label]}")
            transcript.append(f"{first + 1} {last + 1} {DESK_CLASSES[label].replace(' ', '_')}")
        np.savetxt(folder / "task" / "kinematics" / "AllGestures" / f"Task_{trial}.txt", np.tile(part[:, :14], 6)[:, :76])
        (folder / "task" / "transcriptions" / f"Task_{trial}.txt").write_text("\n".join(transcript) + "\n")
    pl.concat(rows).write_csv(folder / "labelled.csv")
    pl.concat(rows).drop("phase").write_csv(folder / "plain.csv")
    (folder / "frames.csv").write_text("\n".join(frames_rows) + "\n")
    (folder / "seconds.tsv").write_text("\n".join(seconds_rows) + "\n")
    return folder


COLUMNS = TableColumns(label="phase", episode="trial", time="t")


def frames_of(env: str, source: Path, columns=COLUMNS, **options) -> pl.DataFrame:
    return collect_frames(sources.read(env, source, columns, SourceOptions(**options)), columns.classes)[0]


def test_intervals_in_frames_or_seconds_give_the_frames_of_a_label_column(lab):
    expected = frames_of("table", lab / "labelled.csv")
    assert frames_of("table", lab / "plain.csv", labels=lab / "frames.csv").equals(expected)
    assert frames_of("table", lab / "plain.csv", labels=lab / "seconds.tsv", labels_unit="seconds").equals(expected)


def test_a_jigsaws_folder_gives_the_frames_of_the_same_csv(lab):
    names = tuple(c.replace(" ", "_") for c in DESK_CLASSES)
    found = frames_of("jigsaws", lab / "task", TableColumns(classes=names))
    expected = frames_of("table", lab / "labelled.csv")
    assert found.columns[:4] == expected.columns[:4] and found.columns[4:] == list(jigsaws.FEATURES)
    assert found.select(expected.columns[:4]).equals(expected.select(expected.columns[:4]))
    assert np.array_equal(found.select(jigsaws.FEATURES).to_numpy(), expected.select(expected.columns[4:]).to_numpy())


def test_frames_outside_every_interval_are_dropped_or_given_the_unlabelled_class(lab, tmp_path):
    lines = (lab / "frames.csv").read_text().splitlines()
    first = lines[1].split(",")
    assert int(first[2]) >= 5
    lines[1] = ",".join([first[0], "5", *first[2:]])  # trial A's first 5 frames in no interval
    gappy = tmp_path / "gappy.csv"
    gappy.write_text("\n".join(lines) + "\n")
    dropped = frames_of("table", lab / "plain.csv", labels=gappy)
    assert dropped.height == sum(TRIALS.values()) - 5
    classes = (*DESK_CLASSES, "idle")
    kept = frames_of("table", lab / "plain.csv", TableColumns(episode="trial", time="t", classes=classes),
                     labels=gappy, unlabelled="idle")
    assert kept.height == sum(TRIALS.values()) and kept["label"].head(5).to_list() == [7] * 5


@pytest.mark.parametrize(("edit", "needle"), [
    (lambda ls: ls[:2] + ["A,3,9,S1 approach peg"] + ls[2:], r"frames.csv:3: overlaps"),
    (lambda ls: [ls[0], "A,9,3,S1 approach peg", *ls[1:]], r"frames.csv:2: ends \(3\) before it starts \(9\)"),
    (lambda ls: ls + ["B,300,999,S1 approach peg"], r"frames.csv:\d+: interval 300..999 falls outside"),
    (lambda ls: ls + ["C,0,3,S1 approach peg"], r"frames.csv:\d+: episode 'C' is in no recording"),
])
def test_bad_intervals_are_refused_naming_the_line(lab, tmp_path, edit, needle):
    bad = tmp_path / "frames.csv"
    bad.write_text("\n".join(edit((lab / "frames.csv").read_text().splitlines())) + "\n")
    with pytest.raises(BadInput, match=needle):
        frames_of("table", lab / "plain.csv", labels=bad)


def test_collect_jigsaws_and_labels_through_the_cli(lab, tmp_path):
    runner = CliRunner()
    done = runner.invoke(app, ["collect", "--env", "jigsaws", "--source", str(lab / "task"), "-w", str(tmp_path / "j")])
    assert done.exit_code == 0, done.output
    assert "700 frames, 2 episodes" in " ".join(done.output.split())
    _, meta = collect.artifacts.read_table(tmp_path / "j" / "frames.parquet", "frames")
    assert meta["reading"]["env"] == "jigsaws" and meta["episode_names"] == ["Task_A", "Task_B"]
    bad = runner.invoke(app, ["collect", "--env", "table", "--source", str(lab / "plain.csv"), "--episode-column",
                              "trial", "--labels", str(lab / "frames.csv"), "--classes", "S1 approach peg",
                              "-w", str(tmp_path / "t")])
    assert bad.exit_code == 2 and "is not one of --classes" in bad.stderr
    assert bad.stderr.strip().count("\n") == 0 and not (tmp_path / "t" / "frames.parquet").exists()


def test_a_file_that_says_its_unit_is_read_without_labels_unit(lab, tmp_path):
    """A unit column (as `mlnseq review` saves) says each row's unit: seconds read as seconds without --labels-unit;
    a --labels-unit that says otherwise, or an episode in two units, is one line."""
    expected = frames_of("table", lab / "labelled.csv")
    lines = (lab / "seconds.tsv").read_text().splitlines()
    said = tmp_path / "said.csv"
    said.write_text("\n".join(["episode,start,end,label,unit", *(",".join([*line.split("\t"), "seconds"])
                                                                 for line in lines[1:])]) + "\n")
    assert frames_of("table", lab / "plain.csv", labels=said).equals(expected)  # the table's default unit: frames
    with pytest.raises(BadInput, match=r"said.csv:2: the file says its unit is seconds, --labels-unit says frames"):
        frames_of("table", lab / "plain.csv", labels=said, labels_unit="frames")
    mixed = tmp_path / "mixed.csv"
    text = said.read_text().splitlines()
    mixed.write_text("\n".join([*text[:2], text[2].replace("seconds", ""), *text[3:]]) + "\n")
    with pytest.raises(BadInput, match=r"mixed.csv:3: in the default unit, unlike .*mixed.csv:2 \(seconds\)"):
        frames_of("table", lab / "plain.csv", labels=mixed)


@pytest.mark.parametrize(("text", "needle"), [
    ("episode,start,end,label\n", r"empty.csv holds no interval or click, only its header"),
    ("", r"empty.csv: cannot read it as intervals|empty.csv holds no interval or click"),
])
def test_a_labels_file_without_a_row_is_one_line(lab, tmp_path, text, needle):
    (tmp_path / "empty.csv").write_text(text)
    done = CliRunner().invoke(app, ["collect", "--env", "table", "--source", str(lab / "plain.csv"), "--episode-column",
                                    "trial", "--labels", str(tmp_path / "empty.csv"), "-w", str(tmp_path / "w")])
    assert done.exit_code == 2 and len(done.stderr.strip().splitlines()) == 1, done.output
    assert __import__("re").search(needle, done.stderr), done.stderr


def test_a_class_no_other_labels_use_is_refused_as_a_typo(lab, tmp_path):
    """A class of the labels file that one episode alone has, and no other labels (the recordings' own, the file's
    other episodes) do, is refused in one line naming the line, unless --classes names it."""
    lines = (lab / "frames.csv").read_text().splitlines()
    typo = tmp_path / "typo.csv"
    typo.write_text("\n".join([*lines[:2], lines[2].replace(lines[2].split(",")[3], "S2 grsap peg"), *lines[3:]]) + "\n")
    with pytest.raises(BadInput, match=r"typo.csv:3: class 'S2 grsap peg' labels episode 'A' only, no other labels "
                                       r"have it .*--classes") as refused:
        frames_of("table", lab / "plain.csv", labels=typo)
    assert "\n" not in str(refused.value)
    one = tmp_path / "one.csv"  # trial A from the file, trial B by its own phase column: the others are B's own
    one.write_text("\n".join(line for line in typo.read_text().splitlines() if not line.startswith("B,")) + "\n")
    with pytest.raises(BadInput, match=r"one.csv:3: class 'S2 grsap peg' labels episode 'A' only"):
        sources.read("table", lab / "labelled.csv", COLUMNS, SourceOptions(labels=one), Labels.SOME)  # as collect
    named = (*DESK_CLASSES, "S2 grsap peg")
    found = frames_of("table", lab / "plain.csv", TableColumns(episode="trial", time="t", classes=named), labels=typo)
    assert found.height == sum(TRIALS.values())  # named in --classes: a class of its own
