"""Install lines that are true: mlnseq is on no package index, so no page, example or message installs it by
name from one; `all` is every extra; the missing-extra message says how to add one from the checkout or the
wheel."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

from mlnseq.catalog import errors

REPO = Path(__file__).resolve().parents[2]
# `pip install mlnseq`, `pip install 'mlnseq[all]'`, `pipx install "mlnseq[train]"`: mlnseq by name, from an index
BY_NAME = re.compile(r"\bpipx? install (?:-\S+ )*['\"]?mlnseq(?:\[[\w,]*\])?['\"]?(?![\w.-])")


def texts() -> dict[Path, str]:
    paths = [REPO / "README.md", *(REPO / "docs").glob("*.md"), *(REPO / "examples").rglob("*.md"),
             *(REPO / "stages").rglob("*.py"), *(REPO / "mlnseq_cli").rglob("*.py"), *(REPO / "scripts").iterdir(),
             REPO / "Makefile", REPO / "pyproject.toml"]
    return {path: path.read_text(encoding="utf-8") for path in paths if path.is_file()}


def test_the_pattern_finds_an_install_by_name_and_not_from_the_checkout_or_a_wheel():
    for line in ("pip install mlnseq", "pip install 'mlnseq[all]'", 'pipx install "mlnseq[train]"'):
        assert BY_NAME.search(line), line
    for line in ("pip install '.[all]'", "pip install 'mlnseq-0.1.0-py3-none-any.whl[train]'",
                 "pip install mlnseq-0.1.0-py3-none-any.whl"):
        assert not BY_NAME.search(line), line


def test_no_page_example_or_message_installs_mlnseq_from_an_index():
    found = [f"{path.relative_to(REPO)}: {match.group(0)}" for path, text in texts().items()
             for match in BY_NAME.finditer(text)]
    assert found == []


def test_all_is_every_extra():
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    [named] = extras["all"]
    listed = set(re.fullmatch(r"mlnseq\[([\w,]+)\]", named).group(1).split(","))
    assert listed == set(extras) - {"all", "test"}


def test_a_missing_extra_says_how_to_add_it_from_the_checkout_or_beside_the_wheel():
    error = errors.missing_extra(ModuleNotFoundError("No module named 'torch'", name="torch"))
    assert str(error) == ("training needs torch, which is not installed: pip install '.[train]' in mlnseq's checkout, "
                          "or pip install 'mlnseq-0.1.0-py3-none-any.whl[train]' beside the wheel")
    assert error.exit_code == 2
