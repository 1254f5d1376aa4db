"""F1 per horizon step: hand-computed copy-last numbers, and an untrained (copy-last) model."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.errors import EvaluateError
from lidarflow.evaluate.horizon import horizon_f1
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.models import build_model


def _walker(n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """A wall cell that stays, and a cell moving one column per frame."""
    occupancy = np.zeros((n, 6, 12), bool)
    occupancy[:, 0, 0] = True
    for t in range(n):
        occupancy[t, 3, t] = True
    return occupancy, np.ones_like(occupancy)


def test_copy_last_per_horizon_by_hand():
    occupancy, visibility = _walker()
    scores = horizon_f1(occupancy, visibility, [], horizon=2, warmup=2)
    # every scored frame: predicted {wall, walker at t}, true {wall, walker at t+k}:
    # tp 1, fp 1, fn 1 at each k -> F1 = 2 / (2 + 1 + 1) = 0.5
    assert scores == {"copy_last": [pytest.approx(0.5), pytest.approx(0.5)]}


def test_untrained_flownet_rolls_forward_as_copy_last():
    occupancy, visibility = _walker(10)
    net = build_model("flownet").eval()  # zero flow: every step predicts the map it is given
    head = build_model("flownet", occupancy_head=True).eval()
    methods = [ModelMethod("net", net), ModelMethod("head", head)]
    scores = horizon_f1(occupancy, visibility, methods, horizon=3, warmup=2)
    for name in ("net", "head"):
        assert scores[name] == pytest.approx(scores["copy_last"])


def test_too_short_for_the_horizon_is_refused():
    occupancy, visibility = _walker(5)
    with pytest.raises(EvaluateError, match="horizon 3"):
        horizon_f1(occupancy, visibility, [], horizon=3, warmup=2)


def test_the_online_decision_is_fed_back_through_the_roll_out():
    from lidarflow.predict.decision import OnlineDecisionConfig

    occupancy, visibility = _walker(12)
    # Untrained, the head is copy-last at logit 2.2: at its own offset -3 it predicts nothing,
    # at any step. Chosen online (here the one occupied-cell offset, 6), the cells are found,
    # and fed back decided they are found again at every step.
    head = build_model("flownet", occupancy_head=True, decision_offset=-3.0).eval()
    config = OnlineDecisionConfig(occupied_offsets=(6.0,), free_offsets=(-0.6,), min_frames=2)
    methods = [ModelMethod("fixed", head), ModelMethod("online", head, online=config)]
    scores = horizon_f1(occupancy, visibility, methods, horizon=3, warmup=4)
    assert scores["fixed"] == [0.0, 0.0, 0.0]
    assert scores["online"] == pytest.approx(scores["copy_last"])


def test_horizon_on_frame_blocks_is_the_same_as_on_arrays():
    from lidarflow.data.blocks import FrameBlocks

    maps = np.zeros((30, 8, 8), bool)
    for t in range(30):
        maps[t, 2, t % 8] = True  # a cell running along a row
    model = build_model("deeptracking")
    whole = horizon_f1(maps, maps, [ModelMethod("m", model)], horizon=3, warmup=2)
    blocks = FrameBlocks(lambda a, b: maps[a:b], len(maps), block=4)
    assert horizon_f1(blocks, blocks, [ModelMethod("m", model)], horizon=3, warmup=2) == whole
