"""LiDAR-FlowNet without its flow network through ONNX, the Predictor and evaluate: it decides
as the same head on a zeroed flow does, and reports no flow and no moving cells of its own."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.runner import evaluate_recording
from lidarflow.models.presets import resolve_model
from lidarflow.outputs.export import export_onnx
from lidarflow.predict import Predictor
from lidarflow.predict.backends import FLOW_KEY
from lidarflow.predict.decision import DecisionPolicy
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, simulate
from tests.head_only_pair import head_only, save_model_dir, zeroed_twin

ONLINE = {"offset": -0.5, "online": True}


def poses(n: int) -> list[tuple[float, float, float]]:
    """A platform driving forward and turning (metres, radians)."""
    return [(0.03 * i, 0.01 * i, 0.02 * i) for i in range(n)]


def test_onnx_matches_pytorch_and_both_decide_as_the_zeroed_flow(tmp_path, sample_recording):
    import onnx

    model = head_only(ego=True, seed=3)
    folder = save_model_dir(model, tmp_path / "noflow", ONLINE)
    twin = save_model_dir(zeroed_twin(model), tmp_path / "zeroed", ONLINE)
    net, _ = resolve_model(folder)
    path = export_onnx(net, tmp_path / "m.onnx", decision=DecisionPolicy.from_record(ONLINE))
    marks = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert marks[FLOW_KEY] == "false"
    predictors = [Predictor(m, horizon=3) for m in (folder, path, twin)]
    torch_p, onnx_p, zeroed = predictors
    assert not torch_p.backend.capabilities.flow and not onnx_p.backend.capabilities.flow
    assert torch_p.uses_motion and onnx_p.uses_motion
    for i, pose in enumerate(poses(12)):
        scan = sample_recording.scan(i)
        a, b, z = (p.update(scan, pose) for p in predictors)
        np.testing.assert_allclose(a.probability, b.probability, atol=1e-4)
        # The head alone runs on the NumPy step (issue 46), whose sampling positions are
        # float64 where PyTorch's grid is float32: ~1e-5 apart, as ONNX is from PyTorch.
        np.testing.assert_allclose(a.probability, z.probability, atol=1e-4)
        np.testing.assert_array_equal(a.occupied, z.occupied)  # decided on the moved map
        np.testing.assert_array_equal(a.horizon_occupied, z.horizon_occupied)
        assert np.mean(a.occupied != b.occupied) < 1e-3
    assert a.ego_compensated and a.occupied.any()
    for p in (a, b):  # no flow of its own, so no moving cells to report
        assert p.backward_flow is None and p.forward_flow is None and p.moving is None
    assert z.forward_flow is not None  # the flow model reports the platform's flow
    assert torch_p.online.offsets == zeroed.online.offsets


def test_export_of_a_flow_model_is_not_marked(tmp_path):
    import onnx

    path = export_onnx(zeroed_twin(head_only(seed=4)), tmp_path / "f.onnx", 20, 20)
    assert FLOW_KEY not in {p.key for p in onnx.load(str(path)).metadata_props}
    assert Predictor(path).backend.capabilities.flow


def test_evaluate_scores_it_as_the_zeroed_flow_without_flow_metrics():
    grid = GridSpec(40, 40, 0.05)
    drive = simulate(50, seed=5, config=SimConfig(scenario="dynamic", episode_frames=80, grid=grid))
    model = head_only(ego=True, seed=6)
    methods = [
        ModelMethod("noflow", model, decision=ONLINE),
        ModelMethod("zeroed", zeroed_twin(model), decision=ONLINE),
    ]
    scores = evaluate_recording(drive, methods, grid)
    ours, ref = (scores[name].summary() for name in ("noflow", "zeroed"))
    for key in ("f1", "changed_f1", "ap", "precision", "recall"):
        assert ours[key] == pytest.approx(ref[key], abs=1e-9), key
    # No flow of its own: no end-point error, no moving-object segmentation scored for it.
    for key in ("epe", "epe_static", "segmentation"):
        assert key in ref and key not in ours, key
