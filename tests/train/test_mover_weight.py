"""The mover-weighted cross-entropy (``loss.mover_weight``, the ``head_movers`` recipe)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from lidarflow.errors import TrainError
from lidarflow.evaluate.dynamic import recording_region
from lidarflow.evaluate.stream import ground_truth_moving
from lidarflow.losses import LossConfig, next_map_bce
from lidarflow.models import build
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, simulate
from lidarflow.train import build_config, recipe, train
from lidarflow.train.config_io import config_from_dict, config_to_dict
from lidarflow.train.data import load_train_data
from lidarflow.train.movers import recording_regions, take_region
from lidarflow.train.objective import make_loss
from tests.conftest import FLOW_MODEL

GRID = GridSpec(40, 40, 0.05)


def _window(seed: int = 0, b: int = 2, t: int = 6, h: int = 5, w: int = 7):
    g = torch.Generator().manual_seed(seed)
    occ = (torch.rand(b, t, 1, h, w, generator=g) < 0.3).float()
    vis = torch.maximum(occ, (torch.rand(b, t, 1, h, w, generator=g) < 0.7).float())
    seq = torch.cat([occ, vis], dim=2)
    logits = torch.randn(b, t, 1, h, w, generator=g)
    region = torch.rand(b, t, h, w, generator=g) < 0.2
    return seq, logits, region


def test_weight_one_is_todays_loss_bit_for_bit():
    seq, logits, region = _window(t=10)
    plain = next_map_bce(seq, logits, warmup=2, visible_only=True)
    assert torch.equal(next_map_bce(seq, logits, 2, True, region=region, region_weight=1.0), plain)
    config = recipe("head_only")
    assert config.loss.mover_weight == 1.0 == LossConfig().mover_weight
    model = build(config.model.spec())
    loss = make_loss(config, 1, model)
    subcell = torch.rand(2, 10, 2, 5, 7)  # the head's sub-cell input channels
    full = torch.cat([seq, subcell], dim=2)
    with torch.no_grad():
        out, _ = model(full)
    assert torch.equal(loss(full, out, region), loss(full, out))


@pytest.mark.parametrize("visible_only", [True, False])
def test_the_weight_multiplies_exactly_the_target_frames_region_cells(visible_only):
    seq, logits, region = _window(seed=3)
    warmup, w = 2, 7.0
    got = next_map_bce(seq, logits, warmup, visible_only, region=region, region_weight=w)
    # by hand: each counted cell's cross-entropy, weighted by its visibility (or 1) and by w
    # where the *target* frame (t + 1) marks it dynamic
    target = seq[:, warmup + 1 :, 0]
    err = F.binary_cross_entropy_with_logits(logits[:, warmup:-1, 0], target, reduction="none")
    base = seq[:, warmup + 1 :, 1] if visible_only else torch.ones_like(err)
    weight = base * torch.where(region[:, warmup + 1 :], w, 1.0)
    torch.testing.assert_close(got, (err * weight).sum() / weight.sum())
    # the region of a frame that is no target (the warm-up's, the last output's input) is ignored
    early = region.clone()
    early[:, : warmup + 1] = ~early[:, : warmup + 1]
    assert torch.equal(next_map_bce(seq, logits, warmup, visible_only, region=early,
                                    region_weight=w), got)  # fmt: skip
    # and moving the region by one frame changes the loss
    shifted = torch.roll(region, 1, dims=1)
    assert not torch.equal(
        next_map_bce(seq, logits, warmup, visible_only, region=shifted, region_weight=w), got
    )


def test_occupied_only_weighs_the_regions_occupied_target_cells_alone():
    seq, logits, region = _window(seed=5)
    warmup, w = 2, 7.0
    got = next_map_bce(seq, logits, warmup, True, region=region, region_weight=w,
                       region_occupied_only=True)  # fmt: skip
    target = seq[:, warmup + 1 :, 0]
    err = F.binary_cross_entropy_with_logits(logits[:, warmup:-1, 0], target, reduction="none")
    keep = region[:, warmup + 1 :] & (target > 0.5)
    assert keep.any() and (region[:, warmup + 1 :] & (target < 0.5)).any()
    weight = seq[:, warmup + 1 :, 1] * torch.where(keep, w, 1.0)
    torch.testing.assert_close(got, (err * weight).sum() / weight.sum())
    config = build_config("head_movers", None, None, ["loss.mover_cells=occupied"])
    assert config.loss.mover_cells == "occupied"
    with pytest.raises(ValueError, match="mover_cells"):
        LossConfig(mover_cells="free")


def test_make_loss_passes_the_weight_and_the_cells_on():
    seq, _, region = _window(seed=6, t=10)
    full = torch.cat([seq, torch.rand(2, 10, 2, 5, 7)], dim=2)
    values = {}
    for keys in (
        [],
        ["loss.mover_weight=10"],
        ["loss.mover_weight=10", "loss.mover_cells=occupied"],
    ):
        config = build_config("head_only", None, None, ["model.init=null", *keys])
        model = build(config.model.spec())
        torch.manual_seed(0)
        for p in model.parameters():
            torch.nn.init.normal_(p, std=0.3)
        with torch.no_grad():
            out, _ = model(full)
            values[len(keys)] = make_loss(config, 1, model)(full, out, region)
    assert len({float(v) for v in values.values()}) == 3, values


def test_a_region_of_the_wrong_shape_is_refused():
    seq, logits, region = _window()
    with pytest.raises(ValueError, match="region must be"):
        next_map_bce(seq, logits, 2, region=region[:, 1:], region_weight=3.0)


def test_the_recipe_is_head_only_with_the_movers_weighted():
    only, movers = recipe("head_only"), recipe("head_movers")
    assert movers.recipe == "head_movers" and movers.loss.mover_weight == 10.0
    assert movers.loss.replace(mover_weight=1.0) == only.loss
    assert (movers.model, movers.data, movers.optim) == (only.model, only.data, only.optim)
    again = config_from_dict(json.loads(json.dumps(config_to_dict(movers))))
    assert again == movers
    assert build_config("head_only", None, None, ["loss.mover_weight=30"]).loss.mover_weight == 30
    with pytest.raises(ValueError, match="mover_weight"):
        LossConfig(mover_weight=0.0)


def test_a_weight_without_the_heads_cross_entropy_is_refused():
    for name, keys in (("paper", []), ("deeptracking", ["model.name=deeptracking"])):
        config = build_config(name if name == "paper" else "paper", None, None,
                              [*keys, "loss.mover_weight=10"])  # fmt: skip
        with pytest.raises(TrainError, match="mover_weight"):
            make_loss(config, 1)


def test_take_region_lifts_the_last_item_off():
    a, b, c = torch.zeros(1), torch.ones(1), torch.full((1,), 2.0)
    rest, region = take_region([a, b, c])
    assert rest == [a, b] and region is c
    rest, region = take_region([a, c])
    assert rest is a and region is c


@pytest.fixture(scope="module")
def drive(tmp_path_factory):
    """A simulated drive (the platform moves, people walk) saved as .npz."""
    cfg = SimConfig(scenario="dynamic", episode_frames=200, grid=GRID)
    rec = simulate(60, seed=2, config=cfg)  # people in view
    return rec.save(tmp_path_factory.mktemp("movers") / "drive.npz")


def test_each_training_window_carries_its_frames_region_as_evaluate_finds_it(drive):
    cfg = build_config("head_movers", None, {
        "data.sources": [str(drive)], "data.grid": GRID.height, "data.res": GRID.res,
        "data.seq_len": 8, "data.warmup": 3, "data.stride": 5, "data.val_fraction": 0.25,
    }).data  # fmt: skip
    data = load_train_data(cfg, with_motion=True, with_subcell=True, with_regions=True)
    windows = data.sources[0]
    (rec,) = [windows.maps[0]]
    assert windows.regions is not None and data.val is not None and data.val.regions is None
    from lidarflow.data import load_any

    recording = load_any(drive).slice(0, len(rec))
    region = recording_region(
        recording, GRID, rec[:, 0], rec[:, 1], ground_truth_moving(recording, GRID)
    )
    assert len(windows.regions[0]) == len(rec)
    assert np.any(windows.regions[0])
    for i, (_, start) in enumerate(windows.index):
        item = windows[i]
        maps, motion, got = item[0], item[1], item[-1]
        assert got.dtype == torch.bool and got.shape == (8, *GRID.shape)
        assert maps.shape[0] == motion.shape[0] == 8
        want = np.stack([region(start + k) for k in range(8)])
        np.testing.assert_array_equal(got.numpy(), want)
    # the regions the windows carry are the ones recording_regions gives
    np.testing.assert_array_equal(recording_regions([recording], [rec], GRID)[0],
                                  windows.regions[0])  # fmt: skip


def test_a_tiny_head_movers_run_trains_and_differs_from_the_unweighted_one(drive, tmp_path):
    flags = {
        "data.sources": [str(drive)],
        "data.grid": GRID.height,
        "data.res": GRID.res,
        "data.seq_len": 8,
        "data.warmup": 3,
        "data.stride": 4,
        "data.val_fraction": 0.25,
        "data.epoch_windows": 8,
        "optim.batch_size": 2,
        "optim.epochs": 2,
        "runtime.tensorboard": False,
        "runtime.threads": 1,
        "model.init": str(FLOW_MODEL),
    }
    runs = {}
    for name in ("head_only", "head_movers"):
        result = train(build_config(name, None, flags), tmp_path / name)
        losses = [row["train_loss"] for row in result.rows if "train_loss" in row]
        assert all(np.isfinite(losses)) and losses[-1] < losses[0], losses
        runs[name] = result.model.state_dict()
    assert any(not torch.equal(runs["head_only"][k], v) for k, v in runs["head_movers"].items())
