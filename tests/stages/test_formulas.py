"""formulas: the paper's template by default, hand-written specs checked against the predicates."""

from __future__ import annotations

from pathlib import Path

import pytest

from mlnseq import formulas as stage
from mlnseq.catalog.errors import BadInput
from mlnseq.mln.published_codes import desk_predicates, write_predicates
from mlnseq.mln.syntax import format_weighted, parse_mln


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory, shared_data: Path) -> Path:
    path = tmp_path_factory.mktemp("desk")
    write_predicates(path, *desk_predicates(shared_data), "desk")
    return path


def test_default_spec_keeps_the_template(workdir: Path) -> None:
    written = stage.run(workdir, stage.FormulasOptions())
    mln = parse_mln(written.path.read_text(), "formulas.mln")
    assert mln.predicates == {"Has": ("word", "page"), "Topic": ("class", "page")}
    assert [f.weight for f in mln.formulas] == [0.0]
    assert "Has(+w,p) => Topic(+c,p)" in written.path.read_text()
    assert "grippers_closed_closed" in written.words and "grippers_opening_opening" not in written.words
    assert written.classes == tuple(f"S{k + 1}" for k in range(7))  # as the frames name them


def test_handwritten_example_is_accepted(workdir: Path, repo_root: Path) -> None:
    written = stage.run(workdir, stage.FormulasOptions(spec=repo_root / "examples" / "desk_handwritten.mln"))
    formulas = [format_weighted(f) for f in parse_mln(written.path.read_text(), "formulas.mln").formulas]
    assert formulas == [  # the template, a formula to learn (weight 0) and an expert's fixed one, as written
        "0.000000    Has(+w,p) => Topic(+c,p)",
        '0.000000    Has("left_gripper_closed",p) ^ Has("right_gripper_closed",p) => Topic("S5",p)',
        '1.500000    Has("left_gripper_open",p) ^ Has("right_gripper_open",p) => Topic("S1",p)',
    ]


def test_a_class_may_be_named_as_in_the_frames(workdir: Path, tmp_path: Path) -> None:
    path = tmp_path / "named.mln"
    path.write_text('0.0 Has("grippers_closed_closed",p) => Topic("S5",p)\n'
                    '1.0 Has("left_gripper_open",p) => Topic("C0",p)\n')
    written = stage.run(workdir, stage.FormulasOptions(spec=path)).path.read_text()
    assert 'Has("grippers_closed_closed",p) => Topic("S5",p)' in written  # names survive, the paper's C<k> too:
    assert 'Has("left_gripper_open",p) => Topic("S1",p)' in written  # written as the frames name the class
    assert "// label order (the paper's C0 .. C6): S1, S2, S3, S4, S5, S6, S7\n" in written


def test_a_misspelt_class_gets_the_nearest_names(workdir: Path, tmp_path: Path) -> None:
    path = tmp_path / "typo.mln"
    path.write_text('0.0 Has(+w, p) => Topic(+c, p)\n1.0 Has("left_gripper_open", p) => Topic("S55", p)\n')
    with pytest.raises(BadInput) as error:
        stage.run(workdir, stage.FormulasOptions(spec=path))
    assert str(error.value) == (f"{path}:2:36: unknown class 'S55' in Topic(\"S55\",p): did you mean S5? the classes "
                                "are S1, S2, S3, S4, S5, S6, S7 (or C0 .. C6 in that order)")


@pytest.mark.parametrize("second", ['2.0 Has("left_gripper_open", p) => Topic("S1", p)',
                                    '0.0 Has("left_gripper_open",p)  =>  Topic(C0, p)'])
def test_a_formula_written_twice_is_refused_naming_both_lines(workdir: Path, tmp_path: Path, second: str) -> None:
    path = tmp_path / "twice.mln"
    path.write_text(f'1.0 Has("left_gripper_open", p) => Topic("S1", p)\n// again\n{second}\n')
    with pytest.raises(BadInput, match=r'twice.mln:3:1: Has\("left_gripper_open",p\) => Topic\("S1",p\) is written '
                                       "twice, here and on line 1"):
        stage.run(workdir, stage.FormulasOptions(spec=path))


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ('0.0 Has("left_gripper_closed",p) => Topc("C4",p)\n', "spec.mln:1:37: unknown predicate Topc"),
        ('\n0.0 Has("left_gripper_clsed",p) => Topic("C4",p)\n', "spec.mln:2:5: unknown constant 'left_gripper_clsed'"),
        ('0.0 Has("left_gripper_closed",p) => Topic("C9",p)\n', "unknown class 'C9'"),
        ('0.0 Has("left_gripper_closed",p) => Topic("C4",q)\n', "one frame variable"),
        ('0.0 Has("left_gripper_closed",p) ^^ Topic("C4",p)\n', "spec.mln:1:35:"),
    ],
)
def test_bad_specs_are_refused(workdir: Path, tmp_path: Path, spec: str, message: str) -> None:
    path = tmp_path / "spec.mln"
    path.write_text(spec)
    before = (workdir / "formulas.mln").read_text() if (workdir / "formulas.mln").exists() else None
    with pytest.raises(BadInput, match=message.replace("(", r"\(")):
        stage.run(workdir, stage.FormulasOptions(spec=path))
    after = (workdir / "formulas.mln").read_text() if (workdir / "formulas.mln").exists() else None
    assert before == after


@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        ("0.0 Topic(+c1, p) ^ Next(p, q) => Topic(+c2, q)\n", "0.000000    Topic(+c1,p) ^ Next(p,q) => Topic(+c2,q)"),
        ('Topic("S1", p) ^ Next(p, q) => Topic("S1", q) v Topic("S2", q).\n',
         'Topic("S1",p) ^ Next(p,q) => (Topic("S1",q) v Topic("S2",q)).'),  # the frames' class names
        ('0.0 Topic(c1, p) ^ Next(p, q) ^ Has("left_gripper_closing", q) => Topic(c2, q)\n',
         '0.000000    Topic(c1,p) ^ Next(p,q) ^ Has("left_gripper_closing",q) => Topic(c2,q)'),
        ('0.0 Next(p, q) => (Topic("C0", p) <=> Topic("C0", q))\n',
         '0.000000    Next(p,q) => (Topic("S1",p) <=> Topic("S1",q))'),  # the paper's C<k> as the frames name it
        ('0.0 !Next(p, q) v !Topic("S3", q) v Topic("S3", p)\n', '0.000000    !Next(p,q) v !Topic("S3",q) v Topic("S3",p)'),
    ],
)
def test_temporal_forms_are_accepted(workdir: Path, tmp_path: Path, spec: str, expected: str) -> None:
    path = tmp_path / "temporal.mln"
    path.write_text(spec)  # no declarations: Has, Topic and (used here) Next are declared for it
    written = stage.run(workdir, stage.FormulasOptions(spec=path))
    mln = parse_mln(written.path.read_text(), "formulas.mln")
    assert mln.predicates["Next"] == ("page", "page")
    assert [format_weighted(f) for f in mln.formulas] == [expected]


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ('0.0 Topc("C0", p) ^ Next(p, q) => Topic("C1", q)\n', "spec.mln:1:5: unknown predicate Topc"),
        ('0.0 Topic("S9", p) ^ Next(p, q) => Topic("S1", q)\n', "spec.mln:1:5: unknown class 'S9'"),
        ('Has(word, page)\nTopic(class, page)\n0.0 Topic("C0", p) ^ Next(p, q) => Topic("C1", q)\n',
         "spec.mln:3:22: unknown predicate Next (declared: Has, Topic); declare Next(page, page)"),
        ('0.0 Topic("C0", p) ^ Next(p, "C1") => Topic("C1", q)\n',
         'spec.mln:1:22: syntax error: Next takes two different frame variables, Next(p, q) for the frame q right '
         'after p; found Next(p,"C1")'),
        ('0.0 Topic("C0", p) ^ Next(p, p) => Topic("C1", p)\n', "spec.mln:1:22: syntax error: Next takes two"),
        ('0.0 Topic("C0", p) ^ Next(+p, q) => Topic("C1", q)\n', "spec.mln:1:22: syntax error: Next takes two"),
        ('0.0 Topic("C0", p) ^ Next(p, q) => Topic("C1", r)\n',
         "spec.mln:1:36: Topic(\"C1\",r) is on frame r, but Next(p,q) joins only p and q"),
        ('0.0 Topic("C0", p) ^ Next(p, q) ^ Next(q, r) => Topic("C1", r)\n', "spec.mln:1:35: a formula joins two"),
        ('Topic("C0", p) ^ Topic("C1", q) ^ Next(p, q).\n',  # hard: a soft conjunction with Next is a template
         "spec.mln:1:1: Topic(\"C0\",p) ^ Topic(\"C1\",q) ^ Next(p,q) must hold whenever Next(p,q) is false"),
        ('0.0 Topic("C0", p) v Next(p, q) => Topic("C1", q)\n', "put Next(p,q) in the body"),
    ],
)
def test_bad_temporal_formulas_name_line_and_column(workdir: Path, tmp_path: Path, spec: str, message: str) -> None:
    path = tmp_path / "spec.mln"
    path.write_text(spec)
    with pytest.raises(BadInput) as error:
        stage.run(workdir, stage.FormulasOptions(spec=path))
    assert message in str(error.value).replace(str(tmp_path) + "/", "")
