"""Validation metrics on simulator recordings, checked against an independent computation."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

from lidarflow.data import load_recording
from lidarflow.evaluate.metrics import confusion
from lidarflow.models import build_model
from lidarflow.scan import GridSpec
from lidarflow.sim.scenario import SimConfig, simulate
from lidarflow.sim.storage import to_sparse
from lidarflow.train.config import DataConfig
from lidarflow.train.data import load_train_data
from lidarflow.train.distributed import Dist
from lidarflow.train.loaders import make_val_loader
from lidarflow.train.validate import validate


@pytest.fixture(scope="module")
def sim_file(tmp_path_factory):
    # the robot drives: the whole scene moves, so there is flow to measure on a small grid
    config = SimConfig(scenario="dynamic", grid=GridSpec(32, 32, 0.3), episode_frames=80)
    return simulate(80, seed=0, config=config).save(tmp_path_factory.mktemp("sim") / "sim.npz")


@pytest.fixture(scope="module")
def sparse_sim_file(sim_file):
    rec = load_recording(sim_file)
    for key in ("flow_backward", "flow_forward"):
        cells, values = to_sparse(rec.extras.pop(key))
        rec.extras[f"{key}_cells"], rec.extras[f"{key}_values"] = cells, values
    rec.meta["flow_storage"] = "sparse"
    return rec.save(sim_file.with_name("sparse.npz"))


@pytest.mark.parametrize("layout", ["dense", "sparse"])
def test_untrained_flownet_scores_copy_last_and_zero_flow_epe(sim_file, sparse_sim_file, layout):
    path = sim_file if layout == "dense" else sparse_sim_file
    cfg = DataConfig(sources=[str(path)], grid=32, res=0.3, seq_len=10, warmup=3, val_fraction=0.5)
    data = load_train_data(cfg)
    assert data.val is not None and data.val.has_flow
    model = build_model("flownet")  # zero flow head: predicts the last map exactly
    metrics = validate(
        model,
        make_val_loader(data.val, 4),
        lambda seq, out: out.sum() * 0,
        cfg.warmup,
        Dist(),
        contextlib.nullcontext,
        True,
    )
    # independent: every val window, pairs t = warmup .. T-2, B^t on the cells of O^{t+1}
    errs, copy = [], None
    dense_val = load_train_data(DataConfig(**{**cfg.__dict__, "sources": [str(sim_file)]})).val
    for rec, start in data.val.index:
        occ = data.val.maps[rec][start : start + cfg.seq_len, 0]
        flow = dense_val.flows[rec][start : start + cfg.seq_len].astype(np.float64)
        for t in range(cfg.warmup, cfg.seq_len - 1):
            errs.append(np.hypot(flow[t, 0], flow[t, 1])[occ[t + 1]])
            c = confusion(occ[t], occ[t + 1])
            copy = c if copy is None else copy + c
    assert metrics["val_f1"] == pytest.approx(copy.f1) == pytest.approx(metrics["val_copy_last_f1"])
    assert metrics["val_changed_f1"] == 0.0
    expected = np.concatenate(errs)
    assert metrics["val_epe"] == pytest.approx(expected.mean(), rel=1e-4)
    assert metrics["val_epe_zero"] == pytest.approx(expected.mean(), rel=1e-4)
    assert expected.max() > 0  # people walked: there was motion to measure
    assert metrics["val_epe_moving"] == pytest.approx(expected[expected > 0].mean(), rel=1e-4)
