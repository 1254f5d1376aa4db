"""Training data: sources, the validation split, mixing, and the sampler's order and sharding."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
import torch

from lidarflow.errors import TrainError
from lidarflow.train.config import DataConfig
from lidarflow.train.data import expand_source, load_train_data
from lidarflow.train.loaders import MixSampler, make_loader
from tests.train.blobs import blob_recording


def _cfg(sources, **kw) -> DataConfig:
    return DataConfig(sources=[str(s) for s in sources], grid=32, seq_len=10, warmup=4, **kw)


def test_expand_source(tmp_path, blob_files):
    assert expand_source(str(blob_files[0])) == [blob_files[0]]
    assert expand_source(str(tmp_path / "blob_*.npz")) == sorted(blob_files)
    assert expand_source(str(tmp_path)) == sorted(blob_files)
    with pytest.raises(TrainError, match="matches no file"):
        expand_source(str(tmp_path / "nothing*.npz"))
    with pytest.raises(TrainError, match="no such file"):
        expand_source(str(tmp_path / "missing.npz"))


def test_tail_split_holds_out_the_end_of_each_recording(blob_files):
    data = load_train_data(_cfg(blob_files, val_fraction=0.25))
    # 60 frames: 15 held out (>= one window of 10) -> 45 for training: 4 windows each
    assert [len(s) for s in data.sources] == [4, 4]
    assert data.val is not None and len(data.val) == 2  # one window of the 15-frame tail each
    rec = blob_recording(60, seed=1)
    occ, _ = rec.maps(data.grid)
    held = data.val.maps[0]
    assert held.shape[0] == 15 and np.array_equal(held[:, 0], occ[45:])  # the last 15 frames
    maps, flow, has_flow = data.val[0]
    assert maps.dtype == torch.uint8 and maps.shape == (10, 2, 32, 32)
    assert has_flow and torch.equal(flow, torch.from_numpy(rec.extras["flow_backward"][45:55]))


def test_recordings_split_and_explicit_validation(blob_files, tmp_path):
    data = load_train_data(
        _cfg([tmp_path / "blob_*.npz"], val_split="recordings", val_fraction=0.5)
    )
    assert [len(s) for s in data.sources] == [6] and len(data.val) == 6  # one whole recording each
    data = load_train_data(_cfg(blob_files[:1], val_sources=[str(blob_files[1])]))
    assert [len(s) for s in data.sources] == [6] and len(data.val) == 6
    with pytest.raises(TrainError, match="at least 2 recordings"):
        load_train_data(_cfg(blob_files[:1], val_split="recordings"))


def test_mix_weights_must_fit_the_sources(blob_files):
    with pytest.raises(TrainError, match="3 weight"):
        load_train_data(_cfg(blob_files, mix=[1, 1, 1]))
    assert load_train_data(_cfg(blob_files, mix=[0.25])).weights == [0.25, 0.75]
    assert load_train_data(_cfg(blob_files, mix=[3, 1])).weights == [0.75, 0.25]


def test_sampler_draws_sources_in_proportion():
    sampler = MixSampler([10, 1000], weights=[0.5, 0.5], num_samples=400, seed=3)
    sampler.set_epoch(0)
    order = list(sampler)
    counts = Counter(i < 10 for i in order)
    assert counts[True] == counts[False] == 200
    assert Counter(order[i] for i in range(400) if order[i] < 10).most_common(1)[0][1] == 20
    # without weights: every window exactly once per epoch
    plain = MixSampler([10, 30], seed=1)
    plain.set_epoch(2)
    assert sorted(plain) == list(range(40))


def test_sampler_order_depends_only_on_seed_and_epoch():
    a, b = MixSampler([50], seed=7), MixSampler([50], seed=7)
    a.set_epoch(3)
    b.set_epoch(3)
    assert list(a) == list(b)
    b.set_epoch(4)
    assert list(a) != list(b)
    c = MixSampler([50], seed=7)
    c.set_epoch(3)
    torch.manual_seed(123)  # the global RNG plays no part
    assert list(c) == list(a)


def test_sampler_shards_like_distributed_sampler():
    shards = []
    for rank in range(3):
        s = MixSampler([10], seed=0, rank=rank, world_size=3)
        s.set_epoch(1)
        shards.append(list(s))
    assert all(len(x) == 4 for x in shards)  # 10 padded to 12
    assert set().union(*map(set, shards)) == set(range(10))


def test_loader_batches_uint8_windows(blob_files):
    data = load_train_data(_cfg(blob_files))
    loader, sampler = make_loader(data, data_cfg := _cfg(blob_files), batch_size=3, seed=0)
    sampler.set_epoch(0)
    batches = list(loader)
    assert sum(len(b) for b in batches) == data.train_windows == len(sampler)
    assert batches[0].shape == (3, data_cfg.seq_len, 2, 32, 32) and batches[0].dtype == torch.uint8
    assert set(torch.unique(batches[0]).tolist()) <= {0, 1}


def test_subcell_windows_carry_each_frames_subcell_maps(blob_files):
    from lidarflow.data import load_any
    from lidarflow.scan import GridSpec

    plain = load_train_data(_cfg(blob_files, val_fraction=0.0))
    data = load_train_data(_cfg(blob_files, val_fraction=0.0), with_subcell=True)
    windows, plain_windows = data.sources[0], plain.sources[0]
    assert windows.index == plain_windows.index
    rec, start = windows.index[3]
    item = windows[3]
    assert item.shape == (10, 4, 32, 32)
    torch.testing.assert_close(item[:, :2], plain_windows[3])  # (O, V) unchanged
    expected = load_any(blob_files[rec]).subcell_maps(GridSpec(32, 32, 0.1))[start : start + 10]
    assert expected.any()
    np.testing.assert_array_equal(item[:, 2:].numpy().astype(bool), expected)
