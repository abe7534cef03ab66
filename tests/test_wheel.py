"""The wheel: built from this checkout, installed into a folder of its own, and the README's tour run from a
folder outside the checkout, in a Python that has mlnseq's dependencies but not pracmln (it stays optional).

Offline: the wheel is built with the set-up's setuptools (no build isolation) and installed without its
dependencies; those are the set-up's own, reached through links to every package but pracmln and the
checkout's editable install.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.mujoco]

PACKAGE_FILES = ("pyproject.toml", "README.md", "stages", "mlnseq_cli")
NOT_LINKED = ("pracmln", "__editable__", "mlnseq", "_virtualenv", "distutils-precedence")


def run(*command: str | Path, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    done = subprocess.run([str(c) for c in command], cwd=cwd, env=env, capture_output=True, text=True)
    assert done.returncode == 0, f"{command}\n{done.stdout}\n{done.stderr}"
    return done


@pytest.fixture(scope="module")
def installed(tmp_path_factory, repo_root) -> dict[str, Path]:
    """The wheel installed into ``target``; ``deps`` links the set-up's packages but pracmln and mlnseq."""
    root = tmp_path_factory.mktemp("wheel")
    source = root / "source"  # a copy: building writes build/ and *.egg-info beside the sources
    source.mkdir()
    for name in PACKAGE_FILES:
        copy = shutil.copytree if (repo_root / name).is_dir() else shutil.copy
        copy(repo_root / name, source / name, **({"ignore": shutil.ignore_patterns("__pycache__")}
                                                 if (repo_root / name).is_dir() else {}))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    run(*pip, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q", "-w", root / "wheels", source,
        cwd=root)
    [wheel] = (root / "wheels").glob("mlnseq-*.whl")
    run(*pip, "install", "--no-deps", "--no-index", "-q", "--target", root / "target", wheel, cwd=root)
    deps = root / "deps"
    deps.mkdir()
    for folder in {Path(sysconfig.get_paths()["purelib"]), Path(sysconfig.get_paths()["platlib"])}:
        for entry in folder.iterdir():
            if not entry.name.startswith(NOT_LINKED) and entry.suffix != ".pth" and not (deps / entry.name).exists():
                (deps / entry.name).symlink_to(entry)
    tour = root / "tour"
    tour.mkdir()
    return {"wheel": wheel, "target": root / "target", "deps": deps, "tour": tour}


def mlnseq(installed: dict[str, Path], *args: str) -> subprocess.CompletedProcess:
    """The installed mlnseq in a Python without site-packages: only the wheel and the linked dependencies."""
    env = {**os.environ, "PYTHONPATH": f"{installed['target']}{os.pathsep}{installed['deps']}", "COLUMNS": "200"}
    env.pop("MLNSEQ_VERBOSE", None)
    return subprocess.run([sys.executable, "-S", "-m", "mlnseq_cli.main", *args], cwd=installed["tour"], env=env,
                          capture_output=True, text=True)


def test_the_wheel_ships_the_built_in_specs_and_no_examples(installed):
    names = run(sys.executable, "-m", "zipfile", "-l", installed["wheel"], cwd=installed["tour"]).stdout
    for spec in ("stages/specs/fetch.binarize.toml", "stages/specs/desk.binarize.toml", "stages/specs/paper.mln"):
        assert spec in names
    assert "examples/" not in names and "tests/" not in names


README_TOUR = (
    ("collect", "--env", "fetch", "--episodes", "4"),
    ("binarize",),
    ("formulas",),
    ("learn-weights", "formulas.mln"),
    ("train", "--epochs", "2"),
    ("train", "--method", "priorlayer", "--epochs", "2"),
    ("conflate",),
    ("eval", "--method", "combined", "--json"),
)


@pytest.fixture(scope="module")
def toured(installed) -> dict[str, subprocess.CompletedProcess]:
    """The README's tour (fewer episodes and epochs) run with the installed mlnseq in its own folder."""
    results = {}
    for args in README_TOUR:
        results[args[0]] = done = mlnseq(installed, *args)
        assert done.returncode == 0, f"mlnseq {' '.join(args)}\n{done.stdout}\n{done.stderr}"
    return results


def test_the_readme_tour_runs_from_outside_the_checkout(installed, toured, repo_root):
    scores = json.loads(toured["eval"].stdout)
    assert 0 <= scores["combined"]["segment_accuracy"] <= 1
    predicates = json.loads(subprocess.run(
        [sys.executable, "-c", "import sys, pyarrow.parquet as pq; "
         "print(pq.read_schema(sys.argv[1]).metadata[b'mlnseq'].decode())",
         installed["tour"] / "mlnseq-work" / "predicates.parquet"],
        capture_output=True, text=True, check=True).stdout)
    spec = Path(predicates["spec"]["path"])  # the built-in spec, found inside the installed package
    assert spec.is_relative_to(installed["target"]) and spec.name == "fetch.binarize.toml"
    assert not spec.is_relative_to(repo_root)


def test_learn_weights_with_pracmln_absent_says_how_to_install_it(installed, toured):
    done = mlnseq(installed, "learn-weights", "--engine", "pracmln")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "pracmln" in lines[0] and "scripts/install_pracmln.sh" in lines[0], done.stderr


def test_the_installed_console_script_runs_the_installed_package(installed):
    env = {**os.environ, "PYTHONPATH": str(installed["target"])}
    done = run(installed["target"] / "bin" / "mlnseq", "--help", cwd=installed["tour"], env=env)
    assert "learn-weights" in done.stdout
    where = run(sys.executable, "-c", "import stages, mlnseq_cli; print(stages.__file__, mlnseq_cli.__file__)",
                cwd=installed["tour"], env=env).stdout.split()
    assert all(Path(path).is_relative_to(installed["target"]) for path in where)
