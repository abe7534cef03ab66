"""The learners' one-BLAS-thread block sets and restores the thread count of numpy's and scipy's OpenBLAS."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from stages.mln import blas


def test_one_thread_sets_and_restores() -> None:
    linalg.cholesky(np.eye(3))  # make sure scipy's BLAS is loaded too
    libraries = blas._libraries()
    if not libraries:
        pytest.skip("no OpenBLAS loaded in this process (another BLAS): the block changes nothing")
    before = [getter() for _, getter in libraries]
    with blas.one_thread():
        assert [getter() for _, getter in libraries] == [1] * len(libraries)
    assert [getter() for _, getter in libraries] == before
