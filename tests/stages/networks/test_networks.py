"""The torch networks of every registered type: shapes, causality under padding, PriorLayer input; the registry."""

import pytest
import torch

from mlnseq import networks
from mlnseq.catalog.errors import BadInput
from mlnseq.networks.classifier import SequenceClassifier, merged
from mlnseq.networks.recurrent import Config as ModelConfig


@pytest.mark.parametrize("cell", networks.CELLS)
def test_padding_after_a_sequence_does_not_change_its_outputs(cell):
    torch.manual_seed(0)
    model = SequenceClassifier(networks.make_config(cell, n_features=3, n_classes=4)).eval()
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


def test_the_checkpoint_dict_of_a_recurrent_network_is_the_one_older_checkpoints_hold():
    config = networks.make_config("gru", n_features=3, n_classes=4, hidden_size=8, prior_layer=True)
    saved = {"n_features": 3, "n_classes": 4, "hidden_size": 8, "cell": "gru", "prior_layer": True}
    assert config.to_dict() == saved
    assert networks.config_of(saved) == config
    assert networks.describe(saved) == "gru of 8"


def test_an_option_of_another_network_type_is_refused():
    with pytest.raises(BadInput, match="--smoothing 0.15: the lstm network has no such option .*tcn"):
        networks.make_config("lstm", n_features=3, n_classes=4, smoothing=0.15)
    with pytest.raises(BadInput, match="unknown network type 'rnn': choose one of lstm, gru, tcn"):
        networks.module_of("rnn")


def test_the_tcn_sees_exactly_its_receptive_field():
    from mlnseq.networks.tcn import receptive_field

    torch.manual_seed(0)
    config = networks.make_config("tcn", n_features=3, n_classes=4, kernel_size=3, levels=3)
    field = receptive_field(3, 3)
    assert field == 15
    model = SequenceClassifier(config).eval()
    x = torch.randn(1, 40, 3)
    changed = x.clone()
    changed[0, 10] += 5.0
    moved = (model(x)[0] - model(changed)[0]).abs().amax(-1)[0] > 1e-6
    assert moved.nonzero().flatten().tolist() == list(range(10, 10 + field))  # frames 10 .. 10 + r - 1 only


def test_the_smoothing_loss_penalises_changes_between_real_frames_only():
    torch.manual_seed(0)
    smooth = SequenceClassifier(networks.make_config("tcn", n_features=3, n_classes=4, smoothing=0.15))
    assert SequenceClassifier(networks.make_config("tcn", n_features=3, n_classes=4)).auxiliary_loss(
        torch.zeros(1, 3, 4), torch.ones(1, 3, dtype=torch.bool)) is None
    steady = torch.log_softmax(torch.zeros(1, 4, 4), -1)
    jump = steady.clone()
    jump[0, 2:] = torch.log_softmax(torch.tensor([9.0, 0.0, 0.0, 0.0]), -1)
    valid = torch.ones(1, 4, dtype=torch.bool)
    assert float(smooth.auxiliary_loss(steady, valid)) == 0.0
    # one change of 3 between frames 1 and 2 (class 0: log 1/4 -> about 0): 0.15 * (its squared change, truncated
    # at 16, averaged over the 4 classes) / 3 pairs
    delta = (jump[0, 2] - steady[0, 1]).pow(2).clamp(max=16).mean()
    torch.testing.assert_close(smooth.auxiliary_loss(jump, valid), 0.15 * delta / 3)
    padded = valid.clone()
    padded[0, 2:] = False  # the jump falls on padding: nothing to smooth
    assert float(smooth.auxiliary_loss(jump, padded)) == 0.0


@pytest.mark.parametrize("cell", networks.CELLS)
@pytest.mark.parametrize("prior_layer", [False, True])
def test_networks_merged_into_one_predict_the_mean_of_their_class_scores(cell, prior_layer):
    """`train --members`: the networks of a seed kept as one wider network of their type, exactly their ensemble."""
    config = networks.make_config(cell, n_features=3, n_classes=4, hidden_size=6, prior_layer=prior_layer)
    members = []
    for seed in range(3):
        torch.manual_seed(seed)
        members.append(SequenceClassifier(config).double().eval())
        with torch.no_grad():
            for parameter in members[-1].parameters():
                parameter.add_(torch.randn_like(parameter) * 0.3)
    x = torch.randn(2, 40, 3, dtype=torch.float64)
    prior = torch.randn(2, 40, 4, dtype=torch.float64) if prior_layer else None
    one = merged(members).double().eval()
    assert one.config.hidden_size == 18 and networks.config_of(one.config.to_dict()) == one.config
    with torch.no_grad():
        mean = torch.log_softmax(sum(member(x, prior)[0] for member in members) / 3, -1)
        torch.testing.assert_close(one(x, prior)[0], mean, rtol=0, atol=1e-12)
    assert merged(members[:1]) is not members[0]  # one: a copy
