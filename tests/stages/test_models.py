"""The networks: shapes, causality under padding, PriorLayer input."""

import pytest
import torch

from stages.models import ModelConfig, SequenceClassifier


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
