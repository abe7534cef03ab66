"""`audit --write-lerobot`'s copy of a dataset LeRobot 0.6.1 wrote (../shared/data/lerobot-0.6.1): per-episode
columns added to its episodes' metadata, every other file byte for byte, the source unread but for its bytes, and
the refusals in one line. The copy through `mlnseq audit` (a failed episode among them) and LeRobot itself filtering
it are tests/stages/sources/test_lerobot_round_trip.py's."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from mlnseq.catalog.errors import BadInput
from mlnseq.sources import lerobot_episodes

EPISODES = Path("meta/episodes/chunk-000/file-000.parquet")


def digests(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def source(shared_data) -> Path:
    return shared_data / "lerobot-0.6.1" / "pick-place"


def columns(verdicts: dict[int, str]) -> dict[str, dict[int, object]]:
    return {"mlnseq_verdict": verdicts, "mlnseq_score": {e: 2.5 if v == "suspect" else 0.0 for e, v in verdicts.items()},
            "mlnseq_reasons": {e: ["grasp again after lift (1.00-2.00 s)"] if v == "suspect" else []
                               for e, v in verdicts.items()}}


def test_the_columns_join_the_episodes_metadata_and_nothing_else_changes(source, tmp_path):
    before = digests(source)
    verdicts = {e: "suspect" if e in (2, 5) else "ok" for e in range(8)}
    out = tmp_path / "copy"
    out.mkdir()
    assert lerobot_episodes.write(out, source, columns(verdicts)) == 8
    assert digests(source) == before
    copied = digests(out)
    assert {k: v for k, v in copied.items() if k != str(EPISODES)} == {k: v for k, v in before.items()
                                                                      if k != str(EPISODES)}
    old, new = pq.read_table(source / EPISODES), pq.read_table(out / EPISODES)
    assert new.schema.names == old.schema.names + ["mlnseq_verdict", "mlnseq_score", "mlnseq_reasons"]
    assert new.select(old.schema.names).equals(old)
    rows = new.to_pylist()
    assert [row["mlnseq_verdict"] for row in rows] == [verdicts[row["episode_index"]] for row in rows]
    assert rows[2]["mlnseq_reasons"] == ["grasp again after lift (1.00-2.00 s)"] and rows[0]["mlnseq_reasons"] == []
    assert pq.ParquetFile(out / EPISODES).metadata.row_group(0).column(0).compression == "SNAPPY"


def test_an_episode_left_out_or_a_column_there_already_is_one_line(source, tmp_path):
    (tmp_path / "a").mkdir()
    with pytest.raises(BadInput, match="episode 7 was not audited .*audit the whole dataset"):
        lerobot_episodes.write(tmp_path / "a", source, columns({e: "ok" for e in range(7)}))
    (tmp_path / "b").mkdir()
    with pytest.raises(BadInput, match="episode 8 was audited but is in no episodes file"):
        lerobot_episodes.write(tmp_path / "b", source, columns({e: "ok" for e in range(10)}))
    (tmp_path / "c").mkdir()
    lerobot_episodes.write(tmp_path / "c", source, columns({e: "ok" for e in range(8)}))
    (tmp_path / "d").mkdir()
    with pytest.raises(BadInput, match="has a column 'mlnseq_verdict' already"):
        lerobot_episodes.write(tmp_path / "d", tmp_path / "c", columns({e: "ok" for e in range(8)}))
