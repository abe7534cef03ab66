"""Sibling commands take the same options (issue 55, item 4): a method or decoder name as any command prints it is
accepted wherever one is asked, explain reads a recording with predict's own source options, and train checks
--folds before any epoch. On the real DESK data."""

from __future__ import annotations

import shutil

import polars as pl
import pytest
from typer.testing import CliRunner

from mlnseq_cli.main import COMMANDS, _load, app
from mlnseq import train
from mlnseq.catalog import artifacts
from mlnseq.catalog.errors import BadInput
from mlnseq.recognition.recognizer import Recognizer

runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def lagged_workdir(tmp_path_factory, desk_stream_workdir):
    """desk_stream_workdir conflated again with `--decode smooth-legal@5` (the name conflate prints)."""
    workdir = tmp_path_factory.mktemp("lagged")
    for path in desk_stream_workdir.iterdir():
        (shutil.copytree if path.is_dir() else shutil.copy)(path, workdir / path.name)
    done = invoke("conflate", "--decode", "filter,smooth-legal@5", "-w", workdir)
    assert done.exit_code == 0, done.output
    return workdir


def test_train_refuses_folds_it_cannot_cut_before_any_epoch(desk_mln_workdir, tmp_path):
    shutil.copy(desk_mln_workdir / artifacts.FRAMES, tmp_path / artifacts.FRAMES)
    heard = []
    with pytest.raises(BadInput, match="--folds 99: .* allows at most"):
        train.run(tmp_path, train.TrainOptions(epochs=2, folds=99), progress=heard.append)
    assert heard == []  # no epoch trained
    assert not artifacts.checkpoint_path(tmp_path, "lstm").exists()


def test_conflate_takes_a_decoder_with_its_lag(lagged_workdir):
    methods = artifacts.read_metadata(lagged_workdir / artifacts.PREDICTIONS, "predictions")["methods"]
    assert "conflation+smooth-legal@5" in methods and not any("smooth-legal@25" in m for m in methods)


@pytest.mark.parametrize("named", [("--method", "conflation+smooth-legal@5"),
                                   ("--method", "conflation", "--decode", "smooth-legal@5"),
                                   ("--method", "conflation", "--decode", "smooth-legal", "--lag", "5")])
def test_export_takes_the_name_conflate_prints(lagged_workdir, tmp_path, named):
    done = invoke("export", *named, "-o", tmp_path / "m.mlnseq", "-w", lagged_workdir)
    assert done.exit_code == 0, done.output
    model = Recognizer.load(tmp_path / "m.mlnseq")
    assert (model.method, model.decoding.name) == ("conflation", "smooth-legal@5")


@pytest.mark.parametrize("named, said", [
    (("--method", "conflation+filter", "--decode", "viterbi"), "names its decoder; --decode viterbi names another"),
    (("--method", "conflation", "--decode", "smooth-legal@5", "--lag", "3"), "--lag 3 says another"),
    (("--method", "nothing+filter"), "unknown --method 'nothing+filter'"),
])
def test_export_refuses_a_name_that_says_two_things(lagged_workdir, tmp_path, named, said):
    done = invoke("export", *named, "-o", tmp_path / "m.mlnseq", "-w", lagged_workdir)
    assert done.exit_code == 2 and said in done.stderr and len(done.stderr.splitlines()) == 1
    assert not (tmp_path / "m.mlnseq").exists()


def test_predict_and_explain_take_the_models_decoded_name(desk_stream_workdir, desk_test_recording, tmp_path):
    model = tmp_path / "c.mlnseq"
    assert invoke("export", "--method", "conflation+filter", "-o", model, "-w", desk_stream_workdir).exit_code == 0
    for decode in ("viterbi", "conflation+viterbi"):
        done = invoke("predict", model, "--source", desk_test_recording, "--decode", decode, "-o", tmp_path / decode)
        assert done.exit_code == 0, done.output
    assert pl.read_parquet(tmp_path / "viterbi").equals(pl.read_parquet(tmp_path / "conflation+viterbi"))
    said = [invoke("explain", model, "--source", desk_test_recording, "--frame", 40, "--decode", decode).output
            for decode in ("viterbi", "conflation+viterbi")]
    assert said[0] == said[1] and "conflation+viterbi" in said[0]
    other = invoke("predict", model, "--source", desk_test_recording, "--decode", "lstm+viterbi", "-o", tmp_path / "x")
    assert other.exit_code == 2 and "this model recognises with conflation, not lstm" in other.stderr


READS_ONLY_IN_PREDICT = {"output", "force", "intervals", "rerun", "write_lerobot", "write_lerobot_probabilities",
                         "replace_subtasks", "explain", "model", "source", "help"}


@pytest.mark.parametrize("sibling", ["explain", "review"])
def test_siblings_take_every_source_option_predict_takes(sibling):
    def options(name):
        return {p.name: p for p in _load(name).params}

    predict, other = options("predict"), options(sibling)
    shared = set(predict) - READS_ONLY_IN_PREDICT
    assert shared >= {"label_column", "max_hold", "label_topic", "labels", "episode_column", "topics", "decode"}
    assert shared <= set(other), shared - set(other)
    assert all(predict[n].help == other[n].help and predict[n].opts == other[n].opts for n in shared)
    assert "explain" in COMMANDS


def test_a_predict_line_pasted_into_explain_reads_the_same(desk_stream_workdir, desk_test_recording, tmp_path):
    model = tmp_path / "m.mlnseq"
    exported = invoke("export", "--method", "mln", "--decode", "filter", "-o", model, "-w", desk_stream_workdir)
    assert exported.exit_code == 0, exported.output
    reading = ("--source", desk_test_recording, "--label-column", "label", "--time-column", "frame", "--max-hold", 1)
    done = invoke("predict", model, *reading, "-o", tmp_path / "p.parquet")
    assert done.exit_code == 0, done.output
    explained = invoke("explain", model, *reading, "--frame", 40, "--json")
    assert explained.exit_code == 0, explained.output
    predicted = pl.read_parquet(tmp_path / "p.parquet").filter(pl.col("frame") == 40)["class"][0]
    assert f'"class": "{predicted}"' in explained.output


def test_auto_with_an_offline_decoder_conflate_did_not_score_points_to_fit_offline(desk_folds_workdir, tmp_path):
    for path in desk_folds_workdir.iterdir():
        (shutil.copytree if path.is_dir() else shutil.copy)(path, tmp_path / path.name)
    assert invoke("conflate", "--decode", "filter", "-w", tmp_path).exit_code == 0  # online only, as fit --lag does
    done = invoke("export", "--method", "auto", "--decode", "viterbi", "-o", tmp_path / "m.mlnseq", "-w", tmp_path)
    assert done.exit_code == 2 and "no cross-validated viterbi candidate" in done.stderr
    assert "`mlnseq fit --offline` conflates offline decoders too" in done.stderr and "--lags" not in done.stderr


NAMED_OUTPUTS = {"output", "intervals", "rerun", "write_lerobot"}  # a file the user names


def test_every_command_writing_a_file_you_name_takes_force_as_cli_md_says(repo_root):
    """docs/cli.md: a command that writes a file you name keeps an existing one unless --force (fit's --force is
    another part of issue 55, left to it)."""
    named = {name for name in COMMANDS if name not in ("config", "fit")
             and NAMED_OUTPUTS & {p.name for p in _load(name).params}}
    assert named >= {"export", "predict", "binarize"}
    assert [name for name in named if "--force" not in {o for p in _load(name).params for o in p.opts}] == []
    assert "keeps it unless `--force`" in " ".join((repo_root / "docs" / "cli.md").read_text().split())


def test_a_name_with_an_unknown_decoder_is_refused_naming_the_option_given(tmp_path, lagged_workdir):
    done = invoke("export", "--method", "conflation+blur", "-o", tmp_path / "m.mlnseq", "-w", lagged_workdir)
    assert done.exit_code == 2 and "unknown --method 'conflation+blur'" in done.stderr
    done = invoke("conflate", "--decode", "smooth-legal@x", "-w", tmp_path)
    assert done.exit_code == 2 and "--decode 'smooth-legal@x': the lag after @ must be a whole number" in done.stderr
