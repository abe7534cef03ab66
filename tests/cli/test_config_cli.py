"""The project file: `--config`, else ./mlnseq.toml, else WORKDIR/mlnseq.toml; `mlnseq config show` names it."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts

runner = CliRunner()


@pytest.fixture
def here(tmp_path, monkeypatch) -> Path:
    """An empty current folder."""
    folder = tmp_path / "project"
    folder.mkdir()
    monkeypatch.chdir(folder)
    monkeypatch.setenv("MLNSEQ_VERBOSE", "")
    return folder


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory, desk_full_workdir) -> Path:
    """A workdir eval can score (its own copy: the tests write mlnseq.toml into it)."""
    return Path(shutil.copytree(desk_full_workdir, tmp_path_factory.mktemp("config") / "work"))


def fraction_in_force(workdir: Path, *args: str) -> tuple[float, str]:
    """The fraction eval used (as metrics.parquet records it) and what it said on stderr."""
    done = runner.invoke(app, [*args, "eval", "-w", str(workdir)])
    assert done.exit_code == 0, done.output
    return artifacts.read_metadata(workdir / artifacts.METRICS, "metrics")["options"]["fraction"], done.stderr


def shown_file(workdir: Path, *args: str) -> str:
    done = runner.invoke(app, [*args, "config", "show", "-w", str(workdir)])
    assert done.exit_code == 0, done.output
    return next(line for line in done.stdout.splitlines() if line.startswith("project file:"))


def test_the_current_folders_file_is_read_and_named(here, evaluated):
    (evaluated / "mlnseq.toml").unlink(missing_ok=True)
    (here / "mlnseq.toml").write_text("[eval]\nfraction = 0.25\n")
    assert fraction_in_force(evaluated) == (0.25, "")
    assert shown_file(evaluated) == "project file: mlnseq.toml (from the current folder)"


def test_the_current_folders_file_wins_over_the_workdirs_with_a_note(here, evaluated):
    (here / "mlnseq.toml").write_text("[eval]\nfraction = 0.25\n")
    (evaluated / "mlnseq.toml").write_text("[eval]\nfraction = 0.75\n")
    fraction, said = fraction_in_force(evaluated)
    assert fraction == 0.25
    assert said.strip() == (f"note: {evaluated / 'mlnseq.toml'} is not read: mlnseq.toml in the current folder wins "
                            "(pass --config to choose)")
    assert shown_file(evaluated) == "project file: mlnseq.toml (from the current folder)"
    shown = runner.invoke(app, ["config", "show", "-w", str(evaluated)])  # its note on stderr, as eval's
    assert shown.stderr == said and "is not read" not in shown.stdout


def test_the_workdirs_file_is_read_when_the_current_folder_has_none(here, evaluated):
    (evaluated / "mlnseq.toml").write_text("[eval]\nfraction = 0.75\n")
    assert fraction_in_force(evaluated) == (0.75, "")
    assert shown_file(evaluated) == f"project file: {evaluated / 'mlnseq.toml'} (from the workdir)"


def test_config_wins_over_both(here, evaluated, tmp_path):
    (here / "mlnseq.toml").write_text("[eval]\nfraction = 0.25\n")
    (evaluated / "mlnseq.toml").write_text("[eval]\nfraction = 0.75\n")
    chosen = tmp_path / "chosen.toml"
    chosen.write_text("[eval]\nfraction = 0.4\n")
    assert fraction_in_force(evaluated, "--config", str(chosen)) == (0.4, "")
    assert shown_file(evaluated, "--config", str(chosen)) == f"project file: {chosen} (from --config)"


def test_without_a_project_file_show_says_where_it_looked(here, tmp_path):
    assert shown_file(tmp_path / "work") == (
        f"project file: none (looked for ./mlnseq.toml and {tmp_path / 'work' / 'mlnseq.toml'})")
