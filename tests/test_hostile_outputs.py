"""Outputs that would collide with each other or with an input, and outputs that cannot all be written: predict
and export refuse in one line (exit 2) and leave every file as it was; predict writes all its outputs or none.
Runs the real CLI on a real DESK model and the DESK test split as a recording."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from refusals import refused_in as refused
from mlnseq import export
from mlnseq.catalog import artifacts

runner = CliRunner()


@pytest.fixture(autouse=True)
def quiet_errors(monkeypatch):
    monkeypatch.delenv("MLNSEQ_VERBOSE", raising=False)


@pytest.fixture(scope="module")
def model(tmp_path_factory, desk_full_workdir) -> Path:
    folder = tmp_path_factory.mktemp("hostile-outputs")
    return export.run(desk_full_workdir, export.ExportOptions(method="lstm", output=folder / "lstm.mlnseq")).path


@pytest.fixture
def recording(tmp_path, desk_test_recording) -> Path:
    return Path(shutil.copy(desk_test_recording, tmp_path / "trial.csv"))


@pytest.mark.parametrize("extra", ["--intervals", "--rerun"])
def test_predict_refuses_two_outputs_of_one_name(model, recording, tmp_path, extra):
    out = tmp_path / "out.parquet"
    refused(tmp_path, "predict", model, "--source", recording, "-o", out, extra, out,
            needles=(f"{extra} {out}", "also the file of -o"))


@pytest.mark.parametrize("flag", ["-o", "--intervals", "--rerun"])
def test_predict_never_overwrites_an_input_even_with_force(model, recording, tmp_path, flag):
    extra = [] if flag == "-o" else ["-o", tmp_path / "p.parquet"]
    refused(tmp_path, "predict", model, "--source", recording, "--force", *extra, flag, recording,
            needles=(f"{flag} {recording}", "is an input"))
    refused(model.parent, "predict", model, "--source", recording, "--force", *extra, flag, model,
            needles=("is an input",))


def test_a_recording_inside_a_source_folder_is_an_input_too(model, recording, tmp_path):
    folder = tmp_path / "trials"
    folder.mkdir()
    shutil.move(recording, folder / "trial.csv")
    refused(tmp_path, "predict", model, "--source", folder, "--force", "-o", tmp_path / "p.parquet",
            "--intervals", folder / "trial.csv", needles=("is an input",))


def test_predict_writes_all_its_outputs_or_none(model, recording, tmp_path):
    """The Rerun file cannot be written (its folder is a file): neither the predictions nor the intervals are
    left, and no temporary file either."""
    blocked = tmp_path / "blocked"
    blocked.write_text("a file, not a folder\n")
    refused(tmp_path, "predict", model, "--source", recording, "-o", tmp_path / "p.parquet",
            "--intervals", tmp_path / "p.csv", "--rerun", blocked / "p.rrd", needles=("cannot write",))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocked", "trial.csv"]


@pytest.fixture
def full_disk(tmp_path):
    """A real 64 KiB tmpfs (root only, where mounting is allowed)."""
    mount = tmp_path / "full"
    mount.mkdir()
    if shutil.which("mount") is None or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                                                       capture_output=True).returncode:
        pytest.skip("cannot mount a small tmpfs here")
    yield mount
    subprocess.run(["umount", str(mount)], check=True)


def test_a_full_disk_while_writing_the_rerun_file_leaves_no_output(model, recording, tmp_path, full_disk):
    refused(tmp_path, "predict", model, "--source", recording, "-o", tmp_path / "p.parquet",
            "--intervals", tmp_path / "p.csv", "--rerun", full_disk / "p.rrd",
            needles=("cannot write", "p.rrd", "No space left on device"))
    assert not list(full_disk.iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["full", "trial.csv"]


def test_export_never_writes_over_a_workdir_file_and_needs_force_for_an_existing_output(desk_full_workdir, tmp_path):
    workdir = Path(shutil.copytree(desk_full_workdir, tmp_path / "work"))
    for force in ([], ["--force"]):
        refused(workdir, "export", "--method", "lstm", "-o", workdir / artifacts.FRAMES, *force, "-w", workdir,
                needles=("frames.parquet", "the model is made from"))
    out = tmp_path / "m.mlnseq"
    assert runner.invoke(app, ["export", "--method", "lstm", "-o", str(out), "-w", str(workdir)]).exit_code == 0
    refused(tmp_path, "export", "--method", "lstm", "-o", out, "-w", workdir, needles=("exists; pass --force",))
    again = runner.invoke(app, ["export", "--method", "lstm", "-o", str(out), "--force", "-w", str(workdir)])
    assert again.exit_code == 0, again.output


def test_a_full_disk_while_training_is_one_line_and_keeps_the_workdir_as_it_was(desk_full_workdir, tmp_path):
    """torch.save on a full disk raises its own RuntimeError ("enforce fail at inline_container.cc"): one line naming
    the checkpoint and the full disk, exit 2, no temporary file left in models/."""
    workdir = Path(shutil.copytree(desk_full_workdir, tmp_path / "work"))
    shutil.rmtree(workdir / "models")
    (workdir / "models").mkdir()
    if shutil.which("mount") is None or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=16k", "tmpfs", str(workdir / "models")], capture_output=True).returncode:
        pytest.skip("cannot mount a small tmpfs here")
    try:
        refused(workdir, "train", "--epochs", "1", "--workdir", workdir,
                needles=("cannot write", "models/lstm.pt:", "No space left on device"))
        assert not list((workdir / "models").iterdir())
    finally:
        subprocess.run(["umount", str(workdir / "models")], check=True)
