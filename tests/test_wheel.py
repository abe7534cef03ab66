"""The wheel: built from this checkout, installed into a folder of its own, and the README's tour run from a
folder outside the checkout, in a Python that has mlnseq's dependencies but not pracmln (it stays optional);
and the base install (no extra) recognising with an exported model, torch and scipy absent.

Offline: the wheel is built with the set-up's setuptools (no build isolation) and installed without its
dependencies; those are the set-up's own, reached through links: to every package but pracmln and the
checkout's editable install (the whole install), or to the base dependencies the wheel's metadata names and
theirs alone (the base install).
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import polars as pl
import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

pytestmark = [pytest.mark.slow]

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


def python(installed: dict[str, Path], *args: str | Path, deps: Path | None = None, cwd: Path | None = None,
           stdin: str | None = None) -> subprocess.CompletedProcess:
    """A Python without site-packages: only the installed wheel and the linked dependencies (``deps``, default
    the whole install's)."""
    env = {**os.environ, "PYTHONPATH": f"{installed['target']}{os.pathsep}{deps or installed['deps']}",
           "COLUMNS": "200"}
    env.pop("MLNSEQ_VERBOSE", None)
    return subprocess.run([sys.executable, "-S", *map(str, args)], cwd=cwd or installed["tour"], env=env,
                          input=stdin, capture_output=True, text=True)


def mlnseq(installed: dict[str, Path], *args: str | Path, **where) -> subprocess.CompletedProcess:
    """The installed mlnseq command (see ``python``)."""
    return python(installed, "-m", "mlnseq_cli.main", *args, **where)


def test_the_wheel_installs_the_package_mlnseq_and_nothing_generic(installed):
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    assert {name.split("/")[0] for name in names} == {"mlnseq", "mlnseq_cli", "mlnseq-0.1.0.dist-info"}
    for spec in ("mlnseq/specs/fetch.binarize.toml", "mlnseq/specs/desk.binarize.toml", "mlnseq/specs/paper.mln",
                 *(f"mlnseq/reviewing/page/{page}" for page in ("index.html", "review.js", "review.css",
                                                                "uPlot.iife.min.js", "uPlot.min.css"))):
        assert spec in names
    assert sorted(path.name for path in installed["target"].iterdir()) == ["bin", "mlnseq", "mlnseq-0.1.0.dist-info",
                                                                          "mlnseq_cli"]


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


@pytest.mark.mujoco
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


@pytest.mark.mujoco
def test_learn_weights_with_pracmln_absent_says_how_to_install_it(installed, toured):
    done = mlnseq(installed, "learn-weights", "--engine", "pracmln")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "pracmln" in lines[0] and "scripts/install_pracmln.sh" in lines[0], done.stderr


def test_the_installed_console_script_runs_the_installed_package(installed):
    env = {**os.environ, "PYTHONPATH": str(installed["target"])}
    done = run(installed["target"] / "bin" / "mlnseq", "--help", cwd=installed["tour"], env=env)
    assert "learn-weights" in done.stdout
    where = run(sys.executable, "-c", "import mlnseq, mlnseq_cli; print(mlnseq.__file__, mlnseq_cli.__file__)",
                cwd=installed["tour"], env=env).stdout.split()
    assert all(Path(path).is_relative_to(installed["target"]) for path in where)


# --- the base install: a robot computer that only recognises ----------------------------------------------

RECORDED = 4000  # frames of the DESK test recording that predict and stream read
HEAVY = ("torch", "scipy", "matplotlib", "mujoco", "gymnasium", "gymnasium_robotics", "rosbags", "h5py", "rerun")


def base_requirements(wheel: Path) -> set[str]:
    """The distributions the wheel needs without any extra, and theirs, as installed in this Python."""
    with zipfile.ZipFile(wheel) as archive:
        metadata = next(n for n in archive.namelist() if n.endswith(".dist-info/METADATA"))
        lines = archive.read(metadata).decode().splitlines()

    def unconditional(requirements: list[str] | None) -> list[str]:
        parsed = (Requirement(text) for text in requirements or ())
        return [canonicalize_name(r.name) for r in parsed if r.marker is None or r.marker.evaluate({"extra": ""})]

    todo = unconditional([line.split(":", 1)[1] for line in lines if line.startswith("Requires-Dist:")])
    found: set[str] = set()
    while todo:
        if (name := todo.pop()) not in found:
            found.add(name)
            todo += unconditional(importlib.metadata.distribution(name).requires)
    return found


@pytest.fixture(scope="module")
def light(installed, tmp_path_factory) -> Path:
    """A folder linking the base dependencies alone (each distribution's top-level files and folders)."""
    folder = tmp_path_factory.mktemp("light")
    for name in base_requirements(installed["wheel"]):
        distribution = importlib.metadata.distribution(name)
        for top in {Path(str(f)).parts[0] for f in distribution.files or () if not str(f).startswith("..")}:
            entry = Path(distribution.locate_file(top))
            if entry.exists() and top != "__pycache__" and not top.endswith(".pth") and not (folder / top).exists():
                (folder / top).symlink_to(entry)
    return folder


@pytest.fixture(scope="module")
def model(installed, desk_stream_workdir, tmp_path_factory) -> Path:
    """A DESK combined model with filter decoding (network, MLN and chain), exported by the whole install."""
    path = tmp_path_factory.mktemp("model") / "combined+filter.mlnseq"
    done = mlnseq(installed, "export", "--method", "combined", "--decode", "filter", "-w", desk_stream_workdir,
                  "-o", path)
    assert done.returncode == 0, done.stderr
    return path


# prints the named modules that are absent: imported (--import) or only looked for
IMPORTABLE = """import importlib, importlib.util, sys
importing = sys.argv[1] == "--import"
for name in sys.argv[2:] if importing else sys.argv[1:]:
    if importing:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as error:
            print(error.name)
    elif importlib.util.find_spec(name) is None:
        print(name)
"""


def test_the_base_install_lacks_the_heavy_libraries(installed, light):
    assert {canonicalize_name(n) for n in ("numpy", "polars", "pyarrow", "typer", "rich")} <= base_requirements(
        installed["wheel"])
    absent = python(installed, "-c", IMPORTABLE, "--import", *HEAVY, deps=light)
    assert absent.stdout.split() == list(HEAVY), absent.stderr
    assert python(installed, "-c", IMPORTABLE, *HEAVY).stdout.split() == []  # the whole install has them all


def test_import_mlnseq_and_load_a_model_on_the_base_install(installed, light, model):
    script = ("import sys, mlnseq\n"
              "recognizer = mlnseq.load(sys.argv[1])\n"
              "print(recognizer.step({'arm_distance': 0.31, 'left_gripper': 0.52, 'right_gripper': 0.98}).name)\n"
              "print(sorted(set(sys.modules) & set(sys.argv[2].split(','))))\n")
    done = python(installed, "-c", script, model, ",".join(HEAVY), deps=light)
    assert done.returncode == 0, done.stderr
    name, heavy = done.stdout.splitlines()
    assert name == python(installed, "-c", script, model, ",".join(HEAVY)).stdout.splitlines()[0] and heavy == "[]"


def test_info_predict_and_stream_on_the_base_install_equal_the_whole_install(installed, light, model,
                                                                             desk_test_recording, tmp_path):
    recording = tmp_path / "head.csv"  # the DESK test recording's first frames: every class, a few seconds
    recording.write_text("".join(desk_test_recording.read_text().splitlines(keepends=True)[:RECORDED + 1]))
    outputs = {}
    for install, deps in (("base", light), ("whole", installed["deps"])):
        folder = tmp_path / install
        folder.mkdir()
        shown = mlnseq(installed, "info", model, deps=deps, cwd=folder)
        predicted = mlnseq(installed, "predict", model, "--source", recording, "-o", "p.parquet", deps=deps,
                           cwd=folder)
        viterbi = mlnseq(installed, "predict", model, "--source", recording, "--decode", "viterbi", "-o",
                         "v.parquet", deps=deps, cwd=folder)
        streamed = mlnseq(installed, "stream", model, deps=deps, cwd=folder, stdin=recording.read_text())
        for done in (shown, predicted, viterbi, streamed):
            assert done.returncode == 0, f"{install}: {done.stderr}"
        outputs[install] = (shown.stdout, predicted.stdout, viterbi.stdout, streamed.stdout, streamed.stderr,
                            pl.read_parquet(folder / "p.parquet"), pl.read_parquet(folder / "v.parquet"))
    base, whole = outputs["base"], outputs["whole"]
    assert base[:5] == whole[:5]
    assert base[5].equals(whole[5]) and base[6].equals(whole[6])
    assert base[5].height == RECORDED == len(base[3].splitlines())
    assert base[5]["class"].n_unique() > 1 and not base[5]["class"].equals(base[6]["class"])  # filter vs viterbi
    assert "macro F1 (segments)" in base[1] and "S1 approach peg" in base[0]


def test_explain_on_the_base_install_equals_the_whole_install(installed, light, model, desk_test_recording, tmp_path):
    recording = tmp_path / "head.csv"
    recording.write_text("".join(desk_test_recording.read_text().splitlines(keepends=True)[:RECORDED + 1]))
    outputs = {}
    for install, deps in (("base", light), ("whole", installed["deps"])):
        found = [mlnseq(installed, "explain", model, "--source", recording, *args, deps=deps)
                 for args in (("--frame", "1000", "--json"), ("--segment", "3"),
                              ("--frame", "1000", "--what-if", "left_gripper=closed"))]
        for done in found:
            assert done.returncode == 0, f"{install}: {done.stderr}"
        outputs[install] = [done.stdout for done in found]
    assert outputs["base"] == outputs["whole"]
    terms = json.loads(outputs["base"][0])["terms"]
    assert {"formula", "network", "past"} <= {term["kind"] for term in terms}
    assert "held by" in outputs["base"][1] and "what if left_gripper=closed?" in outputs["base"][2]


@pytest.mark.parametrize(("args", "extra", "library"), [
    (("learn-weights",), "train", "scipy"),
    (("train", "--epochs", "1"), "train", "torch"),
    (("collect", "--env", "fetch", "--episodes", "1"), "sim", "gymnasium-robotics"),
])
def test_a_command_that_needs_an_extra_names_it_in_one_line(installed, light, desk_stream_workdir, tmp_path,
                                                           args, extra, library):
    for name in ("frames.parquet", "predicates.parquet", "formulas.mln", "weights.parquet"):
        shutil.copy(desk_stream_workdir / name, tmp_path / name)
    before = sorted(path.name for path in tmp_path.iterdir())
    done = mlnseq(installed, *args, "-w", tmp_path / ("fetch" if args[0] == "collect" else ""), deps=light)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"error: {'simulating Fetch' if extra == 'sim' else 'training'} needs {library}, which is not installed: "
        f"pip install '.[{extra}]' in mlnseq's checkout, or pip install 'mlnseq-0.1.0-py3-none-any.whl[{extra}]' "
        "beside the wheel"]
    assert sorted(path.name for path in tmp_path.iterdir()) == before


def test_a_rerun_recording_on_the_base_install_names_the_recordings_extra(installed, light, model,
                                                                         desk_test_recording, tmp_path):
    done = mlnseq(installed, "predict", model, "--source", desk_test_recording, "-o", "p.parquet", "--rerun",
                  "p.rrd", deps=light, cwd=tmp_path)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        "error: writing a Rerun recording needs rerun-sdk, which is not installed: pip install '.[recordings]' in "
        "mlnseq's checkout, or pip install 'mlnseq-0.1.0-py3-none-any.whl[recordings]' beside the wheel"]
    assert not (tmp_path / "p.rrd").exists()


def test_review_serves_its_page_on_the_base_install(installed, light, model, desk_test_recording, tmp_path):
    import signal
    import urllib.request

    recording = tmp_path / "head.csv"
    recording.write_text("".join(desk_test_recording.read_text().splitlines(keepends=True)[:RECORDED + 1]))
    env = {**os.environ, "PYTHONPATH": f"{installed['target']}{os.pathsep}{light}"}
    process = subprocess.Popen([sys.executable, "-S", "-m", "mlnseq_cli.main", "review", str(model), "--source",
                                str(recording), "--port", "0", "--save", str(tmp_path / "labels.csv")], cwd=tmp_path,
                               env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = process.stdout.readline()
        assert " at http://127.0.0.1:" in line, (line, process.stderr.read() if process.poll() is not None else "")
        url = line.split(" at ")[1].split()[0]
        pages = {path: urllib.request.urlopen(url + path, timeout=30).read() for path in
                 ("", "uPlot.iife.min.js", "api/recordings", "api/explain?index=0&frame=1000")}
    finally:
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=30)
    assert process.returncode == 0, err
    assert b"/uPlot.iife.min.js" in pages[""] and len(pages["uPlot.iife.min.js"]) > 40_000
    assert json.loads(pages["api/recordings"])["recordings"][0]["frames"] == RECORDED
    assert json.loads(pages["api/explain?index=0&frame=1000"])["frame"] == 1000
