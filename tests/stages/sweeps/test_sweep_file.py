"""The sweep file and the options of `mlnseq sweep`: a bad one is one line on stderr, exit 2, nothing written or
submitted (no OUT folder); a good one expands into the grid's configs with the stages' flags."""

from __future__ import annotations

from pathlib import Path

import pytest

from mlnseq.sweeps import grid
from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.pipeline.sweep import SWEPT as STAGES
from sweep_files import refused, write_sweep

runner = CliRunner()


def mlnseq(*args: str, cwd: Path):
    """`mlnseq ARGS` in this process (every refusal comes before Snakemake would start)."""
    return runner.invoke(app, list(args))


def test_the_grid_expands_in_the_files_order_with_the_stages_flags(tmp_path, tiny_desk_workdir):
    path = write_sweep(tmp_path, tiny_desk_workdir, 'cell = ["lstm", "gru"]\nwindow = [32, 16]\nepochs = [3]\n'
                       'export.method = ["conflation"]\nmln_mode = ["exact"]\n', seeds="[3]")
    sweep = grid.read(path, STAGES)
    assert sweep.seeds == (3,) and sweep.keys == ("cell", "window", "epochs", "export.method", "mln_mode")
    assert [c.name for c in sweep.configs] == ["cell-lstm_window-32", "cell-lstm_window-16",
                                              "cell-gru_window-32", "cell-gru_window-16"]
    last = sweep.configs[-1]
    assert grid.flags("train", last.options["train"]) == ["--epochs", "3", "--mode", "stream", "--cell", "gru",
                                                         "--window", "16"]
    assert grid.flags("conflate", last.options["conflate"]) == ["--mln-mode", "exact"]
    assert grid.flags("export", last.options["export"]) == ["--method", "conflation", "--decode", "filter",
                                                          "--mln-mode", "exact"]


@pytest.mark.parametrize("grid_lines, words", [
    ('cell = ["lstm", "lstmm"]', ["line 6", "'cell'", "'lstmm'", "choose one of lstm"]),
    ('epochs = [5]\nwindw = [8]', ["line 7", "'windw'", "no stage takes --windw", "train's method, ", "window"]),
    ('hidden_size = [16]', ["line 6", "'hidden_size'", "no stage takes --hidden-size", "conflate's "]),
    ('epochs = ["five"]', ["line 6", "'epochs'", "whole number"]),
    ('epochs = [0]', ["line 6", "--epochs must be at least 1"]),
    ('export.decode = ["sideways"]', ["line 6", "'export.decode'", "'sideways'", "filter"]),
    ('export.output = ["x.mlnseq"]', ["line 6", "'export.output'"]),
    ('cell = "tcn"', ["line 6", "non-empty list", '["tcn"]']),
    ('lag = [-1]', ["line 6", "'lag'", "--lag -1: a lag is at least 0 frames"]),
    ('formulas = ["no-such.mln"]', ["line 6", "'formulas'", "'no-such.mln' is not a formulas file"]),
])
def test_a_bad_grid_is_one_line_naming_its_line_and_key(tmp_path, tiny_desk_workdir, grid_lines, words):
    path = write_sweep(tmp_path, tiny_desk_workdir, grid_lines)
    refused(mlnseq("sweep", str(path), cwd=tmp_path), str(path), *words)
    assert not (tmp_path / "sweep").exists()


def test_bad_sweep_heads_and_files(tmp_path, tiny_desk_workdir):
    path = tmp_path / "s.toml"
    path.write_text('[sweep]\nworkdir = "w"\nseeds = [0, 0]\n')
    refused(mlnseq("sweep", str(path), cwd=tmp_path), "line 3", "distinct")
    path.write_text('[sweep]\nworkdir = "w"\nseed = [0]\n')
    refused(mlnseq("sweep", str(path), cwd=tmp_path), "line 3", "unknown [sweep] key 'seed'", "seeds")
    path.write_text('[sweep\n')
    refused(mlnseq("sweep", str(path), cwd=tmp_path), "not valid TOML", "line 1")
    refused(mlnseq("sweep", str(tmp_path / "none.toml"), cwd=tmp_path), "none.toml not found")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


def test_a_missing_workdir_input_names_the_stage_that_writes_it(tmp_path, tiny_desk_workdir):
    workdir = tmp_path / "data"
    workdir.mkdir()
    for name in ("frames.parquet", "predicates.parquet", "weights.parquet"):
        (workdir / name).symlink_to(tiny_desk_workdir / name)
    path = write_sweep(tmp_path, workdir, 'cell = ["lstm"]')
    refused(mlnseq("sweep", str(path), cwd=tmp_path), "weights.folds.parquet not found", "learn-weights --folds K")
    assert not (tmp_path / "sweep").exists()


def test_more_than_1000_configs_need_yes(tmp_path, tiny_desk_workdir):
    grid_lines = f"batch_size = {list(range(1, 35))}\nwindow = {list(range(1, 31))}"
    path = write_sweep(tmp_path, tiny_desk_workdir, grid_lines)
    refused(mlnseq("sweep", str(path), cwd=tmp_path), "1,020 configs", "over 1,000", "--yes")
    assert not (tmp_path / "sweep").exists()
    assert len(grid.read(path, STAGES).configs) == 1020


def test_a_slurm_profile_that_does_not_parse_submits_nothing(tmp_path, tiny_desk_workdir):
    path = write_sweep(tmp_path, tiny_desk_workdir, 'cell = ["lstm"]')
    profile = tmp_path / "profile"
    profile.mkdir()
    (profile / "config.yaml").write_text("executor: slurm\njobs: [4\n")
    refused(mlnseq("sweep", str(path), "--executor", "slurm", "--profile", str(profile), cwd=tmp_path),
            "config.yaml line 3", "does not parse as YAML")
    (profile / "config.yaml").write_text("- executor\n")
    refused(mlnseq("sweep", str(path), "--executor", "slurm", "--profile", str(profile), cwd=tmp_path), "mapping")
    refused(mlnseq("sweep", str(path), "--executor", "slurm", "--profile", str(tmp_path / "nothing"),
                   cwd=tmp_path), "not a Snakemake profile folder")
    refused(mlnseq("sweep", str(path), "--executor", "slurm", cwd=tmp_path), "needs --profile")
    refused(mlnseq("sweep", str(path), "--executor", "cloud", cwd=tmp_path), "unknown --executor 'cloud'", "slurm")
    assert not (tmp_path / "sweep").exists()


def test_a_sweep_is_planned_from_python_without_the_command_line(tmp_path, tiny_desk_workdir):
    """``mlnseq.sweep``'s plan in a fresh Python: the grid read against the stages' options, no command line loaded."""
    import subprocess
    import sys

    path = write_sweep(tmp_path, tiny_desk_workdir, 'cell = ["lstm", "gru"]\nepochs = [3]\n', seeds="[3]")
    code = ("import sys, mlnseq; from mlnseq.pipeline.sweep import plan; "
            f"print([c.name for c in plan({str(path)!r}).configs], "
            "sorted(m for m in sys.modules if m.split('.')[0] in ('typer', 'mlnseq_cli')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["['cell-lstm',", "'cell-gru']", "[]"]


def test_the_example_profile_parses():
    from mlnseq.pipeline.sweep import check_profile

    settings = check_profile(Path(__file__).resolve().parents[3] / "examples" / "sweep" / "slurm-profile")
    assert settings["executor"] == "slurm" and settings["slurm-status-command"] == "squeue"


def test_a_formulas_key_names_configs_by_the_files_stem(tmp_path, tiny_desk_workdir, repo_root):
    grid_lines = f'formulas = ["{repo_root}/examples/temporal.mln", "{repo_root}/examples/conjunctive.mln"]'
    sweep = grid.read(write_sweep(tmp_path, tiny_desk_workdir, grid_lines), STAGES)
    assert [c.name for c in sweep.configs] == ["formulas-temporal", "formulas-conjunctive"]
    assert sweep.configs[1].formulas == (repo_root / "examples" / "conjunctive.mln").resolve()


def test_the_example_sweep_file_reads():
    sweep = grid.read(Path(__file__).resolve().parents[3] / "examples" / "sweep" / "sweep.toml", STAGES)
    assert [c.name for c in sweep.configs] == ["cell-lstm", "cell-tcn"]
    assert sweep.seeds == (0, 1) and sweep.workdir.name == "mlnseq-work"


def test_without_snakemake_the_sweep_names_its_extra(tmp_path, tiny_desk_workdir):
    """In a Python where Snakemake cannot be imported (blocked in sys.modules), one line names the extra `sweep`."""
    import subprocess
    import sys

    path = write_sweep(tmp_path, tiny_desk_workdir, 'cell = ["lstm"]')
    code = ("import sys; sys.modules['snakemake'] = None; from mlnseq_cli.main import main; "
            f"sys.argv = ['mlnseq', 'sweep', {str(path)!r}]; main()")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    refused(done, "pip install '.[sweep]' in mlnseq's checkout", "'mlnseq-0.1.0-py3-none-any.whl[sweep]' beside the wheel")
    assert not (tmp_path / "sweep").exists()


def test_a_grid_takes_method_names_as_commands_print_them(tmp_path, tiny_desk_workdir):
    """`export.method = ["mln+viterbi"]`, `decode = ["smooth-legal@5"]`: names as conflate and eval print them, each
    checked as its parts; a name and a decode that disagree are refused in one line."""
    path = write_sweep(tmp_path, tiny_desk_workdir, 'export.method = ["mln+viterbi", "conflation"]\n'
                       'decode = ["none"]\n')
    sweep = grid.read(path, STAGES)
    assert [grid.flags("export", c.options["export"])[:2] for c in sweep.configs] == [
        ["--method", "mln+viterbi"], ["--method", "conflation"]]
    lagged = write_sweep(tmp_path / "lagged", tiny_desk_workdir, 'export.method = ["conflation"]\n'
                         'decode = ["smooth-legal@5"]\n')
    assert len(grid.read(lagged, STAGES).configs) == 1
    clash = write_sweep(tmp_path / "clash", tiny_desk_workdir, 'export.method = ["conflation+filter"]\n'
                        'decode = ["viterbi"]\n')
    refused(mlnseq("sweep", str(clash), cwd=tmp_path), "names its decoder; --decode viterbi names another")
