"""What every recogniser fuses (fusion/fuse.py): conflation is the paper's eq. 16, by hand."""

from __future__ import annotations

import numpy as np

from mlnseq.fusion import fuse


def test_conflation_is_equation_16():
    p_lstm = np.array([[0.7, 0.2, 0.1]])
    p_mln = np.array([[0.4, 0.4, 0.2]])
    # by hand: 0.28 / (0.28 + 0.3*0.6), 0.08 / (0.08 + 0.8*0.6), 0.02 / (0.02 + 0.9*0.8)
    expected = [[0.28 / 0.46, 0.08 / 0.56, 0.02 / 0.74]]
    np.testing.assert_allclose(fuse.conflation(p_lstm, p_mln), expected, rtol=1e-6)
    # two sources agreeing on a class strengthen it; a certain zero stays (near) zero
    assert fuse.conflation([[0.6, 0.4]], [[0.6, 0.4]])[0, 0] > 0.6
    assert fuse.conflation([[1.0, 0.0]], [[0.0, 1.0]]).max() <= 0.5 + 1e-9
