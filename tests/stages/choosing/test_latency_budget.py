"""fit's budget in choosing/latency.py: the budget from --lag, --latency and --offline, and the decoders and lags
conflate scores within it (catalog/decoders.py's online decoders; the -legal forms only with hard rules)."""

from __future__ import annotations

import pytest

from mlnseq.catalog.decoders import DEFAULT_LAGS, OFFLINE, ONLINE, Decoder
from mlnseq.catalog.errors import BadInput
from mlnseq.choosing.latency import fit_budget, scored_within


def test_the_budget_is_lag_0_by_default_none_offline_and_latency_at_the_rate():
    assert fit_budget(None, None, False, None) == 0
    assert fit_budget(None, None, True, 50.0) is None
    assert fit_budget(7, None, False, None) == 7
    assert fit_budget(None, 0.2, False, 50.0) == 10
    with pytest.raises(BadInput, match="--latency: the frame rate of the source's recordings is not known; give the "
                                       "budget as --lag FRAMES"):
        fit_budget(None, 0.2, False, None)


@pytest.mark.parametrize("hard", [False, True])
def test_within_a_budget_the_online_decoders_at_the_lags_up_to_it(hard):
    decoders, lags = scored_within(7, hard)
    assert lags == (0, 1, 2, 5, 7)
    assert decoders[0] is Decoder.NONE and set(decoders[1:]) <= set(ONLINE) and not set(decoders) & set(OFFLINE)
    assert any(d.value.endswith("-legal") for d in decoders) is hard
    assert {d.free for d in decoders} == {Decoder.NONE, Decoder.FILTER, Decoder.SMOOTH, Decoder.LAGVITERBI}
    assert scored_within(0, hard)[1] == (0,)


def test_offline_every_decoder_at_conflates_default_lags():
    decoders, lags = scored_within(None, True)
    assert decoders == tuple(Decoder) and lags == DEFAULT_LAGS
    assert scored_within(None, False)[0] == tuple(d for d in Decoder if not d.value.endswith("-legal"))
