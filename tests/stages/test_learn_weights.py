"""learn-weights on the real data: native BPLL reproduces the authors' pracmln weights."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
from scipy.special import expit

from mlnseq.catalog import artifacts
from mlnseq import binarize
from mlnseq import learn_weights as stage
from mlnseq.catalog.errors import BadInput, StaleArtifact
from mlnseq.formulas import DEFAULT_SPEC, formulas_for, read_spec
from mlnseq.mln import bpll, cll, pracmln_compat
from mlnseq.mln.grounding import expand_templates
from mlnseq.mln.published_codes import desk_predicates, fetch_predicates, write_predicates
from mlnseq.mln.syntax import parse_mln

PAPER = read_spec(DEFAULT_SPEC)
DECLARED = "Has(word, page)\nTopic(class, page)\n"

# Weights the authors published (logic_constraints/taurus.w, gym.w), learned by pracmln's BPLL_CG.
AUTHORS_DESK = {
    ("arm_distance_static", "C0"): 2.262237,
    ("arm_distance_static", "C3"): 2.449025,
    ("left_gripper_closing", "C1"): 2.418033,
    ("right_gripper_closing", "C6"): 1.949482,
    ("grippers_closed_closed", "C0"): 2.369413,
    ("grippers_opening_closing", "C2"): 0.0,  # not in training: no formula
}


def weight_of(weights: pl.DataFrame, word: str, klass: str) -> float:
    rows = weights.filter(pl.col("formula") == f'Has("{word}",p) => Topic("{klass}",p)')
    return float(rows["weight"][0]) if rows.height else 0.0


@pytest.fixture(scope="module")
def desk(shared_data: Path) -> pl.DataFrame:
    return desk_predicates(shared_data)[0]


@pytest.fixture(scope="module")
def desk_weights(desk: pl.DataFrame) -> pl.DataFrame:
    return stage.learn(desk, 7, PAPER).weights


def test_native_reproduces_published_desk_weights(desk_weights: pl.DataFrame) -> None:
    assert desk_weights.height == 17 * 7
    for (word, klass), published in AUTHORS_DESK.items():
        assert weight_of(desk_weights, word, klass) == pytest.approx(published, abs=1e-3)
    # Table II: "leftGsClosed ^ rightGsClosed => S5" at 30.81 (near-separable: stopping-dependent).
    assert weight_of(desk_weights, "grippers_closed_closed", "C4") == pytest.approx(30.81, abs=0.5)
    assert not desk_weights["fixed"].any() and not desk_weights["hard"].any()
    assert set(desk_weights["class"]) == {f"C{k}" for k in range(7)}


def test_native_reproduces_published_fetch_weight(shared_data: Path) -> None:
    weights = stage.learn(fetch_predicates(shared_data)[0], 4, PAPER).weights
    assert weight_of(weights, "gripper_closing", "C1") == pytest.approx(5.214315, abs=1e-5)


def test_fixed_and_hard_formulas(desk: pl.DataFrame) -> None:
    mln = parse_mln(
        DECLARED
        + '1.5 Has("left_gripper_open",p) => Topic("C0",p)\n'
        + '0.0 Has("grippers_closed_closed",p) ^ Has("arm_distance_static",p) => Topic("C4",p)\n'
        + 'Has("grippers_closed_closed",p) => !Topic("C6",p).\n'
    )
    weights = stage.learn(desk, 7, mln).weights
    assert weights["weight"][0] == 1.5 and weights["fixed"].to_list() == [True, False, False]
    assert weights["hard"].to_list() == [False, False, True] and np.isinf(weights["weight"][2])
    assert weights["weight"][1] > 1.0 and weights["class"].to_list() == ["C0", "C4", "C6"]


def test_violated_hard_formula_is_refused(desk: pl.DataFrame) -> None:
    mln = parse_mln(DECLARED + 'Has("arm_distance_static",p) => Topic("C4",p).\n')
    with pytest.raises(BadInput, match=r"formulas.mln:3: hard formula .* is false at 20 training frame\(s\): "
                                       r"episode 0 frame 0, episode 0 frame 1, .* and 15 more"):
        stage.learn(desk, 7, mln)


def test_unseen_constant_and_class_warn(shared_data: Path) -> None:
    table, _ = desk_predicates(shared_data, train_limit=100)  # the first 100 frames show S1 to S3
    mln = parse_mln(DECLARED + '0.0 Has("grippers_opening_opening",p) => Topic("C0",p)\n0.0 Has(+w,p) => Topic(+c,p)\n')
    learned = stage.learn(table, 7, mln)
    assert any("class C6 never occurs" in w for w in learned.warnings)
    assert any("grippers_opening_opening" in w and "weight stays 0" in w for w in learned.warnings)
    first = learned.weights.filter(pl.col("template") == 0)
    assert first["weight"].to_list() == [0.0]
    assert set(learned.weights.filter(pl.col("template") == 1)["class"]) == {"C0", "C1", "C2"}


def test_empty_training_split_is_refused(desk: pl.DataFrame) -> None:
    with pytest.raises(BadInput, match="no training frames"):
        stage.learn(desk.filter(pl.col("split") == "test"), 7, PAPER)


def test_run_writes_weights_and_learned_mln(tmp_path: Path, shared_data: Path) -> None:
    table, predicates = fetch_predicates(shared_data)
    write_predicates(tmp_path, table, predicates, "fetch")
    (tmp_path / "formulas.mln").write_text(DEFAULT_SPEC.read_text())
    path, learned = stage.run(tmp_path, stage.LearnWeightsOptions())
    weights, meta = artifacts.read_table(path, "weights")
    assert weights.columns == ["formula", "class", "weight", "fixed", "hard", "template", "temporal"]
    assert meta["engine"] == "native" and set(meta["inputs"]) == {"predicates.parquet", "formulas.mln"}
    assert (meta["objective"], meta["l2"]) == ("pll", 0.0) and not weights["temporal"].any()
    reread = parse_mln((tmp_path / "learned.mln").read_text(), "learned.mln")
    assert [f.weight for f in reread.formulas] == pytest.approx(weights["weight"].to_list(), abs=1e-6)


def test_stale_predicates_are_refused(tmp_path: Path, shared_data: Path) -> None:
    frames = tmp_path / "frames.parquet"
    artifacts.write_table(pl.DataFrame({"x": [1]}), frames, "frames", {})
    table, predicates = fetch_predicates(shared_data)
    write_predicates(tmp_path, table, predicates, "fetch", inputs=(frames,))
    (tmp_path / "formulas.mln").write_text(DEFAULT_SPEC.read_text())
    artifacts.write_table(pl.DataFrame({"x": [2]}), frames, "frames", {})
    with pytest.raises(StaleArtifact, match="rerun `mlnseq binarize`"):
        stage.run(tmp_path, stage.LearnWeightsOptions())
    assert not (tmp_path / "weights.parquet").exists()


@pytest.mark.pracmln
def test_pracmln_matches_native_on_fetch(shared_data: Path) -> None:
    table = fetch_predicates(shared_data)[0]
    learned = stage.learn(table, 4, PAPER, "native")
    native = learned.weights["weight"].to_numpy()
    pracmln = stage.learn(table, 4, PAPER, "pracmln").weights["weight"].to_numpy()
    assert np.abs(native - pracmln).max() < 1e-3
    pracmln_compat.import_pracmln()
    from pracmln.mln.base import parse_mln as pracmln_parse

    read_back = pracmln_parse(learned.learned_mln, grammar="StandardGrammar", logic="FirstOrderLogic")
    assert [float(w) for w in read_back.weights] == pytest.approx(native.tolist(), abs=1e-6)


@pytest.mark.pracmln
def test_pracmln_matches_native_on_taurus_subset(shared_data: Path) -> None:
    # 150 frames, arm distance and left gripper: pracmln takes ~5 s. With all four predicates a
    # subset this small has exactly co-occurring columns whose separable weights are path-dependent.
    table = desk_predicates(shared_data, train_limit=150)[0]
    table = table.select(*artifacts.KEY_COLUMNS, pl.col("^(arm_distance|left_gripper)_.*$"))
    native = stage.learn(table, 7, PAPER, "native").weights["weight"].to_numpy()
    pracmln = stage.learn(table, 7, PAPER, "pracmln").weights["weight"].to_numpy()
    small = (np.abs(native) < 10) & (np.abs(pracmln) < 10)
    large = (np.abs(native) > 10) & (np.abs(pracmln) > 10) & (np.sign(native) == np.sign(pracmln))
    assert small.sum() > 10 and large.any()
    assert np.abs(native - pracmln)[small].max() < 1e-3
    assert (small | large).all()


@pytest.mark.pracmln
def test_pracmln_imports_without_tk(tmp_path: Path) -> None:
    import subprocess
    import sys

    code = (
        "import sys; sys.modules['tkinter'] = None\n"
        "from mlnseq.mln import pracmln_compat\n"
        "print(pracmln_compat.learn_weights('Has(word, page)\\nTopic(class, page)\\n0.0 Has(+w,p) => Topic(+c,p)\\n',"
        " 'Has(\"a\",P0)\\nTopic(\"C0\",P0)\\nHas(\"b\",P1)\\nTopic(\"C1\",P1)\\n', [False]))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=Path(__file__).parents[2])
    assert done.returncode == 0, done.stderr
    assert 'Has("a",p) => Topic("C0",p)' in done.stdout


TEMPORAL = DECLARED + "Next(page, page)\n0.0 Has(+w, p) => Topic(+c, p)\n0.0 Topic(+c1, p) ^ Next(p, q) => Topic(+c2, q)\n"


def test_temporal_formulas_default_to_cll(desk: pl.DataFrame) -> None:
    learned = stage.learn(desk, 7, parse_mln(TEMPORAL))
    assert (learned.objective, learned.l2) == ("cll", cll.DEFAULT_L2)
    weights = learned.weights
    assert weights.height == 119 + 49 and weights["temporal"].sum() == 49
    assert np.isfinite(weights["weight"].to_numpy()).all()
    stay = weights.filter(pl.col("formula") == 'Topic("C2",p) ^ Next(p,q) => Topic("C2",q)')["weight"][0]
    leave = weights.filter(pl.col("formula") == 'Topic("C2",p) ^ Next(p,q) => Topic("C6",q)')["weight"][0]
    assert stay > leave  # surgemes last many frames
    pll = stage.learn(desk, 7, parse_mln(TEMPORAL), objective="pll", l2=1.0)
    assert (pll.objective, pll.l2) == ("pll", 1.0) and not np.allclose(pll.weights["weight"], weights["weight"])
    reread = parse_mln(learned.learned_mln, "learned.mln")
    assert "Next" in reread.predicates and "cll" in learned.learned_mln.splitlines()[0].lower()


def test_chains_never_cross_episodes_or_splits(desk: pl.DataFrame) -> None:
    training = stage.training_data(desk, 7)
    assert training.starts.sum() == 1  # DESK's training split is one episode
    shuffled = desk.with_columns(pl.when(pl.col("frame") == 700).then(pl.lit("test")).otherwise(pl.col("split")).alias("split"))
    training = stage.training_data(shuffled, 7)
    assert training.starts.sum() == 2 and training.frames[training.starts].tolist() == [0, 701]


def test_hard_temporal_rule_broken_by_labels_is_refused(desk: pl.DataFrame) -> None:
    mln = parse_mln(TEMPORAL + 'Topic("C0", p) ^ Next(p, q) => Topic("C0", q).\n', "order.mln")
    with pytest.raises(BadInput, match=r"^order.mln:6: hard formula .* is false at \d+ training frame\(s\): "
                                       r"episode 0 frame \d+, .*fix their labels"):
        stage.learn(desk, 7, mln, where="order.mln")
    order = parse_mln(TEMPORAL + 'Topic("C0", p) ^ Next(p, q) => Topic("C0", q) v Topic("C1", q).\n', "order.mln")
    weights = stage.learn(desk, 7, order).weights
    assert weights.filter(pl.col("hard"))["temporal"].to_list() == [True]


def test_next_without_consecutive_frames_is_refused(desk: pl.DataFrame) -> None:
    single = desk.head(40).with_columns(pl.int_range(pl.len()).cast(pl.Int32).alias("episode"), pl.lit(0).cast(pl.Int32).alias("frame"))
    with pytest.raises(BadInput, match="every episode of the training split has one frame: no transitions can be learned"):
        stage.learn(single, 7, parse_mln(TEMPORAL))


def test_bad_objective_options_are_refused(desk: pl.DataFrame) -> None:
    with pytest.raises(BadInput, match="--engine pracmln learns by pseudo-likelihood only; add --objective pll"):
        stage.learn(desk, 7, parse_mln(TEMPORAL), "pracmln")
    with pytest.raises(BadInput, match="unknown --objective 'ml'"):
        stage.learn(desk, 7, PAPER, objective="ml")
    with pytest.raises(BadInput, match="--l2 must be a number >= 0"):
        stage.learn(desk, 7, PAPER, l2=-1.0)


def fetch_parity_table(fetch_frames_workdir: Path) -> tuple[pl.DataFrame, list[str]]:
    """A small real Fetch collection as predicates: the last 16 frames of episode 0 and the first 20 of episode 1
    train (two chains, all four classes), the rest test."""
    frames, meta = artifacts.read_table(fetch_frames_workdir / artifacts.FRAMES, "frames")
    table = binarize.binarize(frames, binarize.load_spec(binarize.default_spec_path("fetch")))
    train = ((pl.col("episode") == 0) & (pl.col("frame") >= 34)) | ((pl.col("episode") == 1) & (pl.col("frame") < 20))
    return table.with_columns(pl.when(train).then(pl.lit("train")).otherwise(pl.lit("test")).alias("split")), meta["classes"]


@pytest.mark.pracmln
@pytest.mark.mujoco
def test_pracmln_matches_native_pll_with_next(fetch_frames_workdir: Path) -> None:
    # 36 frames in two chains: pracmln grounds the 16 transition formulas on all 1,296 page pairs (10-20 s here).
    # With l2 > 0 (pracmln's Gaussian prior) the optimum is finite: near-deterministic transitions would
    # otherwise send pseudo-likelihood weights to infinity, where both optimisers stop somewhere.
    table, classes = fetch_parity_table(fetch_frames_workdir)
    mln = parse_mln(TEMPORAL, "temporal.mln")
    formulas_for(mln, Path("temporal.mln"), artifacts.feature_columns(table), classes)
    native = stage.learn(table, len(classes), mln, objective="pll", l2=1.0)
    pracmln = stage.learn(table, len(classes), mln, "pracmln", objective="pll", l2=1.0).weights
    assert native.weights["formula"].to_list() == pracmln["formula"].to_list()
    assert native.weights["temporal"].sum() == 16 and np.abs(native.weights["weight"]).max() > 0.5
    assert np.abs(native.weights["weight"].to_numpy() - pracmln["weight"].to_numpy()).max() < 1e-3
    pracmln_compat.import_pracmln()
    from pracmln.mln.base import parse_mln as pracmln_parse

    read_back = pracmln_parse(native.learned_mln, grammar="StandardGrammar", logic="FirstOrderLogic")
    assert [float(w) for w in read_back.weights] == pytest.approx(native.weights["weight"].to_list(), abs=1e-6)


def test_lbfgs_reaches_the_bfgs_optimum(shared_data: Path) -> None:
    """Many weights are learned with L-BFGS: the same pseudo-likelihood and atom probabilities as BFGS. The pairwise
    template is redundant (Has(w) ^ Has(w) is Has(w); one-hot groups), so the weights themselves are not unique."""
    table = desk_predicates(shared_data)[0]
    table = table.select(*artifacts.KEY_COLUMNS, *artifacts.feature_columns(table)[:8])
    mln = parse_mln(DECLARED + "0.0 Has(+w1,p) ^ Has(+w2,p) => Topic(+c,p)\n")
    training = stage.training_data(table, 7)
    expanded, _, _ = expand_templates(mln.formulas, training.space)
    objective = bpll.build_objective(expanded, training.rows, training.space)
    found = {name: bpll.learn(expanded, training.rows, training.space, optimiser=name) for name in ("bfgs", "l-bfgs")}
    assert len(expanded) == 252
    values = {name: bpll.log_pseudo_likelihood(objective, w) for name, w in found.items()}
    assert values["l-bfgs"] == pytest.approx(values["bfgs"], abs=1e-3)
    odds = {name: objective.when_true @ w - objective.when_false @ w for name, w in found.items()}
    assert np.abs(expit(odds["l-bfgs"]) - expit(odds["bfgs"])).max() < 1e-4


def test_weights_learned_mln_and_warnings_name_the_classes_as_the_frames_do(shared_data: Path) -> None:
    table, _ = desk_predicates(shared_data, train_limit=100)  # the first 100 frames show S1 to S3
    names = [f"S{k + 1}" for k in range(7)]
    mln = parse_mln(DECLARED + '1.5 Has("left_gripper_open",p) => Topic(C0,p)\n0.0 Has(+w,p) => Topic(+c,p)\n')
    named, paper = stage.learn(table, 7, mln, class_names=names), stage.learn(table, 7, mln)
    assert named.weights["weight"].to_list() == paper.weights["weight"].to_list()  # names change no number
    assert named.weights["class"].to_list() == [None if c is None else names[int(c[1:])] for c in paper.weights["class"]]
    assert named.weights["formula"][0] == 'Has("left_gripper_open",p) => Topic("S1",p)'
    assert 'Topic("S1",p)' in named.learned_mln and '"C0"' not in named.learned_mln
    assert any("class S7 never occurs" in w for w in named.warnings)


def test_a_template_expansion_also_written_out_is_learned_once_with_the_written_weight(desk: pl.DataFrame) -> None:
    mln = parse_mln(DECLARED + '0.0 Has(+w,p) => Topic(+c,p)\n1.5 Has("left_gripper_open",p) => Topic("C0",p)\n')
    learned = stage.learn(desk, 7, mln)
    same = learned.weights.filter(pl.col("formula") == 'Has("left_gripper_open",p) => Topic("C0",p)')
    assert same.height == 1 and same["weight"][0] == 1.5 and same["fixed"][0] and same["template"][0] == 1
    assert learned.weights.height == stage.learn(desk, 7, PAPER).weights.height
    assert ("line 3: 1 expansion(s) of this template repeat the formula(s) of line 4: each is learned once, as line 4 "
            "gives it") in learned.warnings
def test_the_conjunctive_transition_template_learns_the_same_chain_family(desk: pl.DataFrame, repo_root: Path) -> None:
    conjunctive = stage.learn(desk, 7, parse_mln((repo_root / "examples" / "conjunctive.mln").read_text())).weights
    assert conjunctive["temporal"].sum() == 49
    stay = conjunctive.filter(pl.col("formula") == 'Topic("C2",p) ^ Next(p,q) ^ Topic("C2",q)')["weight"][0]
    leave = conjunctive.filter(pl.col("formula") == 'Topic("C2",p) ^ Next(p,q) ^ Topic("C6",q)')["weight"][0]
    assert stay > leave
    hard = parse_mln(DECLARED + "Next(page, page)\nTopic(C0, p) ^ Next(p, q) ^ Topic(C0, q).\n", "hard.mln")
    with pytest.raises(BadInput, match="must hold whenever Next"):  # a hard conjunction would forbid every other pair
        formulas_for(hard, Path("hard.mln"), artifacts.feature_columns(desk), [f"S{k + 1}" for k in range(7)])


def test_fold_weights_are_learned_without_their_fold(tmp_path: Path, shared_data: Path) -> None:
    frames, predicates = desk_predicates(shared_data)
    write_predicates(tmp_path, frames, predicates, "desk")
    (tmp_path / "formulas.mln").write_text(TEMPORAL)
    stage.run(tmp_path, stage.LearnWeightsOptions(folds=2))
    table, meta = artifacts.read_table(tmp_path / artifacts.FOLD_WEIGHTS, "fold_weights")
    # two blocks, cut where a trial restarts (at S1) nearest the middle
    assert meta["folds"] == {"k": 2, "kind": "blocks", "spans": [[0, 659], [659, 1405]], "cut": "restarts"}
    first = table.filter(pl.col("fold") == 0).drop("fold")
    held_out = frames.with_columns(pl.Series("split", np.where(np.arange(frames.height) < 659, "heldout",
                                                               frames["split"].to_numpy())))
    expected = stage.learn(held_out, 7, parse_mln(TEMPORAL)).weights
    # each fold's learner starts from the whole split's weights: the optimum learned from zero, to its tolerance
    np.testing.assert_allclose(first["weight"].to_numpy(), expected["weight"].to_numpy(), atol=1e-4)
    with pytest.raises(BadInput, match="--folds 1: .* at most 70; use --folds 5 \\(5 folds by block"):
        stage.run(tmp_path, stage.LearnWeightsOptions(folds=1))


def test_learning_without_folds_removes_an_earlier_runs_fold_weights(desk_mln_workdir, tmp_path: Path) -> None:
    """Pages followed in one folder (issue 44 item 5): fold weights of earlier formulas or frames do not outlive a
    learn-weights without folds, so a stream network never follows folds of other weights."""
    import shutil

    for name in ("frames.parquet", "predicates.parquet", "formulas.mln"):
        shutil.copy(desk_mln_workdir / name, tmp_path / name)
    stage.run(tmp_path, stage.LearnWeightsOptions(folds=3))
    assert (tmp_path / artifacts.FOLD_WEIGHTS).is_file()
    stage.run(tmp_path, stage.LearnWeightsOptions())
    assert (tmp_path / artifacts.WEIGHTS).is_file() and not (tmp_path / artifacts.FOLD_WEIGHTS).exists()
