"""`make report` (what `make reproduce` runs after set-up, through its stage server), reduced by its size variables,
end to end.

Tiny Fetch collection, the real DESK files, 1 seed, 2 epochs, 2 data-efficiency fractions, the sequential
logic's folders (decoded rows and ablation), into a temporary RUNS and REPORTS; then the Make dependency
behaviour: nothing to do on a second run, and a touched predicate spec or temporal formulas file reruns
only what depends on it.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from mlnseq import conflate
from mlnseq.catalog import artifacts, methods
from mlnseq.reporting import loading

pytestmark = [pytest.mark.slow, pytest.mark.mujoco]

REPORT_SECTIONS = (
    "## Table III", "### Do the paper's claims hold here?", "## Table IV", "## Fig. 7", "## Fig. 8",
    "## Confusion matrices", "## Data efficiency", "## Learned weights", "## Fetch: richer predicate spec",
    "## Stream mode", "## Sequential logic: decoded methods", "## Ablation", "## Timeline of one test episode",
    "## Which decoded method to deploy", "### Targets (stream mode", "## Timings and machine",
    "## Hyper-parameters used", "## Differences from the paper",
)
SEQUENTIAL_FOLDERS = {f"{d}-{v}" for d in ("fetch", "desk") for v in ("temporal", "order", "conjunctive", "fixed-weight")}


@pytest.fixture(scope="module")
def reduced(tmp_path_factory, repo_root, shared_data) -> dict[str, Path | list[str]]:
    """Run the reduced reproduction once; returns its folders and the make command line."""
    if shutil.which("make") is None:
        pytest.skip("make is not installed")
    root = tmp_path_factory.mktemp("reproduce")
    specs = {}
    for name in ("fetch-rich.binarize.toml", "temporal.mln"):  # copies, so touching one leaves examples/ alone
        specs[name] = root / name
        shutil.copy(repo_root / "examples" / name, specs[name])
    command = [
        "make", "--no-print-directory", "-C", str(repo_root), f"RUNS={root / 'runs'}", f"REPORTS={root / 'reports'}",
        *page_sizes(repo_root), f"DESK_DIR={shared_data / 'desk-taurus'}",
        f"FETCH_RICH_SPEC={specs['fetch-rich.binarize.toml']}", f"TEMPORAL_SPEC={specs['temporal.mln']}",
    ]
    with stage_server(root / ".stage-server.sock", repo_root) as server:  # as `make reproduce` runs the stages
        first = make(command, "-j2", "-Otarget", "report", env={"MLNSEQ_STAGE_SERVER": str(server)})
    return {"root": root, "command": command, "rich_spec": specs["fetch-rich.binarize.toml"],
            "temporal_spec": specs["temporal.mln"], "first": first}


@contextlib.contextmanager
def stage_server(socket: Path, repo_root: Path) -> Iterator[Path]:
    """scripts/stage_server.py serving on ``socket`` while inside: the stages skip their imports' start-up (the same
    artifacts as a process each: tests/test_stage_server.py)."""
    server = subprocess.Popen([sys.executable, str(repo_root / "scripts" / "stage_server.py"), "serve", str(socket)])
    try:
        for _ in range(300):
            if socket.exists() or server.poll() is not None:
                break
            time.sleep(0.1)
        assert socket.exists(), "the stage server did not start"
        yield socket
    finally:
        server.terminate()
        server.wait(timeout=60)


def page_sizes(repo_root: Path) -> list[str]:
    """The size variables of docs/reproduce.md's tiny run, as the page writes them (the docs test leaves that
    block to this test)."""
    block = re.search(r"```bash\n(make report .*?)\n```", (repo_root / "docs" / "reproduce.md").read_text(), re.S)
    sizes = [word for word in shlex.split(block.group(1))[2:] if not word.startswith(("RUNS=", "REPORTS="))]
    assert [word.split("=")[0] for word in sizes] == ["SEEDS", "EPOCHS", "DESK_EPOCHS", "FETCH_EPISODES", "FRACTIONS"]
    return sizes


def make(command: list, *args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    result = subprocess.run([*command, *args], capture_output=True, text=True,
                            env={**os.environ, "MAKEFLAGS": "", **(env or {})})
    assert result.returncode in (0, 1), result.stdout + result.stderr  # -q answers 1 for "work to do"
    return result


def test_the_report_has_every_section_and_figure(reduced):
    reports = reduced["root"] / "reports"
    assert reduced["first"].returncode == 0, reduced["first"].stdout + reduced["first"].stderr
    text = (reports / "REPORT.md").read_text()
    for section in REPORT_SECTIONS:
        assert section in text, section
    figures = ["fig7_test_accuracy.png", "fig8_train_vs_test.png", "data_efficiency.png",
               "confusion_fetch.png", "confusion_desk.png", "timeline_fetch.png", "timeline_desk.png"]
    for name in figures:
        assert f"]({name})" in text
        assert (reports / name).read_bytes()[:4] == b"\x89PNG", name
    assert "**Not run:**" not in text
    assert set(loading.load_run(reduced["root"] / "runs").datasets) == {
        "fetch", "desk", "fetch-rich", "fetch-fraction-0.25", "fetch-fraction-0.5", *SEQUENTIAL_FOLDERS,
        "fetch-tcn", "desk-tcn"}
    for dataset in ("fetch", "desk"):  # the causal TCN's stream rows beside the LSTM's
        assert f"| {dataset}-tcn | TCN + PriorLayer |" in text
    for dataset in ("fetch", "desk"):
        assert f"- {dataset}: deploy **" in text and f"- {dataset}, online choice (" in text
    summary = json.loads((reports / "summary.json").read_text())
    assert set(summary) == {"fetch", "desk"}
    assert all({"online", "offline", "lstm"} <= set(s) <= {"online", "offline", "lstm", "live"} for s in summary.values())
    assert all(s["online"]["lag_frames"] == 0 for s in summary.values() if "lag_frames" in s["online"])


def test_the_sequential_folders_reuse_the_paper_datasets_frames_and_networks(reduced):
    runs = reduced["root"] / "runs"
    for dataset in ("fetch", "desk"):
        for variant in ("temporal", "order"):
            for name in ("frames.parquet", "predicates.parquet"):
                assert (runs / f"{dataset}-{variant}" / name).resolve() == (runs / dataset / name).resolve()
        for mode in ("segment", "stream"):
            lstm = runs / f"{dataset}-temporal" / mode / "seed-0" / "models" / "lstm.pt"
            assert lstm.is_symlink() and lstm.resolve() == (runs / dataset / mode / "seed-0/models/lstm.pt").resolve()
        stream = runs / f"{dataset}-temporal" / "stream" / "seed-0" / "models"
        assert not (stream / "priorlayer.pt").is_symlink()  # trained on the temporal weights
        assert not (runs / f"{dataset}-temporal" / "segment" / "seed-0" / "models" / "priorlayer.pt").exists()
        assert not (runs / f"{dataset}-order" / "stream" / "seed-0" / "models" / "priorlayer.pt").exists()
        fixed = runs / f"{dataset}-fixed-weight" / "stream" / "seed-0"
        assert (fixed / "models" / "lstm.pt").resolve() == (stream / "lstm.pt").resolve()
        meta = artifacts.read_metadata(fixed / artifacts.PREDICTIONS)
        assert meta["network_weight_option"] == 1.0 and meta["network_weights"] == {}
        every = conflate.ConflateOptions(decode=conflate.parse_decode("all")).decodes  # each decoder at each lag
        assert meta["methods"] == [methods.decoded_name(m, d) for d in every for m in ("lstm", "mln", "conflation")]
        paper = artifacts.read_metadata(runs / dataset / "stream" / "seed-0" / artifacts.PREDICTIONS)
        assert "conflation+filter" in paper["methods"] and paper["cross_validation"]["folds"]["k"] == 5
        assert set(paper["cross_validation"]["figures"]) == set(paper["methods"])
        assert paper["network_weights"]["conflation+viterbi"]["how"] == "learned"
        assert artifacts.read_metadata(runs / dataset / "segment" / "seed-0" / artifacts.PREDICTIONS)["methods"] == [
            "lstm", "mln", "priorlayer", "conflation", "combined"]
        tcn = runs / f"{dataset}-tcn"
        assert (tcn / "weights.parquet").resolve() == (runs / f"{dataset}-temporal" / "weights.parquet").resolve()
        tcn_meta = artifacts.read_metadata(tcn / "stream" / "seed-0" / artifacts.PREDICTIONS)
        assert "conflation+filter" in tcn_meta["methods"] and tcn_meta["cross_validation"]["folds"]["k"] == 5
        assert not (tcn / "segment").exists()
        for method in ("lstm", "priorlayer"):
            assert torch.load(tcn / "stream/seed-0/models" / f"{method}.pt", weights_only=True)["config"]["model"][
                "cell"] == "tcn"


def test_every_stage_prints_one_timed_summary(reduced):
    lines = [line for line in reduced["first"].stdout.splitlines() if ": wrote " in line]
    assert lines and all(line.rstrip().endswith(" s]") for line in lines)
    assert any(line.startswith("report: wrote") for line in lines)


def test_a_second_run_does_no_work(reduced):
    timings = reduced["root"] / "runs" / loading.TIMINGS
    before = timings.read_text()
    assert make(reduced["command"], "-q", str(reduced["root"] / "reports" / "REPORT.md")).returncode == 0
    again = make(reduced["command"], "-j2", "report")
    assert again.returncode == 0 and ": wrote " not in again.stdout
    assert timings.read_text() == before


def planned_after_touching(reduced, spec: Path) -> str:
    """What `make -n report` would run once ``spec`` is newer than everything (its time restored after)."""
    before = spec.stat()
    os.utime(spec)
    try:
        return make(reduced["command"], "-n", "report").stdout
    finally:
        os.utime(spec, ns=(before.st_atime_ns, before.st_mtime_ns))


def test_a_touched_spec_reruns_only_what_depends_on_it(reduced):
    planned = planned_after_touching(reduced, reduced["rich_spec"])
    runs = reduced["root"] / "runs"
    stages = [line.split("/mlnseq ", 1)[1] for line in planned.splitlines() if "timed_stage.sh" in line]
    assert len(stages) == 7, planned  # binarize, formulas, learn-weights, train priorlayer, conflate, eval, report
    assert all(f"{runs}/fetch-rich" in s or s.startswith("report") for s in stages), planned
    assert not any("--method lstm" in s or s.startswith("collect") for s in stages), planned


def test_a_touched_temporal_spec_reruns_only_the_sequential_folders(reduced):
    planned = planned_after_touching(reduced, reduced["temporal_spec"])
    stages = [line.split("/mlnseq ", 1)[1] for line in planned.splitlines() if "timed_stage.sh" in line]
    touched = ("-temporal", "-fixed-weight", "-tcn")  # D-tcn decodes with D-temporal's weights
    assert all(any(t in s for t in touched) or s.startswith("report") for s in stages), planned
    assert not any("--method lstm" in s or "-order" in s for s in stages), planned
    # per dataset: formulas, learn-weights, priorlayer (stream), conflate and eval of 3 workdirs, the TCN's
    # priorlayer, conflate and eval; then report
    assert len(stages) == 2 * (2 + 1 + 3 + 3 + 3) + 1, planned


def test_without_desk_the_fetch_half_still_runs(reduced, tmp_path):
    planned = make(reduced["command"], "-n", f"DESK_DIR={tmp_path / 'absent'}", "report").stdout
    assert "DESK Taurus files not found" in planned
    assert "/desk/" not in planned
