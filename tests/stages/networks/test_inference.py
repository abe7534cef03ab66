"""Every registered network type in numpy agrees with torch: whole sequences side by side, and one frame at a
time from its streaming state."""

import numpy as np
import pytest
import torch

from mlnseq.networks.network import Network, StreamingNetwork
from mlnseq import networks
from mlnseq.networks.classifier import SequenceClassifier


def trained_like(cell: str, prior_layer: bool) -> tuple[SequenceClassifier, Network, np.ndarray, np.ndarray]:
    """A torch network with random weights, its numpy twin, raw frames and an MLN input."""
    torch.manual_seed(0)
    config = networks.make_config(cell, n_features=3, n_classes=4, hidden_size=8, prior_layer=prior_layer)
    model = SequenceClassifier(config).eval()
    rng = np.random.default_rng(0)
    raw = rng.normal(5.0, 2.0, size=(80, 3)).astype(np.float32)
    prior = rng.normal(size=(80, 4)).astype(np.float32)
    network = Network.from_state(config.to_dict(), {k: v.numpy() for k, v in model.state_dict().items()},
                                 raw.mean(0), raw.std(0))
    return model, network, raw, prior


def torch_log_probs(model: SequenceClassifier, network: Network, raw: np.ndarray, prior: np.ndarray | None) -> np.ndarray:
    x = torch.from_numpy(((raw - network.mean) / network.std).astype(np.float32))[None]
    p = None if prior is None else torch.from_numpy(prior)[None]
    with torch.inference_mode():
        return model(x, p)[0][0].numpy()


@pytest.mark.parametrize("cell", networks.CELLS)
@pytest.mark.parametrize("prior_layer", [False, True])
def test_numpy_forward_matches_torch_on_batched_spans(cell, prior_layer):
    model, network, raw, prior = trained_like(cell, prior_layer)
    prior = prior if prior_layer else None
    spans = [slice(0, 7), slice(7, 80)]  # two sequences of different lengths, padded side by side
    expected = np.concatenate([torch_log_probs(model, network, raw[s], None if prior is None else prior[s])
                               for s in spans])
    np.testing.assert_allclose(network.log_probs(spans, raw, prior), expected, atol=1e-5)


@pytest.mark.parametrize("cell", networks.CELLS)
def test_streaming_steps_match_the_whole_sequence(cell):
    model, network, raw, prior = trained_like(cell, True)
    whole = torch_log_probs(model, network, raw, prior)
    stream = StreamingNetwork(network)
    stepped = np.stack([stream.step(frame, p) for frame, p in zip(raw, prior)])
    np.testing.assert_allclose(stepped, whole, atol=1e-5)
    stream.reset()
    np.testing.assert_allclose(stream.step(raw[0], prior[0]), whole[0], atol=1e-5)


def test_a_priorlayer_network_needs_its_mln_input():
    _, network, raw, _ = trained_like("lstm", True)
    with pytest.raises(ValueError, match="MLN class input"):
        StreamingNetwork(network).step(raw[0])
