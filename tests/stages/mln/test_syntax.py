"""The .mln parser: pracmln's syntax, the authors' files unchanged, errors with line and column."""

from __future__ import annotations

import pytest

from mlnseq.mln.syntax import And, Implies, MLNSyntaxError, Not, Or, Var, format_formula, format_weighted, parse_formula, parse_mln

# logic_constraints/taurus.mln of masud99r/prediction-with-logic-constraints, verbatim.
AUTHORS_TAURUS_MLN = """//word = { arms_dist_0, arms_dist_1, arms_dist_3 }

//class = { C0, C1, C2, C3, C4, C5, C6 }

//pages = { 1, 2, 3, 4, 5, 6, 7 }

// Has indicates the words in each document
Has(word, page)
// Topic indicates the class of each page
Topic(class, page)

0.0 Has(+w, p) => Topic(+c, p)
//0.0 Has(w, p) => Topic(c, p)
//0.0 Has("arms_dist_1",p) => Topic("C1",p)
//0.0    Has("arms_dist_0",p) => Topic("C1",p)"""


def test_authors_file_parses_unchanged() -> None:
    mln = parse_mln(AUTHORS_TAURUS_MLN, "taurus.mln")
    assert mln.predicates == {"Has": ("word", "page"), "Topic": ("class", "page")}
    (item,) = mln.formulas
    assert item.weight == 0.0 and item.line == 12
    assert isinstance(item.formula, Implies)
    assert item.formula.body.args == (Var("w", expand=True), Var("p"))
    assert format_weighted(item).split(None, 1)[1] == "Has(+w,p) => Topic(+c,p)"


def test_precedence_and_round_trip() -> None:
    text = '!Has("a",p) ^ Has("b",p) v Has("c",p) => Topic("C4",p) <=> Topic("C1",p)'
    formula = parse_formula(text)
    implication = formula.left
    assert isinstance(implication.body, Or) and isinstance(implication.body.operands[0], And)
    assert isinstance(implication.body.operands[0].operands[0], Not)
    assert parse_formula(format_formula(formula)) == formula
    grouped = parse_formula('Has("a",p) ^ (Has("b",p) v Has(C,p)) => Topic("C4",p)')
    assert format_formula(grouped) == 'Has("a",p) ^ (Has("b",p) v Has("C",p)) => Topic("C4",p)'


def test_hard_and_weighted_formulas() -> None:
    mln = parse_mln('Has(word, page)\nTopic(class, page)\nHas("a",p) => Topic("C1",p).\n-1.5e0 Has(x,p) => !Topic("C2",p)\n')
    hard, soft = mln.formulas
    assert hard.hard and hard.weight is None
    assert soft.weight == -1.5 and not soft.hard


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ('Has(word, page)\n0.0 Has("a",p) ^ => Topic("C4",p)', "f.mln:2:18: expected a predicate"),
        ('0.0 Has("a",p) => Topic("C4",p', "f.mln:1:31: expected ',' or ')'"),
        ('\n\n  Has("a",p) => Topic("C4",p)', "f.mln:3:3: a formula needs a weight"),
        ('0.0 Has("a",p) & Topic("C4",p)', "f.mln:1:16: unexpected character '&'"),
    ],
)
def test_syntax_errors_name_line_and_column(text: str, where: str) -> None:
    with pytest.raises(MLNSyntaxError) as error:
        parse_mln(text, "f.mln")
    assert str(error.value).startswith(where)
