"""The tiny sweep (2 cells x 2 seeds, 1 epoch, tiny DESK) run locally through Snakemake: interrupted and resumed, a
job killed (its config failed alone, the rerun redoing only it), its table read back against the artifacts, its winner
deployed, a rerun that does nothing, and a stale file redone."""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

import polars as pl
import pyarrow.parquet as pq

from sweep_files import mlnseq

FIGURES = ("segment_accuracy", "frame_accuracy", "edit")


def metadata(path: Path) -> dict:
    return json.loads(pq.read_schema(path).metadata[b"mlnseq"])


def test_an_interrupted_sweep_resumes_without_redoing_finished_trainings(local_sweep):
    assert local_sweep["interrupted"] == 130, local_sweep["interrupted_stderr"][-2000:]
    assert local_sweep["finished_before"], "no network was trained before the interruption"
    result = local_sweep["result"]
    assert result.returncode == 0, result.stderr[-3000:]
    for model, mtime in local_sweep["finished_before"].items():
        assert model.stat().st_mtime_ns == mtime, f"{model} was trained again"
    assert not list(local_sweep["out"].glob(".snakemake/locks/*"))


def test_the_table_holds_each_configs_cross_validated_figures_over_seeds(local_sweep):
    out = local_sweep["out"]
    table = pl.read_parquet(out / "results.parquet")
    assert table["config"].to_list() == ["cell-lstm", "cell-tcn"] and table["cell"].to_list() == ["lstm", "tcn"]
    assert table["epochs"].to_list() == [1, 1] and table["seeds"].to_list() == [2, 2]
    for figure in FIGURES:
        assert {f"cv_{figure}", f"cv_{figure}_std", f"test_{figure}"} <= set(table.columns)
    for row in table.iter_rows(named=True):
        chosen, cv, test = [], {f: [] for f in FIGURES}, {f: [] for f in FIGURES}
        for seed in (0, 1):
            workdir = out / "runs" / row["config"] / f"seed-{seed}"
            figures = metadata(workdir / "predictions.parquet")["cross_validation"]["figures"]
            online = {name: f for name, f in figures.items() if name.endswith("+filter")}
            # export --method auto --decode filter: the best mean of segment accuracy, frame accuracy and edit
            name = max(online, key=lambda n: sum(online[n][f] for f in ("segment_accuracy", "frame_accuracy", "edit")))
            chosen.append(name)
            metrics = pl.read_parquet(workdir / "metrics.parquet").filter(pl.col("method") == name)
            for figure in FIGURES:
                cv[figure].append(online[name][figure])
                value = metrics.filter(pl.col("metric") == figure)["value"][0]
                test[figure].append(value if figure == "edit" else 100 * value)
            assert (workdir / "frames.parquet").resolve() == (Path(json.loads(
                (out / "sweep.json").read_text())["shared"]) / "frames.parquet").resolve()
        assert row["method"] == ", ".join(sorted(set(chosen)))
        for figure in FIGURES:
            assert abs(row[f"cv_{figure}"] - sum(cv[figure]) / 2) < 1e-9
            assert abs(row[f"cv_{figure}_std"] - abs(cv[figure][0] - cv[figure][1]) / 2 ** 0.5) < 1e-9
            assert abs(row[f"test_{figure}"] - sum(test[figure]) / 2) < 1e-9
            assert abs(row[f"test_{figure}_std"] - abs(test[figure][0] - test[figure][1]) / 2 ** 0.5) < 1e-9
            assert 0 <= row[f"cv_{figure}"] <= 100


def test_the_last_line_names_the_best_config_and_its_export_command_deploys_it(local_sweep, tmp_path):
    table = pl.read_parquet(local_sweep["out"] / "results.parquet")
    lines = local_sweep["result"].stdout.strip().splitlines()
    best = max(range(2), key=lambda i: (table["cv_segment_accuracy"][i], -i))  # online: segment accuracy
    assert lines[-1].startswith(f"best by cross-validation: {table['config'][best]} (")
    command = lines[-1].split("deploy it: ", 1)[1]
    assert command == table["deploy"][best]
    args = shlex.split(command)
    assert args[:2] == ["mlnseq", "export"]
    model = tmp_path / "best.mlnseq"
    deployed = mlnseq(*args[1:], "--output", str(model), cwd=tmp_path)
    assert deployed.returncode == 0, deployed.stderr
    assert model.stat().st_size > 0
    assert {lines[2].split()[0], lines[3].split()[0]} == {"cell-lstm", "cell-tcn"}  # the summary's rows


def test_a_rerun_does_nothing_and_a_stale_file_is_redone_alone(local_sweep):
    out, path = local_sweep["out"], local_sweep["path"]
    before = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/seed-*/**/*.p*") if p.is_file()}
    table = pl.read_parquet(out / "results.parquet")
    again = mlnseq("sweep", str(path), "--cores", "2", cwd=local_sweep["folder"])
    assert again.returncode == 0 and "Nothing to be done" in (out / "sweep.log").read_text(), again.stderr[-2000:]
    assert {p: p.stat().st_mtime_ns for p in before} == before
    assert pl.read_parquet(out / "results.parquet").equals(table)
    stale = out / "runs" / "cell-tcn" / "seed-1" / "metrics.parquet"
    stale.unlink()
    redone = mlnseq("sweep", str(path), "--cores", "2", cwd=local_sweep["folder"])
    assert redone.returncode == 0, redone.stderr[-2000:]
    log = (out / "sweep.log").read_text()
    assert "rule eval:" in log and "rule train:" not in log and "rule conflate:" not in log
    assert stale.exists() and pl.read_parquet(out / "results.parquet").equals(table)
    print(f"resumed sweep: {local_sweep['seconds']:.1f} s", file=sys.stderr)


def test_a_formulas_file_of_the_grid_is_learned_with_the_datasets_folds(tmp_path, tiny_desk_workdir, repo_root):
    """formulas = [temporal.mln]: the file is written and its weights learned with the dataset's 3 folds in
    OUT/formulas/temporal, and the config's workdir links those weights: the same as the dataset's own, which
    were learned from temporal.mln with 3 folds."""
    from sweep_files import write_sweep

    path = write_sweep(tmp_path, tiny_desk_workdir, f'formulas = ["{repo_root}/examples/temporal.mln"]\nepochs = [1]\n',
                       seeds="[0]")
    done = mlnseq("sweep", str(path), "--cores", "2", cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    out, learned = tmp_path / "sweep", tmp_path / "sweep" / "formulas" / "temporal"
    assert pl.read_parquet(out / "results.parquet")["formulas"].to_list() == [f"{repo_root}/examples/temporal.mln"]
    assert metadata(learned / "weights.folds.parquet")["folds"]["k"] == 3
    for name in ("weights.parquet", "weights.folds.parquet"):
        assert (out / "runs" / "default" / "seed-0" / name).resolve() == (learned / name).resolve()
        assert pl.read_parquet(learned / name).equals(pl.read_parquet(tiny_desk_workdir / name))


def test_a_killed_job_fails_its_config_alone_in_one_line_and_the_rerun_redoes_only_it(local_sweep):
    """SIGKILL to one of cell-tcn's train or conflate jobs: cell-lstm finishes (--keep-going), results.parquet holds it
    and cell-tcn marked failed without figures, the terminal shows progress and one error line naming the config, the
    job and its log, Snakemake's output is in OUT/sweep.log alone; the next run redoes cell-tcn's jobs only."""
    import re

    out, killed = local_sweep["out"], local_sweep["killed"]
    assert killed["code"] == 1, killed["stderr"][-3000:]
    stage, seed = re.search(r"mlnseq (train|conflate) .*--workdir runs/cell-tcn/seed-(\d)", killed["job"]).groups()
    errors = [line for line in killed["stderr"].splitlines() if line.startswith("error: config")]
    log = out / "runs" / "cell-tcn" / f"seed-{seed}" / "logs" / ("train-lstm.log" if stage == "train" else "conflate.log")
    assert errors == [f"error: config cell-tcn failed: {stage} of seed {seed} was killed (SIGKILL); its log: {log}"]
    assert all(line.startswith(("sweep: ", "error: ", "    | ")) for line in killed["stderr"].splitlines())
    assert "sweep: 1 of 2 configs done, 1 failed" in killed["stderr"] and "Error in rule" in killed["log"]
    table = killed["table"]
    assert table["config"].to_list() == ["cell-lstm", "cell-tcn"] and table["status"].to_list() == ["done", "failed"]
    assert table["failure"][1] == errors[0].removeprefix("error: ") and table["failure"][0] is None
    assert table["cv_score"][1] is None and table["cv_score"][0] > 0 and table["deploy"][1] is None
    final = pl.read_parquet(out / "results.parquet")
    assert final["status"].to_list() == ["done", "done"] and final.row(0) == table.row(0)
    assert killed["stdout"].strip().splitlines()[-1].startswith("best by cross-validation: cell-lstm (")
    reran = re.findall(r"wildcards: config=([\w-]+)", local_sweep["log"])
    assert reran and set(reran) == {"cell-tcn"}, reran
    for path, mtime in killed["files"].items():
        if "cell-lstm" in path.parts:
            assert path.stat().st_mtime_ns == mtime, f"{path} was made again"


def test_the_summary_shows_the_score_it_ranks_by_and_the_last_progress_line_counts_every_job(local_sweep):
    """The rows sorted by the `cv score` column they show (the mean of the three cross-validated figures); the last
    progress line's jobs are the log's last count (it said 11 of 13 where the log said 13 of 13)."""
    import re

    table = pl.read_parquet(local_sweep["out"] / "results.parquet")
    lines = local_sweep["result"].stdout.strip().splitlines()
    header = lines[1].split("  ")
    assert [h.strip() for h in header if h.strip()][:3] == ["config", "method", "cv score"]
    column = lines[1].index("cv score")
    scores = [float(line[column:].split()[0]) for line in lines[2:4]]
    assert scores == sorted(scores, reverse=True)
    by_config = {c: s for c, s in zip(table["config"], table["cv_score"])}
    assert all(abs(by_config[line.split()[0]] - score) < 0.006 for line, score in zip(lines[2:4], scores))
    progress = [line for line in local_sweep["result"].stderr.splitlines() if line.startswith("sweep: ")]
    steps = re.findall(r"^(\d+) of (\d+) steps", local_sweep["log"], re.M)
    said = re.search(r"\((\d+) of (\d+) jobs\)", progress[-1])
    if steps:  # this run had jobs to do
        assert said is not None and said.groups() == steps[-1], (progress, steps)
