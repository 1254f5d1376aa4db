"""The streaming Predictor: shapes, state, horizon, and ONNX parity with PyTorch."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarflow.errors import PredictError
from lidarflow.models.presets import resolve_model
from lidarflow.outputs.export import export_onnx
from lidarflow.predict import Predictor
from lidarflow.predict.backends import DECISION_KEY
from lidarflow.predict.decision import DecisionPolicy
from tests.conftest import make_model_dir


def frames(recording, n=15):
    return [recording.scan(i) for i in range(n)]


def test_update_shapes_and_threshold(random_flownet_dir, sample_recording):
    predictor = Predictor(random_flownet_dir)
    p = predictor.update(sample_recording.scan(0))
    assert p.probability.shape == (100, 100) and p.horizon.shape == (1, 100, 100)
    assert p.backward_flow.shape == (2, 100, 100) and p.forward_flow.shape == (2, 100, 100)
    np.testing.assert_array_equal(p.occupied, p.probability >= 0.4)
    assert p.probability.min() >= 0.0 and p.probability.max() <= 1.0


def test_reset_replays_identically_and_state_matters(random_flownet_dir, sample_recording):
    predictor = Predictor(random_flownet_dir)
    first = [predictor.update(s).backward_flow for s in frames(sample_recording)]
    predictor.reset()
    again = [predictor.update(s).backward_flow for s in frames(sample_recording)]
    np.testing.assert_array_equal(first[-1], again[-1])
    fresh = Predictor(random_flownet_dir).update(sample_recording.scan(14)).backward_flow
    assert not np.allclose(fresh, first[-1])  # the recurrent state carries the past


def test_horizon_rollout_does_not_leak_into_the_state(random_flownet_dir, sample_recording):
    one = Predictor(random_flownet_dir, horizon=1)
    three = Predictor(random_flownet_dir, horizon=3)
    for scan in frames(sample_recording, 8):
        a, b = one.update(scan), three.update(scan)
    np.testing.assert_allclose(a.probability, b.probability, atol=1e-6)
    assert b.horizon.shape == (3, 100, 100)
    assert not np.allclose(b.horizon[0], b.horizon[2])


def test_maps_input_and_wrong_shape(random_flownet_dir):
    predictor = Predictor(random_flownet_dir)
    occ = np.zeros((100, 100), bool)
    assert predictor.update((occ, occ)).probability.shape == (100, 100)
    with pytest.raises(PredictError, match=r"maps must be \(100, 100\)"):
        predictor.update((np.zeros((50, 50)), np.zeros((50, 50))))


def test_a_malformed_pose_is_a_predict_error(sample_recording):
    predictor = Predictor()  # the bundled model compensates ego motion: it reads the pose
    with pytest.raises(PredictError, match=r"pose must be three numbers \(x, y, yaw\)"):
        predictor.update(sample_recording.scan(0), pose=(1.0, 2.0))
    assert predictor.update(sample_recording.scan(0), pose=(1.0, 2.0, 0.0)).probability.shape


def test_onnx_matches_pytorch_over_a_recording(tmp_path, random_flownet_dir, sample_recording):
    net, _ = resolve_model(random_flownet_dir)
    onnx_path = export_onnx(net, tmp_path / "m.onnx")
    torch_p, onnx_p = Predictor(random_flownet_dir), Predictor(onnx_path)
    worst_flow = worst_prob = 0.0
    for scan in frames(sample_recording, 30):
        a, b = torch_p.update(scan), onnx_p.update(scan)
        worst_flow = max(worst_flow, float(np.abs(a.backward_flow - b.backward_flow).max()))
        worst_flow = max(worst_flow, float(np.abs(a.forward_flow - b.forward_flow).max()))
        worst_prob = max(worst_prob, float(np.abs(a.probability - b.probability).max()))
    assert worst_flow < 1e-4 and worst_prob < 1e-4


def test_deeptracking_has_no_flow(tmp_path, sample_recording):
    folder = make_model_dir(tmp_path / "dt", name="deeptracking")
    p = Predictor(folder).update(sample_recording.scan(0))
    assert p.backward_flow is None and p.forward_flow is None
    assert p.probability.shape == (100, 100)


def test_onnx_grid_mismatch_is_explained(tmp_path, random_flownet_dir):
    from lidarflow.scan import GridSpec

    net, _ = resolve_model(random_flownet_dir)
    path = export_onnx(net, tmp_path / "m.onnx")
    predictor = Predictor(path, grid=GridSpec(64, 64, 0.1))
    with pytest.raises(PredictError, match="exported for a 100x100 grid"):
        predictor.update((np.zeros((64, 64)), np.zeros((64, 64))))


def test_occupancy_head_model_exports_and_keeps_four_flow_channels(tmp_path, sample_recording):
    folder = make_model_dir(tmp_path / "head", occupancy_head=True, zero_init_flow=False)
    net, _ = resolve_model(folder)
    torch_p, onnx_p = Predictor(folder), Predictor(export_onnx(net, tmp_path / "h.onnx"))
    for scan in frames(sample_recording, 12):
        a, b = torch_p.update(scan), onnx_p.update(scan)
    assert a.backward_flow.shape == (2, 100, 100) and a.forward_flow.shape == (2, 100, 100)
    np.testing.assert_allclose(a.probability, b.probability, atol=1e-4)
    np.testing.assert_allclose(a.forward_flow, b.forward_flow, atol=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize(
    "kwargs",
    [
        {"memory_decays": [0.5, 0.95], "constant_velocity_input": True},
        {"memory_decays": [0.5, 0.95], "head_hidden_channels": 4},
        {"memory_decays": [0.5, 0.95], "constant_velocity_input": True, "shift_memories": True},
        {"memory_decays": [0.5, 0.95], "visibility_input": True, "decision_offset": 0.4},
        {"subcell_input": True, "head_hidden_channels": 4, "decision_offset": -0.7},
    ],
    ids=[
        "constant_velocity_input",
        "hidden_layer",
        "shift_memories",
        "visibility_input_with_an_offset",
        "subcell_input_with_an_offset",
    ],
)
def test_head_inputs_export_with_matching_probabilities(tmp_path, sample_recording, kwargs):
    # Random head weights so that the memories (their frame count, the constant-velocity map)
    # shape the output.
    import torch
    from safetensors.torch import load_file, save_file

    folder = make_model_dir(tmp_path / "bc", occupancy_head=True, **kwargs)
    weights = load_file(folder / "model.safetensors")
    weights["head.out.weight"] = torch.randn_like(weights["head.out.weight"])
    save_file(weights, folder / "model.safetensors")
    net, card = resolve_model(folder)
    policy = DecisionPolicy.from_record(card["decision"])
    onnx_path = export_onnx(net, tmp_path / "bc.onnx", decision=policy)
    torch_p, onnx_p = Predictor(folder), Predictor(onnx_path)
    assert torch_p.decision == onnx_p.decision == policy  # the offset travels with the file
    for scan in frames(sample_recording, 12):
        a, b = torch_p.update(scan), onnx_p.update(scan)
        np.testing.assert_allclose(a.probability, b.probability, atol=1e-4)
        near = np.abs(a.probability - 0.4) < 1e-3  # decided alike but where it is a coin toss
        assert np.array_equal(a.occupied[~near], b.occupied[~near])


@pytest.mark.slow
def test_online_decision_in_the_predictor_equals_evaluate_and_survives_onnx(
    tmp_path, sample_recording
):
    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.scan import GridSpec

    # Untrained, the head is copy-last at logit 2.2: an occupied-cell offset of -3 predicts
    # nothing, so the offsets chosen online are not the model's.
    kwargs = {"occupancy_head": True, "decision_offset": -3.0, "online_decision": True}
    folder = make_model_dir(tmp_path / "m", seed=2, zero_init_flow=False, **kwargs)
    net, card = resolve_model(folder)
    policy = DecisionPolicy.from_record(card["decision"])
    onnx_path = export_onnx(net, tmp_path / "m.onnx", decision=policy)
    torch_p, onnx_p = Predictor(folder), Predictor(onnx_path)
    fixed = Predictor(folder, online_decision=False)
    assert torch_p.online is not None and onnx_p.online is not None and fixed.online is None
    # The model ships with an online decision: evaluate decides online too.
    method = ModelMethod("m", net, decision=card["decision"])
    occupancy, visibility = sample_recording.slice(0, 25).maps(GridSpec())
    for occ, vis in zip(occupancy, visibility, strict=True):
        a, b = torch_p.update((occ, vis)), onnx_p.update((occ, vis))
        decided = method.update(occ, vis)
        assert np.array_equal(a.occupied, decided >= 0.4)
        assert np.allclose(a.probability, method.last.probability, atol=1e-6)
        assert np.abs(a.probability - b.probability).max() < 1e-4
        assert np.array_equal(a.horizon[0], a.probability)
        own = fixed.update((occ, vis))
    assert torch_p.online.offsets == onnx_p.online.offsets != (-3.0, -3.0)
    assert torch_p.online.unmoved == onnx_p.online.unmoved
    # The ONNX file carries the head's warp gain, so it tries the unmoved map too.
    assert onnx_p.online.gain == pytest.approx(net.warp_gain(), rel=1e-6)
    assert not own.occupied.any() and a.occupied.any()


def test_online_decision_needs_an_occupancy_head_and_a_marked_onnx(tmp_path, random_flownet_dir):
    import onnx

    from lidarflow.predict.decision import OnlineDecisionConfig

    with pytest.raises(PredictError, match="occupancy head"):
        Predictor(random_flownet_dir, online_decision=True)
    config = OnlineDecisionConfig(occupied_offsets=(0.0, 1.0), free_offsets=(0.5,), decay=0.9)
    tuned = Predictor(make_model_dir(tmp_path / "t", occupancy_head=True), online_decision=config)
    assert tuned.online is not None and tuned.online.config is config
    net, _ = resolve_model(make_model_dir(tmp_path / "h", occupancy_head=True))
    path = export_onnx(net, tmp_path / "h.onnx")
    assert Predictor(path, online_decision=True).online.gain is not None
    earlier = onnx.load(str(path))  # marked before the gain was: the moved map only
    (mark,) = [m for m in earlier.metadata_props if m.key == DECISION_KEY]
    mark.value = json.dumps({k: v for k, v in json.loads(mark.value).items() if k != "gain"})
    onnx.save(earlier, str(path))
    online = Predictor(path, online_decision=True).online
    assert online is not None and online.gain is None and online.margins().shape[0] == 1
    old = onnx.load(str(path))  # as exported before the decision was marked
    del old.metadata_props[:]
    onnx.save(old, str(path))
    with pytest.raises(PredictError, match="export it again"):
        Predictor(path, online_decision=True)


@pytest.mark.slow
def test_the_roll_out_feeds_back_the_online_decision(tmp_path, sample_recording):
    from lidarflow.predict.decision import OnlineDecisionConfig
    from lidarflow.scan import GridSpec

    # At its own offset -3 the untrained head predicts nothing at any step; chosen online (here
    # the one occupied-cell offset, 6) the cells are found, and the roll-out, fed back the
    # decided map and re-decided at every step, finds them again: torch and ONNX alike.
    kwargs = {"occupancy_head": True, "decision_offset": -3.0}
    folder = make_model_dir(tmp_path / "m", seed=2, **kwargs)
    net, _ = resolve_model(folder)
    config = OnlineDecisionConfig(occupied_offsets=(6.0,), free_offsets=(-0.6,), min_frames=2)
    onnx_path = export_onnx(net, tmp_path / "m.onnx")
    predictors = [
        Predictor(folder, horizon=3, online_decision=config),
        Predictor(onnx_path, horizon=3, online_decision=config),
        Predictor(folder, horizon=3),
    ]
    occupancy, visibility = sample_recording.slice(0, 25).maps(GridSpec())
    for occ, vis in zip(occupancy, visibility, strict=True):
        online, onnx, fixed = (p.update((occ, vis)) for p in predictors)
    assert online.horizon_occupied[1:].any(axis=(1, 2)).all()
    assert np.abs(online.horizon - onnx.horizon).max() < 1e-3
    assert np.array_equal(online.horizon_occupied, onnx.horizon_occupied)
    assert not fixed.horizon_occupied.any()


def test_a_subcell_model_takes_its_scans_subcell_maps_and_refuses_bare_maps(
    tmp_path, sample_recording
):
    import torch
    from safetensors.torch import load_file, save_file

    from lidarflow.scan import rasterize, subcell_batch

    folder = make_model_dir(tmp_path / "sub", occupancy_head=True, subcell_input=True)
    weights = load_file(folder / "model.safetensors")  # a head that uses its inputs
    weights["head.out.weight"] = torch.randn_like(weights["head.out.weight"])
    save_file(weights, folder / "model.safetensors")
    predictor = Predictor(folder, horizon=3)
    scans = frames(sample_recording, 5)
    for scan in scans:
        p = predictor.update(scan)
    assert p.horizon.shape == (3, 100, 100)
    with pytest.raises(PredictError, match="give update a Scan"):
        predictor.update((p.occupancy, p.visibility))
    # What the predictor feeds is the scan's own subcell maps: the same as streaming by hand.
    from tests.hand_stream import HandStream

    stream = HandStream(resolve_model(folder)[0])
    for scan in scans:
        occ, vis = rasterize(scan)
        by_hand = stream.step(occ, vis, subcell=subcell_batch(scan.ranges[None], scan.geometry)[0])
    np.testing.assert_allclose(p.probability, by_hand.probability, atol=1e-6)
    blind = HandStream(resolve_model(folder)[0])  # the same without them differs
    for scan in scans:
        without = blind.step(*rasterize(scan))
    assert np.abs(without.probability - p.probability).max() > 1e-3


@pytest.mark.slow
def test_a_model_runs_on_the_grid_it_was_trained_for_unless_told(
    tmp_path, sample_recording, capsys
):
    from lidarflow.scan import GridSpec
    from tests.test_cli import run

    folder = make_model_dir(tmp_path / "g48")
    card = json.loads((folder / "model.json").read_text())
    card["grid"] = {"height": 48, "width": 48, "res": 0.15}  # as `lidarflow train --grid` writes
    (folder / "model.json").write_text(json.dumps(card))
    assert Predictor(folder).grid == GridSpec(48, 48, 0.15)
    assert Predictor(folder, GridSpec(40, 40, 0.2)).grid == GridSpec(40, 40, 0.2)
    # export writes the grid into the file, and the Predictor and `predict` run it there
    onnx = tmp_path / "g48.onnx"
    code, out, err = run(["export", "--onnx", str(onnx), "-m", str(folder)], capsys)
    assert code == 0, err
    assert "48x48 grid of 0.15 m" in out
    assert Predictor(onnx).grid == GridSpec(48, 48, 0.15)
    data = sample_recording.slice(0, 12).save(tmp_path / "r.npz")
    code, _, err = run(
        ["predict", str(data), "-o", str(tmp_path / "p.mcap"), "-m", str(onnx)], capsys
    )
    assert code == 0, err
    # half a grid given: the other half is the model's own
    argv = ["export", "-o", str(onnx), "-m", str(folder), "--res", "0.2", "--force"]
    code, out, err = run(argv, capsys)
    assert code == 0 and "48x48 grid of 0.2 m" in out, err
    # evaluate scores every model on one grid, and says when that is not a model's own
    code, _, err = run(["evaluate", str(data), "-m", str(folder)], capsys)
    assert code == 0 and "trained on a 48x48 grid of 0.15 m" in err, err
    # a file exported before the mark existed says only its size: another grid is refused
    export_onnx(resolve_model(folder)[0], tmp_path / "old.onnx", 48, 48)
    with pytest.raises(PredictError, match="run it on that grid"):
        Predictor(tmp_path / "old.onnx").update(sample_recording.scan(0))


def test_predictions_are_stamped_with_the_time_they_predict(random_flownet_dir, sample_recording):
    predictor = Predictor(random_flownet_dir, horizon=3)
    scans = frames(sample_recording, 6)
    first = predictor.update(scans[0])
    assert first.stamp_ns == scans[0].stamp_ns and first.step_ns is None
    assert first.stamp_ahead_ns(2) == scans[0].stamp_ns  # no step known: the scan's own time
    for scan in scans[1:]:
        p = predictor.update(scan)
    steps = np.diff([s.stamp_ns for s in scans])
    assert steps.min() <= p.step_ns <= steps.max()  # the stream's step so far
    assert p.stamp_ahead_ns(3) == scans[-1].stamp_ns + 3 * p.step_ns
