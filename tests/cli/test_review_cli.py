"""`mlnseq review` on three held-out trials of the own-data robot (examples/own-data: an MLN filter model, the
session's own_data_glitch fixture) served as a process and driven in Debian's headless chromium: the page shows
every recording and phase with no console error, a boundary moved by the keyboard and another dragged by the mouse
are saved as the intervals `collect --labels` reads back, a click shows the terms `explain --json` prints for that
frame; and the door stays shut: another site's Origin, another Host, a path outside the page, an oversized body
are refused; bad input is one line."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from review_browser import browser, opened, request, served, until

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[2]
TRIALS = (9, 10, 11)  # the last three trials; 11 holds the glitch of own_data_glitch (a restarted chain)
CLASSES = ["approach", "grasp", "lift", "release"]
FIGURE = REPO / "docs" / "figures" / "review.png"  # made by `make docs-figures`


@pytest.fixture(scope="module")
def trials(own_data_glitch, tmp_path_factory) -> dict[str, Path]:
    """The three trials as a CSV of their own (trial, t, channels, phase), and the model."""
    folder = tmp_path_factory.mktemp("review")
    csv = folder / "heldout.csv"
    pl.read_csv(own_data_glitch["csv"]).filter(pl.col("trial").is_in(TRIALS)).write_csv(csv)
    return {"csv": csv, "model": own_data_glitch["model"], "folder": folder}


def mlnseq(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "mlnseq_cli.main", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


def phase_runs(csv: Path, trial: int) -> list[list[int]]:
    """A trial's true phases as [first frame, last frame, class index] runs."""
    phases = pl.read_csv(csv).filter(pl.col("trial") == trial)["phase"].to_list()
    runs, start = [], 0
    for t in range(1, len(phases) + 1):
        if t == len(phases) or phases[t] != phases[start]:
            runs.append([start, t - 1, CLASSES.index(phases[start])])
            start = t
    return runs


@pytest.mark.usefixtures("needs_browser")
def test_the_page_shows_every_recording_and_phase_and_draws_the_channels(trials, tmp_path):
    with served(trials["model"], "--source", trials["csv"], "--save", tmp_path / "labels.csv") as (url, printed):
        assert "3 recordings" in printed[0] and url.startswith("http://127.0.0.1:")
        with browser() as page:
            assert opened(page, url) < 10
            ids = page.eval_on_selector_all("#recordings tbody tr", "rows => rows.map(r => r.cells[1].textContent)")
            assert sorted(ids) == sorted(map(str, TRIALS))
            assert all(name in page.inner_text("#legend") for name in CLASSES)
            for trial in TRIALS:
                show(page, trial)
                drawn = page.evaluate("window.review.plots.map(u => [u.data[0].length, u.ctx.canvas.width])")
                assert len(drawn) == 4 and all(points > 50 and width > 300 for points, width in drawn), drawn
                painted = page.evaluate("""(() => { const c = document.querySelector('.channel canvas');
                    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
                    let n = 0; for (let i = 3; i < d.length; i += 4) n += d[i] > 0; return n; })()""")
                assert painted > 1000  # the first channel's line and axes are on the canvas
                shown = {CLASSES[k] for _, _, k in page.evaluate("window.review.data.phases")}
                assert shown <= set(CLASSES) and len(shown) >= 2
            assert page.errors == []


def show(page, trial: int) -> None:
    """Open a recording by a click on its row of the table."""
    page.click(f"#recordings tr:has(td:text-is('{trial}'))")
    until(page, f"window.review.data && window.review.data.id === '{trial}' && window.review.drawnMs")


def drag(page, boundary: int, frame: int) -> None:
    """Drag a boundary of the labels band with the mouse to the start of ``frame``."""
    box = page.locator("#bands").bounding_box()
    start = page.evaluate(f"xOf(window.review.edit[{boundary}][1] + 1)")
    to = page.evaluate(f"xOf({frame})")
    y = box["y"] + 48  # the labels row
    page.mouse.move(box["x"] + start, y)
    page.mouse.down()
    page.mouse.move(box["x"] + (start + to) / 2, y, steps=3)
    page.mouse.move(box["x"] + to, y, steps=3)
    page.mouse.up()


@pytest.mark.usefixtures("needs_browser")
def test_boundaries_moved_by_keyboard_and_mouse_are_saved_and_read_back_by_collect(trials, tmp_path):
    saved = tmp_path / "labels.csv"
    runs = phase_runs(trials["csv"], TRIALS[0])
    expected = [list(r) for r in runs]
    expected[0][1] += 3  # the first boundary: three frames later (the keyboard)
    expected[1][0] += 3
    target = expected[2][0] - 4  # the second boundary: four frames earlier (the mouse)
    expected[1][1], expected[2][0] = target - 1, target
    with served(trials["model"], "--source", trials["csv"], "--save", saved, stop=signal.SIGINT) as (url, _):
        with browser() as page:
            opened(page, url)
            show(page, TRIALS[0])
            assert page.evaluate("window.review.edit") == runs  # the true labels, to be corrected
            page.focus("#bands")
            page.keyboard.press("]")
            for _ in range(3):
                page.keyboard.press("ArrowRight")
            page.keyboard.press("ArrowRight")
            page.keyboard.press("z")  # undo the fourth step
            drag(page, 1, target)
            assert page.evaluate("window.review.edit") == expected
            assert not saved.exists()  # nothing is written without a save
            page.keyboard.press("Control+s")
            until(page, "window.review.saved")
            for trial in TRIALS[1:]:  # the others saved as they are: collect --labels needs every recording
                show(page, trial)
                page.evaluate("window.review.saved = null")
                page.click("#save")
                until(page, "window.review.saved")
            assert page.errors == []
    table = pl.read_csv(saved, schema_overrides={"episode": pl.String})
    assert table.columns == ["episode", "start", "end", "label", "unit"]  # the file says its unit
    mine = table.filter(pl.col("episode") == str(TRIALS[0]))
    assert mine.rows() == [(str(TRIALS[0]), a, b, CLASSES[k], "frames") for a, b, k in expected]
    workdir = tmp_path / "work"
    done = mlnseq("collect", "--env", "table", "--source", trials["csv"], "--episode-column", "trial",
                  "--time-column", "t", "--labels", saved, "-w", workdir)
    assert done.returncode == 0, done.stderr
    frames = pl.read_parquet(workdir / "frames.parquet")
    names = artifacts.read_metadata(workdir / "frames.parquet", "frames")["classes"]
    first = frames.filter(pl.col("episode") == 0)["label"].to_numpy()
    wanted = np.concatenate([[CLASSES[k]] * (b - a + 1) for a, b, k in expected])
    assert [names[k] for k in first] == wanted.tolist()
    others = [phase_runs(trials["csv"], trial) for trial in TRIALS[1:]]
    assert frames.height == sum(b - a + 1 for runs_ in [expected, *others] for a, b, _ in runs_)


@pytest.mark.usefixtures("needs_browser")
def test_a_click_shows_the_terms_explain_json_prints_for_that_frame(trials, tmp_path):
    with served(trials["model"], "--source", trials["csv"], "--save", tmp_path / "labels.csv") as (url, _):
        with browser() as page:
            opened(page, url)
            show(page, TRIALS[2])
            over = page.locator(".channel .u-over").first.bounding_box()
            page.mouse.click(over["x"] + over["width"] * 0.55, over["y"] + over["height"] / 2)
            shown = until(page, "window.review.explained")
            text = page.inner_text("#explain")
            held = page.locator("#explain tr.holds").count()
            if os.environ.get("MLNSEQ_DOCS_FIGURES") == "write":
                FIGURE.parent.mkdir(exist_ok=True)
                page.screenshot(path=str(FIGURE))
            assert page.errors == []
    done = mlnseq("explain", trials["model"], "--source", trials["csv"], "--episode", str(TRIALS[2]), "--frame",
                  str(shown["frame"]), "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout) == shown
    assert all(term["text"] in text for term in shown["terms"])
    holding = [t for t in shown["terms"] if t["kind"] == "formula" and t.get("truth", [0])[0] > 0]
    assert held == len(holding) > 0  # the formulas that hold there, highlighted


def refused(*args: str | Path) -> str:
    """`mlnseq review ARGS`'s one line on stderr (it must end with exit 2, before serving)."""
    done = mlnseq("review", *args)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert done.stdout == "" and len(done.stderr.strip().splitlines()) == 1, done.stderr
    return done.stderr.strip()


def test_bad_input_is_one_line(trials, tmp_path):
    model, csv = trials["model"], trials["csv"]
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert f"--port {port}" in refused(model, "--source", csv, "--port", str(port), "--save", tmp_path / "a.csv")
    unfit = tmp_path / "unfit.csv"
    pl.read_csv(csv).drop("wrist_force").write_csv(unfit)
    assert "wrist_force" in refused(model, "--source", unfit, "--port", "0", "--save", tmp_path / "b.csv")
    folder = tmp_path / "recordings"
    folder.mkdir()
    (folder / "heldout.csv").write_bytes(csv.read_bytes())
    assert "inside the source" in refused(model, "--source", folder, "--port", "0", "--save", folder / "labels.csv")
    assert "inside the source" in refused(model, "--source", csv, "--port", "0", "--save", csv)
    assert "--source" in refused(model, "--port", "0")
    assert not (tmp_path / "a.csv").exists() and not (folder / "labels.csv").exists()


def test_a_fits_workdir_is_reviewed_in_the_order_its_label_next_csv_ranks(trials, tmp_path):
    workdir = tmp_path / "work"
    given = tmp_path / "given.csv"  # trial 9 from a labels file, the others by their own phase column
    given.write_text("\n".join(["episode,start,end,label", *(f"9,{a},{b},{CLASSES[k]}" for a, b, k in phase_runs(
        trials["csv"], 9))]) + "\n")
    done = mlnseq("collect", "--env", "table", "--source", trials["csv"], "--episode-column", "trial",
                  "--time-column", "t", "--label-column", "phase", "--labels", given, "-w", workdir)
    assert done.returncode == 0, done.stderr
    (workdir / "label_next.csv").write_text("episode,rank,reason\n11,1,the glitch\n9,2,unsure at the grasp\n")
    last = phase_runs(trials["csv"], 11)[-1][1]
    (workdir / "unlabelled.intervals.csv").write_text(f"episode,start,end,label,unit\n11,0,9,grasp,frames\n"
                                                      f"11,10,{last},lift,frames\n")
    with served(trials["model"], "-w", workdir, cwd=tmp_path) as (url, printed):
        assert f"saves go to {tmp_path / 'work.labels.csv'}" in printed[0]
        status, body = request(url, "GET", "/api/recordings", {})
        view = json.loads(request(url, "GET", "/api/recording?index=2", {})[1])
    rows = json.loads(body)["recordings"]
    assert status == 200 and [(r["id"], r["rank"]) for r in rows] == [("11", 1), ("9", 2), ("10", 3)]
    assert rows[0]["reason"] == "the glitch" and rows[2]["labelled"]
    assert [r["origin"] for r in rows] == ["its own", "the labels file's", "its own"]  # as fit would train on them
    assert view["id"] == "11" and view["proposal"] == [[0, 9, 1], [10, last, 2]]  # the band's start, to correct
    assert view["labels"] == phase_runs(trials["csv"], 11)


def click_band(page, frame: int) -> None:
    """A click on the labels band at the middle of ``frame``."""
    box = page.locator("#bands").bounding_box()
    x = page.evaluate(f"(xOf({frame}) + xOf({frame} + 1)) / 2")
    page.mouse.click(box["x"] + x, box["y"] + 48)


@pytest.mark.usefixtures("needs_browser")
def test_a_segment_relabelled_split_and_merged_with_undo_is_saved_as_shown(trials, tmp_path):
    saved = tmp_path / "labels.csv"
    trial = TRIALS[1]
    (_, before, _), (a, b, _), (_, c, _), (d, e, _) = phase_runs(trials["csv"], trial)
    split = a + 4
    with served(trials["model"], "--source", trials["csv"], "--save", saved) as (url, _):
        with browser() as page:
            opened(page, url)
            show(page, trial)
            click_band(page, (a + b) // 2)
            assert page.evaluate("window.review.segment") == 1
            page.keyboard.press("3")  # grasp -> lift
            over = page.locator(".channel .u-over").first.bounding_box()
            x = page.evaluate(f"window.review.plots[1].valToPos(window.review.data.time[{split}], 'x')")
            page.mouse.click(over["x"] + x, over["y"] + over["height"] / 2)  # explain a frame: the split's place
            assert until(page, "window.review.explained")["frame"] == split
            click_band(page, (a + b) // 2)
            page.keyboard.press("s")
            click_band(page, a + 2)
            page.keyboard.press("2")  # its first part: grasp again
            click_band(page, (split + b) // 2)
            page.keyboard.press("m")  # the rest merged with the lift after it
            page.keyboard.press("z")
            assert len(page.evaluate("window.review.edit")) == 5  # the merge undone
            page.keyboard.press("m")
            assert page.evaluate("window.review.edit") == [[0, before, 0], [a, split - 1, 1], [split, c, 2],
                                                           [d, e, 3]]
            page.click("#save")
            until(page, "window.review.saved")
            assert page.errors == []
    assert pl.read_csv(saved).drop("unit").rows() == [(trial, 0, before, "approach"), (trial, a, split - 1, "grasp"),
                                                      (trial, split, c, "lift"), (trial, d, e, "release")]


@pytest.fixture(scope="module")
def lerobot_model(shared_data, tmp_path_factory) -> dict[str, Path]:
    """An MLN filter model of LeRobot 0.6.1's annotated pick-place dataset (its own subtask annotations as labels,
    predicates and formulas learned by binarize --suggest; no network): it remembers reading the annotations."""
    from mlnseq import binarize, collect, export, formulas, learn_weights
    from mlnseq.sources import SourceOptions

    source = shared_data / "lerobot-0.6.1" / "pick-place-annotated"
    workdir = tmp_path_factory.mktemp("lerobot") / "work"
    collect.run(workdir, collect.CollectOptions(env="lerobot", source=source,
                                                recordings=SourceOptions(annotations="subtask")))
    binarize.run(workdir, binarize.BinarizeOptions(suggest=workdir / "learned.binarize.toml"))
    formulas.run(workdir, formulas.FormulasOptions())
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
    model = export.run(workdir, export.ExportOptions(method="mln", decode="filter",
                                                     output=workdir.parent / "arm.mlnseq")).path
    return {"model": model, "source": source}


def subtasks(dataset: Path) -> tuple[pl.DataFrame, list[str]]:
    from mlnseq import collect
    from mlnseq.sources import SourceOptions

    collected = collect.collect(collect.CollectOptions(env="lerobot", source=dataset,
                                                       recordings=SourceOptions(annotations="subtask")))
    return collected.frames, collected.meta["classes"]


def test_a_lerobot_source_saved_is_also_its_subtask_annotations_in_a_copy(lerobot_model, tmp_path):
    import hashlib

    source, out = lerobot_model["source"], tmp_path / "annotated"
    before = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(source.rglob("*")) if p.is_file()}
    with served(lerobot_model["model"], "--source", source, "--save", tmp_path / "labels.csv", "--save-lerobot",
                out) as (url, _):
        rows = json.loads(request(url, "GET", "/api/recordings", {})[1])["recordings"]
        index = next(r["index"] for r in rows if r["id"] == "0")
        view = json.loads(request(url, "GET", f"/api/recording?index={index}", {})[1])
        edit = [list(run) for run in view["labels"]]
        edit[0][1] += 5  # the first boundary five frames later
        edit[1][0] += 5
        body = json.dumps({"index": index, "segments": [[a, b, view["classes"][k]] for a, b, k in edit]}).encode()
        status, answer = request(url, "POST", "/api/save", {"Content-Type": "application/json",
                                                            "Content-Length": str(len(body))}, body)
        assert status == 200 and json.loads(answer)["lerobot"] == str(out)
    frames, classes = subtasks(out)
    own, own_classes = subtasks(source)
    assert classes == own_classes == view["classes"]
    first = frames.filter(pl.col("episode") == 0)["label"].to_list()
    assert first == [k for a, b, k in edit for _ in range(a, b + 1)]
    assert frames.filter(pl.col("episode") != 0).equals(own.filter(pl.col("episode") != 0))  # their own kept
    assert first != own.filter(pl.col("episode") == 0)["label"].to_list()
    after = {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(source.rglob("*")) if p.is_file()}
    assert after == before  # the source is only read


def test_save_lerobot_needs_a_lerobot_source_and_a_folder_outside_it(trials, lerobot_model, tmp_path):
    assert "--save-lerobot writes LeRobot datasets" in refused(
        trials["model"], "--source", trials["csv"], "--port", "0", "--save", tmp_path / "a.csv", "--save-lerobot",
        tmp_path / "out")
    source = lerobot_model["source"]
    assert "--save-lerobot" in refused(lerobot_model["model"], "--source", source, "--port", "0", "--save",
                                       tmp_path / "b.csv", "--save-lerobot", source / "copy")


def test_another_host_is_said_and_the_same_port_serves_again_at_once_after_a_stop(trials, tmp_path):
    """--host other than this machine's own says who else can open the page; after SIGTERM (with connections it
    answered and closed), the same port serves again at once."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    args = (trials["model"], "--source", trials["csv"], "--save", tmp_path / "labels.csv")
    with served(*args, port=port) as (url, printed):
        assert url == f"http://127.0.0.1:{port}/"
        for _ in range(3):
            assert request(url, "GET", "/api/recordings", {})[0] == 200
    assert not any("--host" in line for line in printed)  # this machine alone: nothing more to say
    with served(*args, port=port) as (url, _):  # at once: no "Address already in use" for a minute
        assert request(url, "GET", "/", {})[0] == 200
    with served(*args, "--host", "0.0.0.0") as (url, printed):
        assert request(url, "GET", "/", {})[0] == 200
    said = " ".join(" ".join(printed).split())  # every line it printed, the one after the address too
    assert "--host 0.0.0.0 listens beyond this machine: any machine that can reach this one at any of its" in said
    assert "--host 127.0.0.1 keeps it to this machine" in said


@pytest.mark.usefixtures("needs_browser")
def test_a_save_refused_names_save_says_so_in_the_terminal_and_the_row_says_not_saved(trials, tmp_path):
    folder = tmp_path / "labels"
    folder.mkdir()
    with served(trials["model"], "--source", trials["csv"], "--save", folder / "labels.csv") as (url, printed):
        folder.rmdir()
        folder.write_text("a file where the folder was: nothing can be written inside it\n")
        with browser() as page:
            opened(page, url)
            show(page, TRIALS[0])
            page.click("#save")
            until(page, "document.getElementById('status').textContent.startsWith('not saved')")
            status = page.inner_text("#status")
            row = page.eval_on_selector(f"#recordings tr:has(td:text-is('{TRIALS[0]}'))",
                                        "r => r.cells[5].textContent")
            assert row == "not saved" and page.evaluate("window.review.saved") is None
    assert f"--save {folder / 'labels.csv'}: not saved" in status and "start review again with --save" in status
    said = [line for line in printed if "not saved" in line]
    assert len(said) == 1 and said[0].startswith(f"review: {TRIALS[0]} not saved: --save {folder / 'labels.csv'}")
