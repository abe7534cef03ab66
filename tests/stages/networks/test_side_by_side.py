"""Networks fitted side by side (the fold networks of `train --folds K`, the seeds of `train --seed A --seed B ...`)
make the updates each makes alone: on the real DESK folds and segments, in float64 so that rounding stays far below
what a wrong update would change."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from mlnseq import networks
from mlnseq.catalog import artifacts
from mlnseq.catalog.methods import PaperFloor, Prior
from mlnseq.networks import recurrent
from mlnseq.networks.fitting import Fitting, Schedule, SideBySide, Together, fit_together
from mlnseq.networks.updates import Optimizer, Training
from mlnseq.choosing import folds as folding
from mlnseq.fusion.fuse import prior_input
from mlnseq.choosing.workdir_inputs import FrameData, mln_class_scores
from mlnseq.train import Rows, TrainOptions

EPOCHS, BATCH, RATE = 3, 4, 0.1


def in_float64(fitting: Fitting) -> Fitting:
    fitting.model.double()
    fitting.tensors = tuple(t.double() if t is not None and t.is_floating_point() else t for t in fitting.tensors)
    return fitting


def started(data: FrameData, folds: folding.Folds, config, options: TrainOptions) -> list[Fitting]:
    fittings = []
    for k in range(folds.k):
        fold_data = replace(data, splits=folds.splits(k))
        fittings.append(in_float64(Rows.of(fold_data, options).start(fold_data, config, options, torch.device("cpu"))))
    return fittings


def assert_each_ends_where_alone(alone: list[Fitting], together: list[Fitting]) -> None:
    initial = together[0].model.h2c.weight.detach().clone()
    for fitting in alone:
        for _ in range(EPOCHS):
            fitting.epoch(BATCH, RATE)
    fit_together(together, EPOCHS, BATCH, RATE)

    assert (together[0].model.h2c.weight - initial).abs().max() > 1e-3  # they trained
    for one, batched in zip(alone, together):
        for name, parameter in one.model.named_parameters():
            torch.testing.assert_close(batched.model.get_parameter(name), parameter, rtol=0, atol=1e-12, msg=name)


@pytest.mark.parametrize("cell, prior_layer, smoothing",
                         [("tcn", False, 0.0), ("tcn", True, 0.15), ("lstm", False, 0.0), ("gru", True, 0.0)])
def test_fold_networks_fitted_side_by_side_end_where_each_fitted_alone_ends(desk_mln_workdir, cell, prior_layer,
                                                                            smoothing):
    frames, meta = artifacts.read_table(desk_mln_workdir / artifacts.FRAMES, "frames")
    prior = None
    if prior_layer:
        scores, _ = mln_class_scores(desk_mln_workdir, frames, meta["classes"])
        prior = prior_input(scores, Prior.PAPER, PaperFloor.for_recordings(meta["source"]))
    data = FrameData.from_frames(frames, prior)
    options = TrainOptions(mode="stream", cell=cell)
    extra = {"smoothing": smoothing} if cell == "tcn" else {}
    config = networks.make_config(cell, n_features=data.features.shape[1], n_classes=len(meta["classes"]),
                                  prior_layer=prior_layer, **extra)
    folds = folding.assign(data.episodes, data.splits, data.labels, 3)
    alone, together = started(data, folds, config, options), started(data, folds, config, options)
    units = [len(f.tensors[3]) for f in alone]
    assert len(set(units)) > 1 and any(n % BATCH for n in units)  # some networks wait, some batches are short
    assert isinstance(Together(together).groups[0], SideBySide)
    assert_each_ends_where_alone(alone, together)


def test_seeds_fitted_side_by_side_in_groups_end_where_each_fitted_alone_ends(desk_mln_workdir):
    """Segment mode's seeds: 64-unit LSTMs go side by side two at a time, so 3 seeds make a pair and one alone."""
    frames, meta = artifacts.read_table(desk_mln_workdir / artifacts.FRAMES, "frames")
    data = FrameData.from_frames(frames)
    options = TrainOptions(mode="segment", hidden_size=64)
    config = networks.make_config("lstm", n_features=data.features.shape[1], n_classes=len(meta["classes"]),
                                  hidden_size=64)
    rows = Rows.of(data, options)

    def seeds() -> list[Fitting]:
        return [in_float64(rows.start(data, config, replace(options, seed=seed), torch.device("cpu")))
                for seed in (0, 1, 2)]

    alone, together = seeds(), seeds()
    assert [type(group) for group in Together(together).groups] == [SideBySide, Fitting]
    assert_each_ends_where_alone(alone, together)


@pytest.mark.parametrize("cell, gates", [("lstm", 4), ("gru", 3)])
def test_recurrent_networks_side_by_side_are_one_block_diagonal_layer_whose_blocks_alone_learn(cell, gates):
    torch.manual_seed(0)
    config = recurrent.Config(n_features=3, n_classes=2, hidden_size=5, cell=cell)
    stacked = {name: torch.randn(2, *shape, dtype=torch.float64)
               for name, shape in recurrent.body_shapes(config).items()}
    weights = recurrent.side_by_side_weights(config, stacked)
    for name, back in recurrent.side_by_side_stacked(config, weights, 2).items():
        assert torch.equal(back, stacked[name]), name
    layer = weights["rnn.weight_hh_l0"]
    blocks = layer.view(gates, 2, 5, 2, 5)  # gate, network, unit, network read, unit read
    assert (blocks[:, 0, :, 1] == 0).all() and (blocks[:, 1, :, 0] == 0).all()
    (layer * torch.randn_like(layer)).sum().backward()
    gradient = layer.grad.view(gates, 2, 5, 2, 5)
    assert (gradient[:, 0, :, 1] == 0).all() and (gradient[:, 1, :, 0] == 0).all() and (gradient[:, 0, :, 0] != 0).all()


@pytest.mark.parametrize("cell, optimizer", [("lstm", Optimizer.ADAM), ("tcn", Optimizer.AVERAGED)])
def test_settled_networks_fitted_side_by_side_end_where_each_fitted_alone_ends(desk_mln_workdir, cell, optimizer):
    """Adam's or averaged SGD's budget of updates: each network draws its own batches, makes the same number of
    updates and keeps its weights' moving average, alone or beside the others."""
    frames, meta = artifacts.read_table(desk_mln_workdir / artifacts.FRAMES, "frames")
    data = FrameData.from_frames(frames)
    options = TrainOptions(mode="stream", cell=cell)
    config = networks.make_config(cell, n_features=data.features.shape[1], n_classes=len(meta["classes"]))
    folds = folding.assign(data.episodes, data.splits, data.labels, 3)
    alone, together = started(data, folds, config, options), started(data, folds, config, options)
    training, units = Training(optimizer, EPOCHS, BATCH), max(len(f.tensors[3]) for f in alone)
    initial = together[0].model.h2c.weight.detach().clone()
    for fitting in alone:
        Schedule([fitting], training, units).run()
    Schedule(together, training, units).run()
    assert (together[0].model.h2c.weight - initial).abs().max() > 1e-3  # they trained
    for one, batched in zip(alone, together):
        for name, parameter in one.model.named_parameters():
            torch.testing.assert_close(batched.model.get_parameter(name), parameter, rtol=0, atol=1e-10, msg=name)
