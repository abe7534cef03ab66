"""What docs/deploy.md says export does with a --decode the workdir's conflate did not score: filter and viterbi
are exported (decided as conflate decides them), a lagged or legal decoder is refused in one line."""

from __future__ import annotations

import re

from typer.testing import CliRunner

from mlnseq_cli.main import app
from mlnseq.catalog import artifacts

runner = CliRunner()
PAGE_SAYS = "a lagged or `-legal` `--decode` the workdir's conflate did not\nscore. `filter` and `viterbi` are exported"


def test_the_page_says_it(repo_root):
    assert PAGE_SAYS in (repo_root / "docs" / "deploy.md").read_text()


def test_filter_is_exported_where_conflate_scored_no_decoding(desk_full_workdir, tmp_path):
    scored = artifacts.read_metadata(desk_full_workdir / artifacts.PREDICTIONS, "predictions")["methods"]
    assert "mln" in scored and not any("+" in name for name in scored)  # the bare conflate: no decoding scored
    done = runner.invoke(app, ["export", "--method", "mln", "--decode", "filter", "-o", str(tmp_path / "m.mlnseq"),
                               "-w", str(desk_full_workdir)])
    assert done.exit_code == 0, done.output
    assert (tmp_path / "m.mlnseq").is_file()


def test_a_lagged_decoder_conflate_did_not_score_is_refused(desk_full_workdir, tmp_path):
    done = runner.invoke(app, ["export", "--method", "mln", "--decode", "smooth-legal", "--lag", "2", "-o",
                               str(tmp_path / "m.mlnseq"), "-w", str(desk_full_workdir)])
    assert done.exit_code == 2
    assert re.search(r"no mln\+smooth-legal@2 predictions; run `mlnseq conflate --decode smooth-legal --lags 2`",
                     done.stderr)
    assert not (tmp_path / "m.mlnseq").exists()
