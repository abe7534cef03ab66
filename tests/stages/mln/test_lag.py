"""Lagged and legal decoders (mlnseq.mln.lag) on real chains: DESK with the hard order (examples/desk.order.mln)
and Fetch with learned transitions; online one frame at a time against the whole recording at once."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from mlnseq.catalog.decoders import Decoder, Decoding, decodings, parse_decoding, parse_lags
from mlnseq.catalog.errors import BadInput
from mlnseq.mln import chain, lag, lag_online
from mlnseq.mln.chain import ChainFactors

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


def chain_of_workdir(workdir) -> tuple[ChainFactors, np.ndarray, np.ndarray]:
    """The MLN's chain over every frame of a workdir (cut at episodes and splits), the labels and the test rows."""
    from mlnseq.mln.factors import MLNFactors
    from mlnseq.choosing.workdir_inputs import read_workdir

    inputs = read_workdir(workdir, ())
    mln = MLNFactors.from_weights(inputs.mln.weights, inputs.mln.columns, inputs.classes)
    data = inputs.data
    return (mln.chain(inputs.mln.evidence, chain.chain_starts(data.episodes, data.splits)), data.labels,
            data.splits == "test")


def learned_workdir(tmp_path_factory, frames_workdir, spec: str, name: str):
    from mlnseq import binarize, formulas, learn_weights

    workdir = tmp_path_factory.mktemp(name)
    shutil.copy(frames_workdir / "frames.parquet", workdir / "frames.parquet")
    binarize.run(workdir, binarize.BinarizeOptions())
    formulas.run(workdir, formulas.FormulasOptions(spec=EXAMPLES / spec))
    learn_weights.run(workdir, learn_weights.LearnWeightsOptions())
    return workdir


@pytest.fixture(scope="module")
def desk_order(tmp_path_factory, desk_frames_workdir):
    return chain_of_workdir(learned_workdir(tmp_path_factory, desk_frames_workdir, "desk.order.mln", "desk-order"))


@pytest.fixture(scope="module")
def fetch_temporal(tmp_path_factory, fetch_frames_workdir):
    return chain_of_workdir(learned_workdir(tmp_path_factory, fetch_frames_workdir, "temporal.mln", "fetch-temporal"))


def head(factors: ChainFactors, frames: int) -> ChainFactors:
    return ChainFactors(factors.unary[:frames], factors.pairwise, factors.link[:frames])


def online_finals(factors: ChainFactors, decoding: Decoding, together: int = 1) -> tuple[list, int]:
    """The frames decided one frame at a time (pending frames decided at each chain's end), ``together`` frames
    stepped before each ``decide``, and the most frames held."""
    decoder, out, held = lag_online.Online(factors.n_classes, decoding), [], 0
    for t, row in enumerate(factors.link):
        if row < 0:
            out += decoder.finish()
        out += decoder.step(factors.unary[t], None if row < 0 else factors.pairwise[row], decide=False)
        if (t + 1) % together == 0:
            out += decoder.decide()
        held = max(held, decoder.pending)
    out += decoder.finish()
    assert [final.index for final in out] == list(range(len(factors.link)))
    return out, held


def online(factors: ChainFactors, decoding: Decoding) -> tuple[np.ndarray, int]:
    """Classes one frame at a time, and the most frames held."""
    finals, held = online_finals(factors, decoding)
    return np.array([final.label for final in finals]), held


EVERY = [Decoding(Decoder.FILTER), Decoding(Decoder.FILTER_LEGAL), Decoding(Decoder.POSTERIOR),
         Decoding(Decoder.POSTERIOR_LEGAL)] + decodings((Decoder.SMOOTH, Decoder.SMOOTH_LEGAL, Decoder.LAGVITERBI,
                                                         Decoder.LAGVITERBI_LEGAL), (0, 2, 25))


@pytest.mark.parametrize("decoding", EVERY, ids=lambda d: d.name)
def test_online_gives_the_batch_classes_on_desk_with_bounded_state(desk_order, decoding):
    factors = head(desk_order[0], 1405 + 600)  # the training recording and the test recording's first 600 frames
    batch = lag.decode(factors, decoding)
    path, held = online(factors, decoding)
    np.testing.assert_array_equal(path, batch.path)
    if not decoding.decoder.offline:
        assert held <= decoding.lag + 1


@pytest.mark.parametrize("decoding", [Decoding(Decoder.SMOOTH_LEGAL, 25), Decoding(Decoder.LAGVITERBI, 2),
                                      Decoding(Decoder.POSTERIOR_LEGAL), Decoding(Decoder.FILTER_LEGAL)],
                         ids=lambda d: d.name)
def test_frames_decided_together_get_the_classes_and_probabilities_of_one_at_a_time(desk_order, decoding):
    """A stream decides the frames it read together at once (``step(..., decide=False)``, then ``decide``), their
    windows side by side: bit for bit what deciding each as it comes gives, whatever the number held back."""
    factors = head(desk_order[0], 1405 + 600)
    alone = online_finals(factors, decoding)[0]
    for together in (3, 4, 60, 5000):
        finals = online_finals(factors, decoding, together)[0]
        assert [final.restarted for final in finals] == [final.restarted for final in alone]
        np.testing.assert_array_equal([final.label for final in finals], [final.label for final in alone])
        np.testing.assert_array_equal(np.array([final.probabilities for final in finals]),
                                      np.array([final.probabilities for final in alone]), err_msg=str(together))


@pytest.mark.parametrize("n_classes", [3, 7, 8, 12])
@pytest.mark.parametrize("layout", ["runs", "alternating"])
def test_batch_gives_the_online_probabilities_bit_for_bit_at_any_class_count(n_classes, layout):
    """The batch backward step sums over the next class column by column where numpy's own sum of a row adds in that
    order (up to 7 classes) and with numpy's sum beyond; over long runs of one transition matrix class-major, over
    frames whose matrices alternate frame by frame: every way the numbers of the online decoder's row sums."""
    rng = np.random.default_rng(n_classes)
    frames = np.arange(2000)
    rows = (frames // 500) % 2 if layout == "runs" else frames % 2
    link = np.where(frames % 400 == 0, -1, rows)
    pairwise = rng.normal(0.0, 2.0, (2, n_classes, n_classes))
    factors = ChainFactors(rng.normal(0.0, 3.0, (2000, n_classes)), pairwise, link)
    for decoding in (Decoding(Decoder.SMOOTH, 4), Decoding(Decoder.LAGVITERBI, 3)):
        decoder, finals = lag_online.Online(n_classes, decoding), []
        for t, row in enumerate(link):
            finals += (decoder.finish() if row < 0 else []) + decoder.step(factors.unary[t],
                                                                           None if row < 0 else factors.pairwise[row])
        finals += decoder.finish()
        np.testing.assert_array_equal(np.array([final.probabilities for final in finals]),
                                      lag.decode(factors, decoding).probabilities, err_msg=decoding.name)


def test_decoding_with_every_decoder_at_once_gives_each_decoders_own_classes(desk_order):
    factors = desk_order[0]
    for decoding, shared in zip(EVERY, lag.decode_all(factors, EVERY)):
        alone = lag.decode(factors, decoding)
        np.testing.assert_array_equal(shared.path, alone.path, err_msg=decoding.name)
        np.testing.assert_array_equal(shared.probabilities, alone.probabilities, err_msg=decoding.name)


def test_chains_joined_one_after_another_decode_as_each_alone(desk_order):
    factors = desk_order[0]
    training, test = head(factors, 1405), ChainFactors(factors.unary[1405:], factors.pairwise, factors.link[1405:])
    joined = ChainFactors.joined([test, training])
    for decoding in (Decoding(Decoder.SMOOTH_LEGAL, 5), Decoding(Decoder.POSTERIOR), Decoding(Decoder.LAGVITERBI, 2)):
        together = lag.decode(joined, decoding).path
        np.testing.assert_array_equal(together[:len(test.link)], lag.decode(test, decoding).path)
        np.testing.assert_array_equal(together[len(test.link):], lag.decode(training, decoding).path)


def test_chains_decoded_at_once_get_each_chains_own_decoding(desk_order):
    """conflate decodes every method's chain at once (decoding.decode_each): chains with other frame factors and
    other transitions, side by side, get each its own classes, probabilities and dead ends."""
    from mlnseq.fusion import decoding as decoders

    factors = head(desk_order[0], 1405 + 1600)
    noise = np.random.default_rng(0).normal(0.0, 1.0, factors.unary.shape)
    other = ChainFactors(factors.unary + noise, factors.pairwise * 0.5, factors.link)  # -inf stays -inf
    parts = [factors, other, head(other, 700)]
    wanted = [*EVERY, Decoding(Decoder.VITERBI)]
    for part, together in zip(parts, decoders.decode_each(parts, wanted)):
        for decoding, got in zip(wanted, together):
            alone = decoders.decode_each([part], [decoding])[0][0]
            np.testing.assert_array_equal(got.path, alone.path, err_msg=decoding.name)
            np.testing.assert_array_equal(got.probabilities, alone.probabilities, err_msg=decoding.name)
            np.testing.assert_array_equal(got.restarts, alone.restarts, err_msg=decoding.name)


@pytest.mark.mujoco
@pytest.mark.parametrize("decoding", [Decoding(Decoder.SMOOTH_LEGAL, 5), Decoding(Decoder.LAGVITERBI, 1),
                                      Decoding(Decoder.FILTER_LEGAL)], ids=lambda d: d.name)
def test_online_gives_the_batch_classes_on_fetch_episodes(fetch_temporal, decoding):
    factors = fetch_temporal[0]
    assert (factors.link < 0).sum() >= 4  # several episodes, each its own chain
    np.testing.assert_array_equal(online(factors, decoding)[0], lag.decode(factors, decoding).path)


def test_lag_zero_smoothing_is_the_filter_and_a_whole_chain_lag_is_full_smoothing(desk_order):
    factors = desk_order[0]
    filtered = chain.decode_filter(factors).path
    np.testing.assert_array_equal(lag.decode(factors, Decoding(Decoder.SMOOTH, 0)).path, filtered)
    np.testing.assert_array_equal(lag.decode(factors, Decoding(Decoder.FILTER)).path, filtered)
    training = head(factors, 1405)  # one chain: the training recording
    whole = lag.decode(training, Decoding(Decoder.SMOOTH, 1405)).path
    np.testing.assert_array_equal(whole, lag.decode(training, Decoding(Decoder.POSTERIOR)).path)
    np.testing.assert_array_equal(whole, chain.smoothed(training).argmax(axis=1))
    np.testing.assert_array_equal(lag.decode(training, Decoding(Decoder.LAGVITERBI, 1405)).path,
                                  chain.viterbi(training))


def test_legal_forms_never_emit_a_transition_the_hard_order_forbids(desk_order):
    factors, labels, test = desk_order
    assert not test[:1405].any() and test[1405:].all()
    assert lag.forbidden_transitions(head(factors, 1405), labels[:1405]) == 0  # the training labels keep the order
    assert lag.forbidden_transitions(factors, chain.decode_filter(factors).path) > 100
    for decoding in (Decoding(Decoder.FILTER_LEGAL), Decoding(Decoder.SMOOTH_LEGAL, 5),
                     Decoding(Decoder.LAGVITERBI_LEGAL, 2), Decoding(Decoder.POSTERIOR_LEGAL)):
        free = lag.decode(factors, Decoding(decoding.decoder.free, decoding.lag))
        legal = lag.decode(factors, decoding)
        assert lag.forbidden_transitions(factors, free.path) > 0, decoding.name
        assert lag.forbidden_transitions(factors, legal.path) == 0, decoding.name


def test_smoothing_with_a_lag_beats_the_filter_on_desk_test(desk_order):
    factors, labels, test = desk_order
    accuracy = {lag_: (lag.decode(factors, Decoding(Decoder.SMOOTH, lag_)).path == labels)[test].mean()
                for lag_ in (0, 5, 25)}
    assert accuracy[0] < accuracy[5] < accuracy[25]


@pytest.mark.mujoco
def test_the_start_distribution_is_fitted_from_the_chains_first_frames(fetch_temporal):
    factors, labels, test = fetch_temporal
    starts = factors.link < 0
    start = lag.fit_start(labels[~test], starts[~test], factors.n_classes)
    assert np.isclose(np.exp(start).sum(), 1.0) and (np.exp(start) > 0).all()  # smoothed: no class impossible
    first = int(np.bincount(labels[starts]).argmax())  # every Fetch episode begins with the same class (reach)
    assert start.argmax() == first
    primed = lag.with_start(factors, start)
    np.testing.assert_allclose(primed.unary[starts] - factors.unary[starts],
                               np.broadcast_to(start, (starts.sum(), len(start))))
    assert (primed.unary[~starts] == factors.unary[~starts]).all()


def test_decodings_parse_and_refuse_bad_lags():
    assert parse_decoding("smooth-legal@5") == Decoding(Decoder.SMOOTH_LEGAL, 5)
    assert parse_decoding("filter").lag == 0 and parse_decoding("viterbi").lag is None
    assert parse_lags("25,0,5,5") == (0, 5, 25)
    for text, needle in (("smooth@-1", "at least 0"), ("smooth", "needs a lag"), ("blur@2", "unknown"),
                         ("smooth@x", "whole number"), ("viterbi@3", "takes no lag")):
        with pytest.raises(BadInput, match=needle):
            parse_decoding(text)
    with pytest.raises(BadInput, match="at least 0"):
        parse_lags("-1,2")
    names = [d.name for d in decodings((Decoder.FILTER, Decoder.SMOOTH, Decoder.LAGVITERBI_LEGAL), (0, 5))]
    assert names == ["filter", "smooth@5", "lagviterbi-legal@0", "lagviterbi-legal@5"]
