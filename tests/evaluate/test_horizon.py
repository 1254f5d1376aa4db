"""F1 per horizon step: hand-computed copy-last numbers, and an untrained (copy-last) model."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.errors import EvaluateError
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.runner import horizon_scores
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
    scores = horizon_scores(occupancy, visibility, [], horizon=2, warmup=2)["f1"]
    # every scored frame: predicted {wall, walker at t}, true {wall, walker at t+k}:
    # tp 1, fp 1, fn 1 at each k -> F1 = 2 / (2 + 1 + 1) = 0.5
    assert scores == {"copy_last": [pytest.approx(0.5), pytest.approx(0.5)]}


def test_untrained_flownet_rolls_forward_as_copy_last():
    occupancy, visibility = _walker(10)
    net = build_model("flownet").eval()  # zero flow: every step predicts the map it is given
    head = build_model("flownet", occupancy_head=True).eval()
    methods = [ModelMethod("net", net), ModelMethod("head", head)]
    scores = horizon_scores(occupancy, visibility, methods, horizon=3, warmup=2)["f1"]
    for name in ("net", "head"):
        assert scores[name] == pytest.approx(scores["copy_last"])


def test_too_short_for_the_horizon_is_refused():
    occupancy, visibility = _walker(5)
    with pytest.raises(EvaluateError, match="horizon 3"):
        horizon_scores(occupancy, visibility, [], horizon=3, warmup=2)["f1"]


def test_the_online_decision_is_fed_back_through_the_roll_out():
    from lidarflow.predict.decision import OnlineDecisionConfig

    occupancy, visibility = _walker(12)
    # Untrained, the head is copy-last at logit 2.2: at its own offset -3 it predicts nothing,
    # at any step. Chosen online (here the one occupied-cell offset, 6), the cells are found,
    # and fed back decided they are found again at every step.
    head = build_model("flownet", occupancy_head=True).eval()
    config = OnlineDecisionConfig(occupied_offsets=(6.0,), free_offsets=(-0.6,), min_frames=2)
    own = {"offset": -3.0, "online": False}  # the policy it ships with
    methods = [
        ModelMethod("fixed", head, decision=own),
        ModelMethod("online", head, online=config, decision=own),
    ]
    scores = horizon_scores(occupancy, visibility, methods, horizon=3, warmup=4)["f1"]
    assert scores["fixed"] == [0.0, 0.0, 0.0]
    assert scores["online"] == pytest.approx(scores["copy_last"])


def test_horizon_on_frame_blocks_is_the_same_as_on_arrays():
    from lidarflow.data.blocks import FrameBlocks

    maps = np.zeros((30, 8, 8), bool)
    for t in range(30):
        maps[t, 2, t % 8] = True  # a cell running along a row
    model = build_model("deeptracking")
    whole = horizon_scores(maps, maps, [ModelMethod("m", model)], horizon=3, warmup=2)["f1"]
    blocks = FrameBlocks(lambda a, b: maps[a:b], len(maps), block=4)
    blocked = horizon_scores(blocks, blocks, [ModelMethod("m", model)], horizon=3, warmup=2)
    assert blocked["f1"] == whole


def test_the_baselines_roll_forward_as_the_models_do():
    from lidarflow.baselines import ConstantVelocity, CopyLast, TemporalAverage
    from lidarflow.evaluate.runner import horizon_scores

    # the whole scene drifts one column a frame (as under a platform moving sideways)
    occupancy = np.zeros((10, 6, 16), bool)
    for t in range(10):
        occupancy[t, 1, t] = occupancy[t, 4, t + 2] = True
    visibility = np.ones_like(occupancy)
    methods = [CopyLast(), TemporalAverage(3, 0.4), ConstantVelocity()]
    scores = horizon_scores(occupancy, visibility, methods, horizon=3, warmup=3)
    # constant velocity, applied k times, finds the scene k columns on at every k
    assert scores["f1"]["constant_velocity"] == pytest.approx([1.0, 1.0, 1.0])
    assert scores["changed_f1"]["constant_velocity"] == pytest.approx([1.0, 1.0, 1.0])
    assert scores["f1"]["copy_last"] == scores["changed_f1"]["copy_last"] == [0.0, 0.0, 0.0]
    # the temporal average's majority of three frames keeps nothing that moves: fed back, it
    # goes on predicting nothing
    assert scores["f1"]["temporal_average"] == [0.0, 0.0, 0.0]
    # on the walker beside a wall it keeps the wall (one of the two cells) at every k
    occupancy, visibility = _walker(10)
    scores = horizon_scores(occupancy, visibility, methods[1:2], horizon=3, warmup=3)
    assert scores["f1"]["temporal_average"] == pytest.approx([2 / 3] * 3)
    assert list(scores) == ["f1", "changed_f1", "wmse"]  # no SSIM on a grid under 11 x 11


def test_the_last_map_moved_by_the_ego_motion_moves_on_each_step_ahead():
    from lidarflow.baselines import CopyLastEgo
    from lidarflow.evaluate.runner import horizon_scores

    # a still wall seen from a platform driving one row a frame towards it
    n, h, w = 12, 20, 8
    occupancy = np.zeros((n, h, w), bool)
    for t in range(n):
        occupancy[t, 2 + t, 3] = True
    motions = np.tile(np.array([1.0, 0.0, 0.0], np.float32), (n, 1))
    scores = horizon_scores(
        occupancy, np.ones_like(occupancy), [CopyLastEgo()], horizon=3, warmup=2, motions=motions
    )
    assert scores["f1"]["copy_last_ego"] == pytest.approx([1.0, 1.0, 1.0])
    assert scores["f1"]["copy_last"] == [0.0, 0.0, 0.0]


def test_on_ahead_sees_every_scored_prediction_1_to_k_ahead():
    from lidarflow.baselines import ConstantVelocity

    occupancy = np.zeros((10, 6, 16), bool)
    for t in range(10):
        occupancy[t, 1, t] = True
    seen: dict[str, dict[int, np.ndarray]] = {}
    horizon_scores(
        occupancy, np.ones_like(occupancy), [ConstantVelocity()], horizon=3, warmup=3,
        on_ahead=lambda name, t, predicted: seen.setdefault(name, {}).update({t: predicted}),
    )  # fmt: skip
    assert set(seen) == {"copy_last", "constant_velocity"}
    assert sorted(seen["copy_last"]) == sorted(seen["constant_velocity"]) == [3, 4, 5, 6]
    assert seen["copy_last"][4].shape == (3, 6, 16) and seen["copy_last"][4][2, 1, 4]
    # constant velocity k ahead: the walker k columns on
    assert [seen["constant_velocity"][4][k, 1, 5 + k] >= 0.4 for k in range(3)] == [True] * 3
