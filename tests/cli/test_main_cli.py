"""The application: its command list, each command's help, and the libraries each loads (in fresh processes).

`mlnseq --help` and `mlnseq COMMAND --help` load no heavy library; a command loads torch, matplotlib or
MuJoCo only when it runs and needs them.
"""

from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import typer

from mlnseq_cli.main import COMMANDS
from mlnseq.catalog import artifacts

HEAVY = ("torch", "matplotlib", "mujoco", "gymnasium", "gymnasium_robotics", "scipy")
DATA = ("polars", "pyarrow", "numpy")  # what a stage needs, but not the command list

# Runs `mlnseq ARGS` in this process (the console entry point) and prints its output, exit code and modules.
RUN_AND_LIST_MODULES = """
import contextlib, io, json, sys
from mlnseq_cli.main import main
sys.argv = ["mlnseq", *sys.argv[1:]]
out = io.StringIO()
with contextlib.redirect_stdout(out):
    try:
        main()
        code = 0
    except SystemExit as exit:
        code = exit.code or 0
print(json.dumps({"output": out.getvalue(), "code": code, "modules": sorted(sys.modules)}))
"""


def mlnseq(*args: str | Path) -> dict:
    env = {**os.environ, "COLUMNS": "200", "MLNSEQ_VERBOSE": ""}
    done = subprocess.run([sys.executable, "-c", RUN_AND_LIST_MODULES, *map(str, args)], capture_output=True,
                          text=True, env=env)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def loaded(result: dict, names: tuple[str, ...]) -> list[str]:
    return [name for name in names if name in result["modules"]]


def test_the_command_list_loads_no_command_and_no_library():
    result = mlnseq("--help")
    assert result["code"] == 0
    for name, command in COMMANDS.items():
        assert f"{name} " in result["output"] and command.summary.split(":")[0] in result["output"]
    assert loaded(result, HEAVY + DATA) == []
    assert not any(module.startswith("mlnseq_cli.") and module not in ("mlnseq_cli.main", "mlnseq_cli.flags")
                   for module in result["modules"])


@pytest.mark.parametrize("command", list(COMMANDS))
def test_a_commands_help_is_its_docstring_and_loads_no_heavy_library(command):
    result = mlnseq(command, "--help")
    assert result["code"] == 0
    target = getattr(importlib.import_module(f"mlnseq_cli.{COMMANDS[command].module}"), COMMANDS[command].function)
    docstring = target.info.help if isinstance(target, typer.Typer) else target.__doc__
    assert f"Usage: mlnseq {command}" in result["output"]
    assert " ".join(docstring.split()[:8]) in " ".join(result["output"].split())
    assert loaded(result, HEAVY) == []


def test_light_stages_run_without_torch(tmp_path, desk_full_workdir):
    workdir = tmp_path / "work"
    shutil.copytree(desk_full_workdir, workdir)
    for args in (["eval"], ["binarize"], ["formulas"], ["learn-weights"]):  # eval before its inputs change
        result = mlnseq(*args, "-w", workdir)
        assert result["code"] == 0, result["output"]
        light = HEAVY[:-1] if args == ["learn-weights"] else HEAVY  # scipy's optimiser is learn-weights' engine
        assert loaded(result, light) == [], args
    assert artifacts.read_metadata(workdir / artifacts.WEIGHTS, "weights")


def test_training_and_conflation_load_torch_but_not_the_simulator(tmp_path, desk_full_workdir):
    workdir = tmp_path / "work"
    shutil.copytree(desk_full_workdir, workdir)
    for args in (["train", "--epochs", "1"], ["conflate"]):
        result = mlnseq(*args, "-w", workdir)
        assert result["code"] == 0, result["output"]
        assert "torch" in result["modules"] and loaded(result, ("mujoco", "matplotlib")) == []
        assert "torch._dynamo" not in result["modules"]  # torch.optim's first use would import it (seconds)


def test_an_unknown_command_is_refused():
    done = subprocess.run([sys.executable, "-m", "mlnseq_cli.main", "colect"], capture_output=True, text=True)
    assert done.returncode == 2 and "No such command 'colect'" in done.stderr


def test_a_mistyped_command_gets_the_closest_name():
    done = subprocess.run([sys.executable, "-m", "mlnseq_cli.main", "trian"], capture_output=True, text=True)
    assert done.returncode == 2 and "No such command 'trian'. Did you mean 'train'?" in done.stderr


def test_version_is_the_installed_packages_and_loads_no_command():
    from importlib import metadata

    result = mlnseq("--version")
    assert result["code"] == 0 and result["output"] == f"mlnseq {metadata.version('mlnseq')}\n"
    assert loaded(result, HEAVY + DATA) == []


@pytest.mark.parametrize("args", [[], ["train"], ["config", "show"]])
def test_flags_show_no_type_in_help_and_completion_is_offered(args):
    output = mlnseq(*args, "--help")["output"]
    assert "<bool>" not in output and "--help " in output
    assert ("--install-completion" in output) == (args == [])
    if args == ["train"]:
        assert "<int>" in output  # options that take a value still show its type


def test_shell_completion_lists_command_names_without_importing_them():
    env = {**os.environ, "_MLNSEQ_COMPLETE": "complete_bash", "COMP_WORDS": "mlnseq lea", "COMP_CWORD": "1",
           "PYTHONPROFILEIMPORTTIME": "1"}
    done = subprocess.run([sys.executable, "-m", "mlnseq_cli.main"], capture_output=True, text=True, env=env)
    assert done.returncode == 0 and done.stdout.split() == ["learn-weights"]
    imported = [line.rsplit("|", 1)[1].strip() for line in done.stderr.splitlines() if "|" in line]
    assert "mlnseq_cli.learn_weights" not in imported and "polars" not in imported
    options = subprocess.run([sys.executable, "-m", "mlnseq_cli.main"], capture_output=True, text=True,
                             env={**env, "COMP_WORDS": "mlnseq train --ep", "COMP_CWORD": "2"})
    assert options.stdout.split() == ["--epochs"]
