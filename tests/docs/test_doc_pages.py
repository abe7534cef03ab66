"""The docs test's own machinery (tests/doc_pages.py) on small pages written here: it fails where a page and its
run differ, skips with the page's reason, and reads the markers docs/testing.md describes."""

from __future__ import annotations

from pathlib import Path
from unittest import SkipTest

import pytest

import doc_pages

PAGE = """# A page

<!-- skip: next -- a robot's live feed -->
```bash
exit 3
```

<!-- file: hello.sh -->
```bash
echo "frame accuracy train 99.2%, test {test}%"
```

```bash
bash hello.sh
```

<!-- output -->
```text
frame accuracy ... test 64.1%
```

The test figure is 64.1 %<!-- figure: test {{}}% -->.

<!-- exit: 2 -->
```bash
echo refused >&2; exit 2
```

```bash
false
```

```bash
echo never
```
"""


def runs(tmp_path: Path, test: str) -> tuple[doc_pages.Runs, list[doc_pages.Step]]:
    (tmp_path / "page.md").write_text(PAGE.format(test=test))
    root = tmp_path / "pages"
    root.mkdir()
    found = doc_pages.Runs(root, [tmp_path / "page.md"])
    return found, doc_pages.steps(found.documents["page.md"])


def test_a_page_that_says_what_its_run_prints(tmp_path):
    found, steps = runs(tmp_path, "64.1")
    assert [(s.kind, s.line) for s in steps] == [("block", 4), ("block", 13), ("output", 18), ("block", 25),
                                                 ("block", 29), ("block", 33), ("figure", 22)]
    outcomes = [found.outcome(step) for step in steps]
    assert isinstance(outcomes[0], SkipTest) and str(outcomes[0]) == "a robot's live feed"
    assert outcomes[1] is None and outcomes[2] is None and outcomes[3] is None  # the exit status shown, 2
    assert isinstance(outcomes[4], AssertionError) and "exit status 1, not 0" in str(outcomes[4])
    assert "docs test: this command failed: false" in str(outcomes[4])
    assert isinstance(outcomes[5], SkipTest) and "an earlier block of the page failed" in str(outcomes[5])
    assert outcomes[6] is None
    assert (found.runs["page.md"].folder / "hello.sh").is_file()  # the file block saved, not run


def test_a_page_whose_figures_differ_from_its_run_fails(tmp_path):
    found, steps = runs(tmp_path, "64.2")
    output, figure = found.outcome(steps[2]), found.outcome(steps[6])
    assert "this shown line is not printed" in str(output) and "frame accuracy ... test 64.1%" in str(output)
    assert str(figure).endswith("the page quotes 64.1, the run printed 64.2 (not equal)")


def test_a_skip_must_say_why(tmp_path):
    (tmp_path / "page.md").write_text("<!-- skip: next -->\n```bash\nexit 1\n```\n")
    with pytest.raises(ValueError, match="must say why"):
        doc_pages.parse(tmp_path / "page.md")


@pytest.mark.parametrize(("quoted", "measured", "tolerance", "within"), [
    ("5,000", "5000", None, True), ("64.1", "64.2", None, False), ("64.1", "64.4", "0.5", True),
    ("15", "40", "4x", True), ("15", "70", "4x", False),
])
def test_tolerances(quoted, measured, tolerance, within):
    assert doc_pages.within(quoted, measured, tolerance) is within


def test_every_page_parses_and_each_skip_says_why():
    for path in doc_pages.pages():
        document = doc_pages.parse(path)  # a skip without its reason raises here
        assert all(step.page == doc_pages.page_name(path) for step in doc_pages.steps(document))


def test_make_docs_figures_writes_what_the_run_printed_into_the_page(tmp_path, monkeypatch):
    monkeypatch.setattr(doc_pages, "WRITE", True)
    found, steps = runs(tmp_path, "64.2")
    assert [found.outcome(step) for step in steps[1:3] + steps[6:7]] == [None, None, None]
    assert doc_pages.write_figures() == ["page.md"]
    text = (tmp_path / "page.md").read_text()
    assert "frame accuracy ... test 64.2%\n" in text and "The test figure is 64.2 %<!-- figure: test {}% -->" in text
