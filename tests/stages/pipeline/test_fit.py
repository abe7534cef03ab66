"""``mlnseq.fit`` from Python on six ROS 2 bags of the real DESK trials (tests/desk_bags.py), 2 epochs: the typed
result is the model file's manifest and export --method auto's choice, the observer hears each stage as it finishes,
options are refused before any work, and ``force`` overwrites what only it may."""

from __future__ import annotations

from contextlib import nullcontext
from pathlib import Path

import numpy as np
import polars as pl
import pytest

pytest.importorskip("rosbags", reason="the [recordings] extra is not installed")
pytest.importorskip("torch", reason="the [train] extra is not installed")

import desk_bags  # noqa: E402  (tests/desk_bags.py)
from choice_rule import expected_choice  # noqa: E402  (tests/choice_rule.py)
import mlnseq  # noqa: E402
from mlnseq import export  # noqa: E402
from mlnseq.catalog import artifacts  # noqa: E402
from mlnseq.collect import CollectOptions, SourceOptions  # noqa: E402
from mlnseq.pipeline.fit import Observer  # noqa: E402

EPOCHS = 2


class Heard(Observer):
    """Each call in order, with whether the next stage's file and the model file existed then."""

    def __init__(self, workdir: Path, model: Path) -> None:
        self.workdir, self.model, self.calls, self.epochs = workdir, model, [], []

    def note(self, name: str, later: str) -> None:
        self.calls.append((name, (self.workdir / later).exists(), self.model.exists()))

    def collected(self, step):
        self.note("collected", artifacts.PREDICATES)

    def binarized(self, step):
        self.note("binarized", artifacts.FORMULAS)

    def folded(self, step):
        self.note("folded", artifacts.FORMULAS)

    def formulas_written(self, step):
        self.note("formulas_written", artifacts.WEIGHTS)

    def weights_learned(self, step):
        self.note("weights_learned", "models")

    def training(self, epochs, folds):
        self.note("training", "models")
        return nullcontext(lambda done: self.epochs.append(done.epoch))

    def trained(self, step):
        self.note("trained", artifacts.PREDICTIONS)

    def conflated(self, step):
        self.note("conflated", "model.mlnseq")


def source(folder: Path) -> CollectOptions:
    return CollectOptions(env="rosbag", source=folder, recordings=SourceOptions(label_topic="/phase"))


@pytest.fixture(scope="module")
def bags(tmp_path_factory, shared_data):
    desk = np.loadtxt(shared_data / "desk-taurus" / "taurus_kinematics_train.txt")
    root = tmp_path_factory.mktemp("user")
    return desk_bags.write_folders(desk, root / "bags", root / "heldout")


@pytest.fixture(scope="module")
def fitted(bags, tmp_path_factory):
    workdir = tmp_path_factory.mktemp("fit")
    heard = Heard(workdir, workdir / "arm.mlnseq")
    result = mlnseq.fit(source(bags[0]), workdir, mlnseq.FitOptions(epochs=EPOCHS, output=workdir / "arm.mlnseq"),
                        observer=heard)
    return workdir, result, heard


def test_the_result_is_the_model_files_manifest_and_export_autos_choice(fitted, tmp_path):
    workdir, result, _ = fitted
    assert result.path == workdir / "arm.mlnseq" and result.budget == 0 and result.folding.k == 4
    written = mlnseq.load(result.path).manifest
    assert written == result.manifest
    chosen = written.chosen_by_cross_validation
    assert chosen is not None and chosen.name == result.standing.chosen.name == result.method
    assert chosen.figures == result.standing.chosen.figures and result.standing.among == len(chosen.candidates)
    auto = export.run(workdir, export.ExportOptions(method="auto", lag=0, output=tmp_path / "auto.mlnseq"))
    assert auto.manifest.chosen_by_cross_validation.name == result.method
    assert (auto.manifest.method, auto.manifest.decode, auto.manifest.lag) == (written.method, written.decode,
                                                                               written.lag)
    cross = artifacts.read_metadata(workdir / artifacts.PREDICTIONS, "predictions")["cross_validation"]
    among = {n: cross["figures"][n] for n in chosen.candidates}
    assert result.method == expected_choice(among, cross["fold_frame_accuracy"])
    others = [c.name for c in (result.standing.runner_up, result.standing.network_alone) if c is not None]
    assert result.standing.runner_up is not None and result.method not in others and len(set(others)) == len(others)
    assert "lstm" in [result.method, *others]


def test_the_test_figures_are_the_test_splits(fitted):
    workdir, result, _ = fitted
    assert set(result.test) == {result.method, "lstm"}
    predictions = pl.read_parquet(workdir / artifacts.PREDICTIONS).filter(pl.col("split") == "test")
    for name, figures in result.test.items():
        right = predictions["label"].to_numpy() == predictions[artifacts.pred_column(name)].to_numpy()
        assert figures.frame_accuracy == pytest.approx(float(right.mean()))
        assert 0 <= figures.segment_accuracy <= 1
    assert any(line.startswith("test split (held out of everything above): ") for line in result.said)
    assert result.said[0].startswith("  chose:") and result.wrote.startswith(f"wrote {result.path} (")


def test_the_observer_hears_each_stage_as_it_finishes(fitted):
    workdir, result, heard = fitted
    names = [name for name, _, _ in heard.calls]
    assert names == ["collected", "binarized", "folded", "formulas_written", "weights_learned", "training", "trained",
                     "conflated"]
    assert not any(later or model for _, later, model in heard.calls)  # before the next stage ran, and the export
    kept = result.trained.result.trained.kept_epoch  # where the fold networks, trained first, said to stop
    assert 1 <= kept <= EPOCHS and heard.epochs == list(range(1, kept + 1))
    assert not any(note.code == "missing-input" for note in result.conflated.notes)  # no "run train --method
    # priorlayer": fit has no option for it
    assert result.binarized.spec == workdir / artifacts.LEARNED_SPEC
    assert result.formulas.spec == workdir / "learned.formulas.mln"  # as the workdir was given


def test_options_are_refused_before_any_work(bags, fitted, tmp_path):
    _, result, _ = fitted
    for options, said in ((mlnseq.FitOptions(lag=2, offline=True), "give one of --latency, --lag and --offline, not "
                                                                      "--lag and --offline"),
                          (mlnseq.FitOptions(output=result.path), f"--output {result.path} exists: pass --force"),
                          (mlnseq.FitOptions(epochs=0), "--epochs must be at least 1"),
                          (mlnseq.FitOptions(spec=tmp_path / "none.toml"), "--spec")):
        with pytest.raises(mlnseq.BadInput, match=said.replace("(", r"\(")):
            mlnseq.fit(source(bags[0]), tmp_path / "w", options)
        assert not (tmp_path / "w").exists()


def test_force_overwrites_the_model_and_a_learned_spec_edited_by_hand(bags, fitted, tmp_path):
    workdir, result, _ = fitted
    model = tmp_path / "arm.mlnseq"
    model.write_bytes(result.path.read_bytes())
    spec = tmp_path / "w" / artifacts.LEARNED_SPEC
    spec.parent.mkdir()
    spec.write_text((workdir / artifacts.LEARNED_SPEC).read_text() + "# my edit\n")
    with pytest.raises(mlnseq.BadInput, match="was edited since it was learned"):
        mlnseq.fit(source(bags[0]), tmp_path / "w", mlnseq.FitOptions(epochs=1, folds=0))
    before = model.read_bytes()
    again = mlnseq.fit(source(bags[0]), tmp_path / "w", mlnseq.FitOptions(epochs=1, folds=0, output=model, force=True))
    assert "# my edit" not in spec.read_text() and mlnseq.load(model).manifest == again.manifest
    assert model.read_bytes() != before
    assert again.standing is None and again.method == "conflation+filter" and again.folding.k == 0
    assert again.said[0] == ("chose conflation+filter (network and MLN) without cross-validation (--folds 0): nothing "
                             "to choose on")


def test_the_seed_seeds_the_networks_and_the_model_file_records_it(bags, fitted, tmp_path, monkeypatch):
    """The same seed and inputs give the same model file, byte for byte; another seed, other networks."""
    import zipfile

    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1700000000")
    spec = tmp_path / "hand.binarize.toml"
    spec.write_text(desk_bags.HAND_SPEC)
    model = tmp_path / "arm.mlnseq"
    made = []
    for seed in (1, 1, 2):
        fitted_again = mlnseq.fit(source(bags[0]), tmp_path / "w", mlnseq.FitOptions(
            epochs=EPOCHS, seed=seed, spec=spec, output=model, force=True))
        assert fitted_again.manifest.network.seed == seed
        with zipfile.ZipFile(model) as archive:
            made.append((model.read_bytes(), archive.read("network.npz")))
    assert made[0] == made[1] and made[1][1] != made[2][1]
    assert fitted[1].manifest.network.seed == 0
