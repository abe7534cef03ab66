"""The LeRobot round trip on datasets LeRobot 0.6.1 wrote itself (../shared/data/lerobot-0.6.1): its own subtask
annotations read as labels (`--labels subtask`), predicted phases written back in that convention (`predict
--write-lerobot`) and read again, the source never written to, and the refusals in one line each."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from mlnseq import collect, predict, sources
from mlnseq.catalog.errors import BadInput
from mlnseq.sources import SourceOptions, lerobot_language, lerobot_writer
from mlnseq.sources.recording import TableColumns
from mlnseq.sources.table import collect_frames
from mlnseq_cli.main import app
from mlnseq.recognition.reading import ReadOptions

DATA_FILE = Path("data/chunk-000/file-000.parquet")
INFO = Path("meta/info.json")
JOINTS = ["shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper"]


@pytest.fixture(scope="module")
def lerobot_data(shared_data) -> Path:
    return shared_data / "lerobot-0.6.1"


def digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def subtask_frames(source: Path, **options) -> tuple[pl.DataFrame, dict]:
    collected = collect.collect(collect.CollectOptions(env="lerobot", source=source, recordings=SourceOptions(
        annotations="subtask", **options)))
    return collected.frames, collected.meta


@pytest.fixture(scope="module")
def model(lerobot_data, tmp_path_factory) -> Path:
    """`mlnseq fit --labels subtask` on the annotated dataset (2 epochs): a model that remembers reading them."""
    folder = tmp_path_factory.mktemp("fit")
    done = CliRunner().invoke(app, ["fit", "--env", "lerobot", "--source", str(lerobot_data / "pick-place-annotated"),
                                    "--labels", "subtask", "--epochs", "2", "-w", str(folder / "work"),
                                    "-o", str(folder / "arm.mlnseq")])
    assert done.exit_code == 0, done.output
    return folder / "arm.mlnseq"


def test_labels_subtask_on_the_annotated_dataset_are_its_intervals(lerobot_data):
    frames, meta = subtask_frames(lerobot_data / "pick-place-annotated")
    by_intervals, same = collect_frames(sources.read("lerobot", lerobot_data / "pick-place", TableColumns(),
                                                     SourceOptions(labels=lerobot_data / "pick-place.intervals.csv")))
    assert frames.equals(by_intervals) and frames.height == 1256
    assert meta["classes"] == same["classes"] == ["grasp", "lift", "place", "reach"]  # from the rows' contents
    assert meta["reading"]["annotations"] == "subtask" and meta["notes"] == []
    picked = collect.collect(collect.CollectOptions(
        env="lerobot", source=lerobot_data / "pick-place-annotated", recordings=SourceOptions(annotations="subtask"),
        columns=TableColumns(features=("observation.state", "action/gripper")))).meta["features"]
    assert picked == [*(f"observation.state/{n}" for n in JOINTS), "action/gripper"]


def test_the_true_phases_written_back_are_lerobots_own_annotated_dataset_byte_for_byte(lerobot_data, tmp_path):
    frames, meta = collect_frames(sources.read("lerobot", lerobot_data / "pick-place", TableColumns(), SourceOptions(
        labels=lerobot_data / "pick-place.intervals.csv")))
    table = pl.DataFrame({"episode": np.asarray(meta["episode_names"])[frames["episode"].to_numpy()],
                          "class": np.asarray(meta["classes"])[frames["label"].to_numpy()]})
    predicted = lerobot_writer.Predicted(table["episode"].to_numpy(), table["class"].to_numpy(), None,
                                         tuple(meta["classes"]))
    written = lerobot_writer.write(tmp_path, lerobot_data / "pick-place", predicted)
    assert written == lerobot_writer.Written(predicted=8, kept=0)
    assert digests(tmp_path) == digests(lerobot_data / "pick-place-annotated")


@pytest.fixture(scope="module")
def written_back(model, lerobot_data, tmp_path_factory) -> tuple[Path, predict.Predicted, dict]:
    folder = tmp_path_factory.mktemp("written")
    source = lerobot_data / "pick-place-heldout"
    before = digests(source)
    result = predict.run(predict.PredictOptions(
        model=model, source=source, output=folder / "p.parquet", rerun=folder / "p.rrd",
        write_lerobot=folder / "out", lerobot_probabilities=True))
    assert digests(source) == before  # the source never written to
    return folder / "out", result, before


def test_write_lerobot_then_labels_subtask_gives_back_predicts_classes(written_back, model):
    out, result, source_files = written_back
    assert result.metrics is None  # the model reads subtask annotations where a dataset has them: none here
    assert result.lerobot == lerobot_writer.Written(predicted=2, kept=0) and result.written[-1] == out
    frames, meta = subtask_frames(out)
    assert frames.height == result.table.height == 336
    assert [meta["classes"][k] for k in frames["label"]] == result.table["class"].to_list()
    assert meta["features"] == [*(f"observation.state/{n}" for n in JOINTS), *(f"action/{n}" for n in JOINTS)]
    # a model trained without the new columns reads the written dataset, and its annotations as labels
    again = predict.run(predict.PredictOptions(model=model, source=out, output=out.parent / "again.parquet"))
    assert again.table.drop("label").equals(result.table) and again.metrics["frame_accuracy"] == 1.0



def test_the_written_dataset_is_the_source_with_the_language_columns_and_probabilities(written_back, lerobot_data):
    out, result, source_files = written_back
    written = digests(out)
    assert {k: v for k, v in written.items() if k not in (str(DATA_FILE), str(INFO))} == {
        k: v for k, v in source_files.items() if k not in (str(DATA_FILE), str(INFO))}
    assert written.keys() == source_files.keys()
    source = lerobot_data / "pick-place-heldout"
    info, before = json.loads((out / INFO).read_text()), json.loads((source / INFO).read_text())
    classes = list(result.table.columns[4:])
    assert info == {**before, "features": {
        **before["features"], "language_persistent": lerobot_language.DECLARATION,
        "language_events": lerobot_language.DECLARATION, "mlnseq.subtask_probabilities": {
            "dtype": "float32", "shape": [4], "names": [c.removeprefix("p_") for c in classes]}}}
    old, new = pq.ParquetFile(source / DATA_FILE), pq.ParquetFile(out / DATA_FILE)
    assert new.read().select(old.schema_arrow.names).equals(old.read())
    assert new.schema_arrow.metadata == old.schema_arrow.metadata  # LeRobot's huggingface metadata as it was
    assert new.schema_arrow.field("language_persistent").type == lerobot_language.PERSISTENT_TYPE
    assert [new.metadata.row_group(i).num_rows for i in range(new.num_row_groups)] == [
        old.metadata.row_group(i).num_rows for i in range(old.num_row_groups)]
    table = new.read()
    assert table["language_events"].to_pylist() == [[]] * 336
    probabilities = np.asarray(table["mlnseq.subtask_probabilities"].to_pylist())
    assert np.array_equal(probabilities, result.table.select(classes).to_numpy().astype(np.float32))
    first = table.filter(pa.compute.equal(table["episode_index"], 0))
    stamps = first["timestamp"].to_numpy()
    classes_0 = result.table.filter(pl.col("episode") == 0)["class"].to_numpy()
    starts = np.r_[0, np.flatnonzero(classes_0[1:] != classes_0[:-1]) + 1]
    assert first["language_persistent"][0].as_py() == [
        {"role": "assistant", "content": classes_0[k], "style": "subtask", "timestamp": float(stamps[k]),
         "camera": None, "tool_calls": None} for k in starts]  # one row per segment, at its first frame's time


def test_the_rerun_recording_holds_the_written_back_segments_as_time_ranges(written_back):
    rr = pytest.importorskip("rerun", reason="the [recordings] extra is not installed")
    out, result, _ = written_back
    lanes = {chunk.entity_path: chunk.to_record_batch().to_pydict()
             for chunk in rr.chunk.RrdReader(out.parent / "p.rrd").stream() if "/segments/" in chunk.entity_path}
    lane = lanes["/episode/0/segments/predicted"]
    episode = result.table.filter(pl.col("episode") == 0)
    classes = episode["class"].to_numpy()
    starts = np.r_[0, np.flatnonzero(classes[1:] != classes[:-1]) + 1]
    assert lane["frame"] == [*starts.tolist(), episode.height]
    assert [s[0] for s in lane["StateChange:state"]] == [*classes[starts].tolist(), ""]  # "": the lane ends there


@pytest.fixture(scope="module")
def mixed(lerobot_data, tmp_path_factory) -> Path:
    """pick-place-annotated with episodes 5, 6 and 7 unannotated (their language_persistent emptied): the annotation
    workflow, some episodes labelled in LeRobot and the rest to predict."""
    root = tmp_path_factory.mktemp("mixed") / "pick-place"
    shutil.copytree(lerobot_data / "pick-place-annotated", root, copy_function=shutil.copyfile)
    parquet = pq.ParquetFile(lerobot_data / "pick-place-annotated" / DATA_FILE)
    with pq.ParquetWriter(root / DATA_FILE, parquet.schema_arrow) as writer:
        for index in range(parquet.num_row_groups):
            group = parquet.read_row_group(index)
            rows = [[] if e >= 5 else r for e, r in zip(group["episode_index"].to_pylist(),
                                                       group["language_persistent"].to_pylist())]
            position = group.schema.get_field_index("language_persistent")
            writer.write_table(group.set_column(position, group.schema.field(position),
                                                pa.array(rows, type=group.schema.field(position).type)))
    return root


def test_episodes_without_annotations_are_read_unlabelled_with_a_note(mixed, lerobot_data, tmp_path):
    everything, _ = subtask_frames(lerobot_data / "pick-place-annotated")
    read, meta = subtask_frames(mixed)
    frames = read.filter(pl.col("split") != "unlabelled")
    assert frames["episode"].n_unique() == 5 and frames.height == 174 + 133 + 146 + 172 + 145
    bare = read.filter(pl.col("split") == "unlabelled")
    assert bare["episode"].unique().sort().to_list() == [5, 6, 7] and bare["label"].null_count() == bare.height
    assert bare.height == everything.filter(pl.col("episode") >= 5).height  # every frame of theirs, none dropped
    assert meta["notes"] == ["3 recordings without labels: used unlabelled (never in a test split or a score)"]
    assert frames.drop("split").equals(everything.filter(pl.col("episode") < 5).drop("split"))
    done = CliRunner().invoke(app, ["collect", "--env", "lerobot", "--source", str(mixed), "--labels", "subtask",
                                    "-w", str(tmp_path)])
    assert done.exit_code == 0 and "note: 3 recordings without labels: used unlabelled" in " ".join(done.output.split())


def test_annotated_episodes_keep_their_annotations_unless_replaced(mixed, model, lerobot_data, tmp_path):
    result = predict.run(predict.PredictOptions(model=model, source=mixed, output=tmp_path / "p.parquet",
                                                write_lerobot=tmp_path / "out"))
    assert (result.metrics["recordings"], result.metrics["of"]) == (5, 8)  # the annotated episodes scored alone
    assert result.table.filter(pl.col("episode") >= 5)["label"].null_count() == result.table.filter(
        pl.col("episode") >= 5).height  # the others: no label
    assert result.lerobot == lerobot_writer.Written(predicted=3, kept=5)
    frames, meta = subtask_frames(tmp_path / "out")
    labels = np.asarray(meta["classes"])[frames["label"].to_numpy()]
    truth, truth_meta = subtask_frames(lerobot_data / "pick-place-annotated")
    annotated = frames["episode"].to_numpy() < 5
    assert (labels[annotated] == np.asarray(truth_meta["classes"])[truth["label"].to_numpy()][annotated]).all()
    assert (labels[~annotated] == result.table["class"].to_numpy()[~annotated]).all()
    replaced = predict.run(predict.PredictOptions(model=model, source=mixed, output=tmp_path / "q.parquet",
                                                  write_lerobot=tmp_path / "out", replace_subtasks=True, force=True))
    assert replaced.lerobot == lerobot_writer.Written(predicted=8, kept=0)
    frames, meta = subtask_frames(tmp_path / "out")
    assert [meta["classes"][k] for k in frames["label"]] == replaced.table["class"].to_list()


def refusal(*args: str) -> str:
    done = CliRunner().invoke(app, [str(a) for a in args])
    assert done.exit_code == 2, done.output
    assert done.stderr.strip().count("\n") == 0 and "Traceback" not in done.stderr
    return " ".join(done.stderr.split())


def test_the_refusals_are_one_line_each(model, written_back, lerobot_data, tmp_path):
    heldout = lerobot_data / "pick-place-heldout"
    out = written_back[0]
    write = ["predict", model, "--source", heldout, "-o", tmp_path / "p.parquet", "--write-lerobot"]
    assert "is the source dataset; predict never writes into its source" in refusal(*write, heldout, "--force")
    assert "is inside the source dataset" in refusal(*write, heldout / "meta" / "copy")
    assert "holds the source dataset" in refusal(*write, lerobot_data, "--force")
    assert f"--write-lerobot {out} exists; pass --force to replace it" in refusal(*write, out)
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("not a dataset\n")
    assert "is a folder but not a LeRobot dataset (no meta/info.json); --force replaces only a dataset" in refusal(
        *write, tmp_path / "notes", "--force")  # --force never removes a folder of other things
    assert "is inside --write-lerobot" in refusal("predict", model, "--source", heldout, "-o", out / "p.parquet",
                                                  "--write-lerobot", out, "--force")
    assert "--write-lerobot-probabilities and --replace-subtasks go with --write-lerobot OUT" in refusal(
        "predict", model, "--source", heldout, "-o", tmp_path / "p.parquet", "--write-lerobot-probabilities")
    pick_place = lerobot_data / "pick-place"
    collect_ = ["collect", "--env", "lerobot", "--source", pick_place, "-w", tmp_path / "w"]
    assert "pick-place: no language_persistent column, so no subtask annotations" in refusal(
        *collect_, "--labels", "subtask")
    annotated = ["collect", "--env", "lerobot", "--source", lerobot_data / "pick-place-annotated", "-w", tmp_path / "w"]
    assert ("--label-column language_persistent: language_persistent holds LeRobot's language annotations (lists of "
            "rows), not values; read its subtasks as labels with --labels subtask") in refusal(
        *annotated, "--label-column", "language_persistent")
    assert "--features language_persistent: language_persistent holds LeRobot's language" in refusal(
        *annotated, "--features", "language_persistent", "--labels", "subtask")
    assert ("--features mlnseq.subtask_probabilities/reach: mlnseq.subtask_probabilities is a column mlnseq wrote "
            "(predict --write-lerobot)") in refusal("collect", "--env", "lerobot", "--source", out, "--features",
                                                    "mlnseq.subtask_probabilities/reach", "--labels", "subtask")
    assert "--labels subtask reads a LeRobot dataset's own subtask annotations, but --source is read as --env table" in (
        refusal("collect", "--env", "table", "--source", lerobot_data / "pick-place.intervals.csv", "--labels",
                "subtask", "-w", tmp_path / "w"))


def test_a_failed_write_leaves_nothing_half_written(model, lerobot_data, tmp_path):
    """Intervals that leave frames out: the prediction does not cover every frame, so nothing is written."""
    intervals = tmp_path / "part.csv"
    rows = (lerobot_data / "pick-place-heldout.intervals.csv").read_text().splitlines()
    intervals.write_text("\n".join([rows[0], rows[1].replace(",0,", ",3,", 1), *rows[2:]]) + "\n")
    with pytest.raises(BadInput, match=r"episode 0 has 177 frames, 174 of them predicted; --write-lerobot needs every "
                                       r"frame: predict without --labels, or with --unlabelled CLASS"):
        predict.run(predict.PredictOptions(model=model, source=lerobot_data / "pick-place-heldout",
                                           output=tmp_path / "p.parquet", write_lerobot=tmp_path / "out",
                                           reading=ReadOptions(overrides={"labels": intervals})))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["part.csv"]  # no dataset, no predictions, no leftovers


def test_only_v3_datasets_are_written_back(tmp_path):
    (tmp_path / "v21" / "meta").mkdir(parents=True)
    (tmp_path / "v21" / INFO).write_text(json.dumps({"codebase_version": "v2.1", "features": {}}))
    with pytest.raises(BadInput, match=r"v21 is a v2.1 dataset and LeRobot 0.6.1 reads subtask annotations from v3.0 "
                                       r"ones: convert it with LeRobot's convert_dataset_v21_to_v30 first"):
        lerobot_writer.write(tmp_path / "out", tmp_path / "v21", lerobot_writer.Predicted(
            np.zeros(1), np.array(["a"]), None, ("a",)))


LEROBOT_FILTER = """
import json, sys
from lerobot.datasets.lerobot_dataset import LeRobotDataset
ds = LeRobotDataset("local/audited", root=sys.argv[1], episode_filter=lambda ep: ep["mlnseq_verdict"] == "ok")
print(json.dumps({"kept": sorted({int(ds[i]["episode_index"]) for i in range(len(ds))}), "frames": len(ds)}))
"""


def gripper_open(source: Path, out: Path, episode: int) -> Path:
    """A copy of ``source`` whose ``episode`` never closes its gripper (state and action held open: 1.0)."""
    shutil.copytree(source, out)
    table = pq.read_table(out / DATA_FILE)
    rows = table.column("episode_index").to_numpy() == episode
    for name in ("observation.state", "action"):
        column = table.column(name).combine_chunks()
        values = column.values.to_numpy(zero_copy_only=False).reshape(len(table), -1).copy()
        values[rows, JOINTS.index("gripper")] = 1.0
        held = pa.FixedSizeListArray.from_arrays(pa.array(values.ravel(), type=column.type.value_type), values.shape[1])
        table = table.set_column(table.schema.get_field_index(name), table.schema.field(name), held)
    pq.write_table(table, out / DATA_FILE, compression="snappy")
    return out


def test_audit_writes_the_verdicts_where_lerobot_filters_episodes(model, lerobot_data, tmp_path):
    """An episode whose gripper never closes is suspect, the other ok; the copy's episodes metadata holds each one's
    verdict, score and reasons, the rest of it is the source's; with MLNSEQ_LEROBOT_PYTHON (a Python with LeRobot
    0.6.1 installed: too heavy for the suite), LeRobot's own episode_filter on the verdict keeps exactly the ok ones."""
    import os
    import subprocess

    failed = gripper_open(lerobot_data / "pick-place-heldout", tmp_path / "failed", episode=1)
    before = digests(failed)
    done = CliRunner().invoke(app, ["audit", str(model), "--source", str(failed), "-o", str(tmp_path / "a.csv"),
                                    "--write-lerobot", str(tmp_path / "out")])
    assert done.exit_code == 0, done.output
    verdicts = dict(pl.read_csv(tmp_path / "a.csv").select("episode", "verdict").iter_rows())
    assert verdicts == {0: "ok", 1: "suspect"} and digests(failed) == before
    episodes = pq.read_table(tmp_path / "out" / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert {row["episode_index"]: row["mlnseq_verdict"] for row in episodes} == verdicts
    assert episodes[1]["mlnseq_score"] >= 1 and episodes[1]["mlnseq_reasons"][0].startswith(episodes[1]["mlnseq_reason"])
    copied = digests(tmp_path / "out")
    assert {k: v for k, v in copied.items() if "meta/episodes" not in k} == {
        k: v for k, v in before.items() if "meta/episodes" not in k}
    python = os.environ.get("MLNSEQ_LEROBOT_PYTHON")
    if python:
        run = subprocess.run([python, "-c", LEROBOT_FILTER, str(tmp_path / "out")], capture_output=True, text=True,
                             timeout=600, env={**os.environ, "HF_HUB_OFFLINE": "1"})
        assert run.returncode == 0, run.stderr[-2000:]
        assert json.loads(run.stdout.splitlines()[-1]) == {"kept": [0], "frames": 177}
