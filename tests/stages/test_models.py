"""The networks: shapes, causality under padding, PriorLayer input, per-frame streaming."""

import numpy as np
import pytest
import torch

from stages.models import ModelConfig, SequenceClassifier, StreamingClassifier


@pytest.mark.parametrize("cell", ["lstm", "gru"])
def test_padding_after_a_sequence_does_not_change_its_outputs(cell):
    torch.manual_seed(0)
    model = SequenceClassifier(ModelConfig(n_features=3, n_classes=4, cell=cell)).eval()
    x = torch.randn(1, 7, 3)
    padded = torch.cat([x, torch.zeros(1, 5, 3)], dim=1)
    alone, _ = model(x)
    with_padding, _ = model(padded)
    assert alone.shape == (1, 7, 4)
    torch.testing.assert_close(alone, with_padding[:, :7])
    torch.testing.assert_close(alone.exp().sum(-1), torch.ones(1, 7))


def test_prior_layer_reads_the_mln_input_and_requires_it():
    torch.manual_seed(0)
    model = SequenceClassifier(ModelConfig(n_features=3, n_classes=4, prior_layer=True)).eval()
    x = torch.randn(2, 5, 3)
    a, _ = model(x, torch.zeros(2, 5, 4))
    b, _ = model(x, torch.full((2, 5, 4), 3.0))
    assert not torch.allclose(a, b)
    with pytest.raises(ValueError):
        model(x)


def test_streaming_steps_match_the_whole_sequence():
    torch.manual_seed(0)
    model = SequenceClassifier(ModelConfig(n_features=3, n_classes=4)).eval()
    raw = np.random.default_rng(0).normal(5.0, 2.0, size=(9, 3)).astype(np.float32)
    mean, std = raw.mean(0), raw.std(0)
    whole = model(torch.from_numpy((raw - mean) / std)[None])[0][0].exp().detach().numpy()
    stream = StreamingClassifier(model, mean, std)
    stepped = np.stack([stream.step(frame) for frame in raw])
    np.testing.assert_allclose(stepped, whole, rtol=1e-5, atol=1e-6)
    stream.reset()
    np.testing.assert_allclose(stream.step(raw[0]), whole[0], rtol=1e-5, atol=1e-6)
