"""Issue 55's smaller output items: binarize --table never offers a value true in none of a class's frames as its
marker (the real DESK predicates); collect names the joints that stop and start where their absence refuses it."""

from __future__ import annotations

import polars as pl

from mlnseq_cli import binarize as binarize_command
from mlnseq_cli.console import console
from mlnseq.catalog import artifacts


def test_a_class_no_value_marks_is_said_so_not_offered_a_zero_share(desk_mln_workdir, monkeypatch):
    predicates, meta = artifacts.read_table(desk_mln_workdir / artifacts.PREDICATES, "predicates")
    classes = meta["classes"]
    never = {"right_gripper": ["right_gripper_opening", "right_gripper_static"]}  # true in no training frame
    assert all(predicates.filter(pl.col("split") == "train")[c].sum() == 0 for c in never["right_gripper"])
    monkeypatch.setattr(console, "width", 200)
    with console.capture() as captured:
        binarize_command.print_class_table(predicates, never, classes)
    marks = captured.get().split("marks each class")[1].splitlines()[1:]
    assert len(marks) == len(classes)
    assert all(": none: no value is true in more of its frames" in line for line in marks), marks
    with console.capture() as captured:
        binarize_command.print_class_table(predicates, meta["predicates"], classes)
    marks = captured.get().split("marks each class")[1].splitlines()[1:]
    assert all("none" not in line and "(0%" not in line for line in marks), marks


def joint_switch_bag(path):
    """A ROS 2 bag whose /joint_states joints change from a, b, c to x, y, z at 3 s (50 Hz, 6 s), with /phase reach
    from 0 s and lift from 2.8 s: no frame has all six joints but the two held seconds after the switch, all lift."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    JointState, Header, Time, String = (store.types[n] for n in (
        "sensor_msgs/msg/JointState", "std_msgs/msg/Header", "builtin_interfaces/msg/Time", "std_msgs/msg/String"))
    start, step = 1_700_000_000 * 10**9, 20_000_000
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        joints = writer.add_connection("/joint_states", JointState.__msgtype__, typestore=store)
        phase = writer.add_connection("/phase", String.__msgtype__, typestore=store)
        for k in range(300):
            t = start + k * step
            if k in (0, 140):
                writer.write(phase, t, store.serialize_cdr(String(data="reach" if k == 0 else "lift"),
                                                           String.__msgtype__))
            message = JointState(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="base"),
                                 name=["a", "b", "c"] if k < 150 else ["x", "y", "z"],
                                 position=np.sin(np.arange(3) + k / 20.0), velocity=np.zeros(0), effort=np.zeros(0))
            writer.write(joints, t, store.serialize_cdr(message, JointState.__msgtype__))


def test_joints_that_stop_and_start_are_named_where_their_absence_refuses_collect(tmp_path):
    from typer.testing import CliRunner

    from mlnseq_cli.main import app

    (tmp_path / "bags").mkdir()
    joint_switch_bag(tmp_path / "bags" / "trial_1")
    done = CliRunner().invoke(app, ["collect", "--env", "rosbag", "--source", str(tmp_path / "bags"),
                                    "--label-topic", "/phase", "-w", str(tmp_path / "work")])
    assert done.exit_code == 2 and len(done.stderr.splitlines()) == 1
    assert "the labels hold a single class ('lift')" in done.stderr
    assert "position/a, position/b, position/c stop at 2.98 s" in done.stderr
    assert "position/x, position/y, position/z start at 3.00 s" in done.stderr
    assert not (tmp_path / "work" / artifacts.FRAMES).exists()


def test_collect_on_a_lerobot_dataset_with_subtasks_and_no_labels_suggests_labels_subtask(shared_data, tmp_path):
    from typer.testing import CliRunner

    from mlnseq_cli.main import app

    def collected(name):
        return CliRunner().invoke(app, ["collect", "--env", "lerobot", "--source",
                                        str(shared_data / "lerobot-0.6.1" / name), "-w", str(tmp_path / name)])

    annotated = collected("pick-place-annotated")
    assert annotated.exit_code == 2 and "subtask annotations label its frames with --labels subtask" in annotated.stderr
    plain = collected("pick-place")  # no annotations: nothing to suggest but a column or intervals
    assert plain.exit_code == 2 and "subtask" not in plain.stderr and "label intervals with --labels" in plain.stderr


def test_one_recording_is_split_by_its_frames_as_the_pages_say(repo_root, desk_test_recording, tmp_path):
    from typer.testing import CliRunner

    from mlnseq_cli.main import app

    stages_md = " ".join((repo_root / "docs" / "stages.md").read_text().split())
    assert "a single recording (one episode) is split by its frames: its first 70 % train" in stages_md
    assert "one recording alone: the first 70 % of its frames" in (repo_root / "docs" / "first-day.md").read_text()
    done = CliRunner().invoke(app, ["collect", "--env", "table", "--source", str(desk_test_recording),
                                    "--time-column", "frame", "-w", str(tmp_path)])
    assert done.exit_code == 0, done.output
    frames = pl.read_parquet(tmp_path / artifacts.FRAMES)
    assert frames["episode"].n_unique() == 1
    assert (frames["split"] == "train").sum() == round(0.7 * frames.height)
    train, test = (frames.filter(pl.col("split") == part)["frame"] for part in ("train", "test"))
    assert train.max() < test.min()  # by position: the first frames train


def test_a_sweep_sets_exactly_the_options_the_stages_commands_take():
    """The sweep's table of options (mlnseq.pipeline.sweep, no command line imported) against the commands' flags."""
    import inspect
    from dataclasses import fields

    from mlnseq_cli.conflate import conflate
    from mlnseq_cli.export import export
    from mlnseq_cli.train import train
    from mlnseq.pipeline.sweep import SWEPT

    for name, command in (("train", train), ("conflate", conflate), ("export", export)):
        flags = set(inspect.signature(command).parameters) - {"workdir"}
        assert SWEPT.flags[name] == flags & {f.name for f in fields(SWEPT[name])}, name


def test_sweeps_md_offers_as_grid_choices_only_options_a_stage_takes(repo_root):
    from mlnseq.pipeline.sweep import SWEPT as STAGES

    intro = " ".join((repo_root / "docs" / "sweeps.md").read_text().split("\n\n")[1].split())
    named = {"network type": "cell", "training window": "window", "epochs": "epochs", "MLN mode": "mln_mode",
             "deployed method": "method", "decoding": "decode"}
    assert "its size" not in intro and "not the network's size, which train does not take" in intro
    for words, key in named.items():
        assert words in intro and any(key in flags for flags in STAGES.flags.values()), key
    assert not any("hidden_size" in flags for flags in STAGES.flags.values())


def test_deploy_md_says_what_its_commands_need_first(repo_root):
    page = (repo_root / "docs" / "deploy.md").read_text()
    text = " ".join(page.split())
    assert "run that page's commands first, in the same folder" in text and "<!-- continues: sequential-logic.md -->" \
        in page
    assert "on a fresh clone it first runs the set-up of `make setup`" in text
    makefile = (repo_root / "Makefile").read_text()
    assert "dist: | $(SETUP_DONE)" in makefile  # what the page says: dist needs the set-up done


def test_the_rich_fetch_spec_on_other_frames_names_the_fix_its_page_gives(desk_mln_workdir, repo_root, tmp_path):
    import shutil

    from typer.testing import CliRunner

    from mlnseq_cli.main import app

    shutil.copy(desk_mln_workdir / artifacts.FRAMES, tmp_path / artifacts.FRAMES)
    done = CliRunner().invoke(app, ["binarize", "--spec", str(repo_root / "examples" / "fetch-rich.binarize.toml"),
                                    "-w", str(tmp_path)])
    assert done.exit_code == 2 and done.stderr.count("\n") == 1
    assert "channel 'grip_pos_x' is not in frames.parquet" in done.stderr
    assert "collect them with `mlnseq collect --env fetch --goals`" in done.stderr
    assert "with `--goals`" in (repo_root / "docs" / "predicates.md").read_text()  # the page's fix
