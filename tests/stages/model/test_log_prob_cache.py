"""The network log-probability cache: a workdir linking another's network reads the values its first run stored;
what they were computed from changing computes them again."""

import os
import shutil

import numpy as np

from mlnseq.catalog import artifacts
from mlnseq.model import log_prob_cache
from mlnseq.choosing.workdir_inputs import read_workdir


def _linked_copy(source, target):
    target.mkdir()
    for name in (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS):
        os.symlink(source / name, target / name)
    (target / "models").mkdir()
    os.symlink(source / "models" / "lstm.pt", target / "models" / "lstm.pt")


def _store(cache, key, values):
    with open(cache, "wb") as handle:
        handle.write(key.encode() + b"\n")
        np.save(handle, values)


def test_a_linked_network_is_run_once_and_read_back(tmp_path, desk_full_workdir):
    source = tmp_path / "source"
    shutil.copytree(desk_full_workdir, source)
    first = read_workdir(source, ["lstm"]).networks["lstm"].log_probs
    cache = artifacts.log_probs_cache_path(source / "models" / "lstm.pt")
    assert cache.parent == source / "models" and cache.exists()
    _linked_copy(source, tmp_path / "linked")
    assert artifacts.log_probs_cache_path(tmp_path / "linked" / "models" / "lstm.pt") == cache
    # the stored values are what a linked workdir reads: mark them to see that they, not a new run, come back
    key = log_prob_cache.cache_key(source / "models" / "lstm.pt", source / artifacts.FRAMES, None)
    _store(cache, key, first + 1)
    np.testing.assert_array_equal(read_workdir(tmp_path / "linked", ["lstm"]).networks["lstm"].log_probs, first + 1)
    # other frames: another key, computed again (and stored again)
    _store(cache, "stale", first + 1)
    np.testing.assert_array_equal(read_workdir(tmp_path / "linked", ["lstm"]).networks["lstm"].log_probs, first)
    cache.write_bytes(b"not a cache")
    np.testing.assert_array_equal(read_workdir(source, ["lstm"]).networks["lstm"].log_probs, first)
