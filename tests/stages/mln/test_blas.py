"""The learners' one-BLAS-thread block sets and restores the thread count of numpy's and scipy's OpenBLAS."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import linalg

from mlnseq.mln import blas


def test_one_thread_sets_and_restores() -> None:
    linalg.cholesky(np.eye(3))  # make sure scipy's BLAS is loaded too
    libraries = blas._libraries()
    if not libraries:
        pytest.skip("no OpenBLAS loaded in this process (another BLAS): the block changes nothing")
    before = [getter() for _, getter in libraries]
    for setter, _ in libraries:  # stages/__init__ already asked for one thread: start from two
        setter(2)
    try:
        two = [getter() for _, getter in libraries]
        if two != [2] * len(libraries):
            pytest.skip(f"OpenBLAS here runs at most {min(two)} thread(s): one thread cannot be told apart")
        with blas.one_thread():
            assert [getter() for _, getter in libraries] == [1] * len(libraries)
        assert [getter() for _, getter in libraries] == two
    finally:
        for (setter, _), threads in zip(libraries, before):
            setter(threads)


def test_a_block_inside_another_keeps_its_setting() -> None:
    libraries = blas._libraries()
    if not libraries:
        pytest.skip("no OpenBLAS loaded in this process (another BLAS): the block changes nothing")
    before = [getter() for _, getter in libraries]
    try:
        with blas.one_thread():
            for setter, _ in libraries:  # what the outer block holds, changed inside it
                setter(2)
            if [getter() for _, getter in libraries] != [2] * len(libraries):
                pytest.skip("OpenBLAS here runs at most one thread: the inner block's setting cannot be told apart")
            with blas.one_thread():
                inner = [getter() for _, getter in libraries]
            after_inner = [getter() for _, getter in libraries]
        assert inner == after_inner  # the inner block neither set one thread nor restored anything
        assert [getter() for _, getter in libraries] == before  # the outer block restored what it found
    finally:
        for (setter, _), threads in zip(libraries, before):
            setter(threads)
