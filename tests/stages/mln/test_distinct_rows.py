"""distinct_rows: np.unique(axis=0)'s rows, order, inverse and counts, on DESK's evidence and on edge shapes."""

import numpy as np
import polars as pl
import pytest

from mlnseq.catalog import artifacts
from mlnseq.mln.distinct_rows import distinct_row_counts, distinct_rows


def _same_as_numpy(values: np.ndarray) -> None:
    expected, inverse = np.unique(values, axis=0, return_inverse=True)
    _, counts = np.unique(values, axis=0, return_counts=True)
    distinct, found = distinct_rows(values)
    assert distinct.dtype == bool and np.array_equal(distinct, expected)
    assert np.array_equal(found, inverse.reshape(-1))
    assert np.array_equal(distinct_row_counts(values)[1], counts)


def test_distinct_rows_of_desk_evidence_and_its_pairs_equal_numpy_unique(desk_mln_workdir):
    predicates = pl.read_parquet(desk_mln_workdir / artifacts.PREDICATES)
    evidence = predicates.select(artifacts.feature_columns(predicates)).to_numpy().astype(bool)
    assert evidence.shape[1] > 8  # more than one packed byte a row
    _same_as_numpy(evidence)
    _same_as_numpy(np.concatenate([evidence[:-1], evidence[1:]], axis=1))  # consecutive pairs
    _same_as_numpy(evidence[:, [3, 0, 5]])  # a few columns read out of order


@pytest.mark.parametrize("shape", [(0, 3), (5, 0), (0, 0), (1, 1), (40, 9)])
def test_distinct_rows_on_edge_shapes(shape):
    _same_as_numpy(np.random.default_rng(1).random(shape) < 0.5)


def test_distinct_rows_refuses_what_is_not_a_bool_matrix():
    with pytest.raises(TypeError):
        distinct_rows(np.zeros((3, 2), dtype=np.int64))
