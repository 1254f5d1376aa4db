"""Ego motion in evaluation, prediction and the CLI: poses reach the models, the compensation
baseline, refusals without poses, and the Predictor's pose input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarflow.baselines import CopyLast, CopyLastEgo, FrameInputs
from lidarflow.errors import EvaluateError, PredictError
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.runner import evaluate_recording
from lidarflow.models import build_model
from lidarflow.motion.icp import recording_points
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.scanmatch import scan_motions
from lidarflow.outputs.export import copy_marks, export_onnx
from lidarflow.outputs.job import predict_to_bag
from lidarflow.predict import Predictor
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, simulate
from tests.conftest import make_model_dir
from tests.hand_stream import HandStream
from tests.test_cli import run

GRID = GridSpec(40, 40, 0.05)


@pytest.fixture(scope="module")
def driving():
    return simulate(60, seed=3, config=SimConfig(scenario="dynamic", episode_frames=100, grid=GRID))


@pytest.mark.slow
def test_compensation_beats_copy_last_and_the_untrained_ego_model_is_exactly_it(driving):
    untrained = ModelMethod("ego", build_model("flownet", ego_motion=True))
    oracle = ModelMethod("ego_oracle", build_model("flownet", ego_motion=True), oracle=True)
    scores = evaluate_recording(
        driving, [CopyLast(), CopyLastEgo(), CopyLastEgo(oracle=True), untrained, oracle], GRID
    )
    s = {k: v.summary() for k, v in scores.items()}
    assert s["copy_last_ego"]["f1"] > s["copy_last"]["f1"] + 0.03
    assert s["copy_last_ego_oracle"]["f1"] >= s["copy_last_ego"]["f1"] - 0.01
    # zero world flow: the ego model predicts the last map moved by the odometry, nothing else
    for key in ("f1", "changed_f1", "ap"):
        assert s["ego"][key] == pytest.approx(s["copy_last_ego"][key], abs=2e-3)
        assert s["ego_oracle"][key] == pytest.approx(s["copy_last_ego_oracle"][key], abs=2e-3)
    assert s["ego"]["epe"] < 0.6  # the ego flow alone explains a static world seen driving


def test_ego_models_refuse_a_recording_without_poses(driving):
    blind = driving.slice(0, len(driving))
    blind.poses = None
    ego = ModelMethod("ego", build_model("flownet", ego_motion=True))
    methods = [CopyLast(), ego]
    with pytest.raises(EvaluateError, match=r"no sensor poses.*ego"):
        evaluate_recording(blind, methods, GRID)
    evaluate_recording(blind, [CopyLast()], GRID)  # the others still run


def test_predictor_takes_poses_like_the_streaming_evaluation(driving, tmp_path):
    folder = make_model_dir(tmp_path / "ego", ego_motion=True, zero_init_flow=False)
    predictor = Predictor(folder, GRID)
    assert predictor.uses_motion
    stream = HandStream(predictor.backend.model)
    occ, vis = driving.maps(GRID)
    motions = metres_to_cells(relative_motions(driving.poses)[0], GRID.res)
    for t in range(8):
        p = predictor.update((occ[t], vis[t]), driving.poses[t])
        ref = stream.step(occ[t], vis[t], motions[t] if t else None)
        np.testing.assert_allclose(p.probability, ref.probability, atol=1e-6)
        assert p.ego_compensated == (t > 0)
    assert not predictor.update((occ[8], vis[8]), None).ego_compensated
    blind = driving.slice(0, 12)
    blind.poses = None
    with pytest.raises(PredictError, match="no sensor poses"):
        predict_to_bag(blind, predictor, tmp_path / "out.mcap")


def test_onnx_export_of_an_ego_model_matches_pytorch_with_poses(driving, tmp_path):
    folder = make_model_dir(tmp_path / "ego", ego_motion=True, zero_init_flow=False)
    torch_p = Predictor(folder, GRID)
    onnx_p = Predictor(export_onnx(torch_p.backend.model, tmp_path / "m.onnx", 40, 40), GRID)
    assert onnx_p.uses_motion
    occ, vis = driving.maps(GRID)
    worst = 0.0
    for t in range(12):
        pose = None if t == 6 else driving.poses[t]  # an unknown pose: zeros in ONNX
        a, b = torch_p.update((occ[t], vis[t]), pose), onnx_p.update((occ[t], vis[t]), pose)
        worst = max(worst, float(np.abs(a.probability - b.probability).max()))
        worst = max(worst, float(np.abs(a.backward_flow - b.backward_flow).max()))
        worst = max(worst, float(np.abs(a.forward_flow - b.forward_flow).max()))
        assert a.ego_compensated == b.ego_compensated
    assert worst < 1e-4


def test_onnx_matches_pytorch_when_the_robot_steps_exactly_half_a_cell(sample_recording, tmp_path):
    # Half-cell steps leave the warped previous map at exactly 0.5, where the two backends'
    # warps differ by 1e-5: the constant-velocity shift must not hinge on that.
    from lidarflow.models.presets import resolve_model

    net, _ = resolve_model(None)  # the bundled model: constant-velocity input, shifted memories
    onnx = export_onnx(net, tmp_path / "b.onnx", 100, 100, 0.1)
    torch_p, onnx_p = Predictor(None), Predictor(onnx)
    worst = 0.0
    for t in range(8):
        scan, pose = sample_recording.scan(t), (0.05 * t, 0.0, 0.0)
        a, b = torch_p.update(scan, pose), onnx_p.update(scan, pose)
        worst = max(worst, float(np.abs(a.probability - b.probability).max()))
    assert worst < 1e-3


@pytest.mark.slow
def test_cli_train_ego_then_evaluate_scores_the_compensation(driving, tmp_path, capsys):
    data = driving.save(tmp_path / "drive.npz")
    code, _, err = run(
        [
            "train",
            str(data),
            "--ego-motion",
            "-o",
            str(tmp_path / "run"),
            "--grid",
            "40",
            "--res",
            "0.05",
            "--seq-len",
            "8",
            "--warmup",
            "3",
            "--batch-size",
            "4",
            "--epochs",
            "1",
            "--threads",
            "1",
            "--set",
            "runtime.tensorboard=false",
        ],
        capsys,
    )
    assert code == 0, err
    assert json.loads((tmp_path / "run" / "model.json").read_text())["model_kwargs"] == {
        "ego_motion": True
    }
    out = tmp_path / "e.json"
    code, _, err = run(
        [
            "evaluate",
            str(data),
            "--model",
            str(tmp_path / "run"),
            "--grid",
            "40",
            "--res",
            "0.05",
            "--ego-oracle",
            "--json",
            str(out),
        ],
        capsys,
    )
    assert code == 0, err
    methods = json.loads(out.read_text())["recordings"][0]["methods"]
    assert {"copy_last_ego", "copy_last_ego_oracle", "run", "run_oracle"} <= set(methods)
    blind = driving.slice(0, len(driving))
    blind.poses = None
    code, _, err = run(
        [
            "evaluate", str(blind.save(tmp_path / "blind.npz")), "--model", str(tmp_path / "run"),
            "--grid", "40", "--res", "0.05",
        ],
        capsys,
    )  # fmt: skip
    assert code == 1 and "no sensor poses" in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_poses_optional_models_take_the_motion_from_the_scans_without_poses(driving, tmp_path):
    blind = driving.slice(0, 30)
    blind.poses = None
    kwargs = {"occupancy_head": True, "constant_velocity_input": True, "zero_init_flow": False}
    folder = make_model_dir(tmp_path / "opt", ego_motion=True, poses_optional=True, **kwargs)
    optional = Predictor(folder, GRID)
    assert optional.uses_motion and optional.poses_optional
    model = optional.backend.model
    scores = evaluate_recording(blind, [CopyLast(), CopyLastEgo(), ModelMethod("opt", model)], GRID)
    s = {k: v.summary() for k, v in scores.items()}
    # The drive's motion matched from the scans: moving the last map by it beats copying it.
    assert s["copy_last_ego"]["f1"] > s["copy_last"]["f1"] + 0.03
    # The Predictor steps the model with the same matched motions; without them (scan_odometry
    # off) it is the inner network, step for step.
    occ, vis = blind.maps(GRID)
    motions = scan_motions(occ)
    stream, inner = HandStream(model), HandStream(model.inner)
    blind_predictor = Predictor(folder, GRID, scan_odometry=False)
    for t in range(8):
        known = None if np.isnan(motions[t]).any() else motions[t]
        a, b = optional.update((occ[t], vis[t])), stream.step(occ[t], vis[t], known)
        np.testing.assert_allclose(a.probability, b.probability, atol=1e-5)
        assert a.ego_compensated == (known is not None)
        c, d = blind_predictor.update((occ[t], vis[t])), inner.step(occ[t], vis[t])
        np.testing.assert_allclose(c.probability, d.probability, atol=1e-6)
        assert not c.ego_compensated
    assert np.isfinite(motions[1:8, 0]).sum() >= 4  # the robot drives: most steps matched
    counts = predict_to_bag(blind, optional, tmp_path / "out.mcap")
    assert sum(counts.values()) > 0
    # A model that needs poses beside it is still refused, and named.
    needing = ModelMethod("needs", build_model("flownet", ego_motion=True))
    with pytest.raises(EvaluateError, match=r"no sensor poses.*needs") as err:
        evaluate_recording(blind, [CopyLast(), needing, CopyLastEgo()], GRID)
    assert "copy_last_ego" not in str(err.value)
    # The ONNX file carries the mark (and a graph rewritten from it, as int8 is, copies it).
    onnx_path = export_onnx(optional.backend.model, tmp_path / "opt.onnx", 40, 40)
    assert Predictor(onnx_path, GRID).poses_optional
    plain = export_onnx(build_model("flownet", ego_motion=True), tmp_path / "plain.onnx", 40, 40)
    assert not Predictor(plain, GRID).poses_optional
    copy_marks(onnx_path, plain)
    assert Predictor(plain, GRID).poses_optional


def test_a_predictor_given_scans_steps_the_model_with_the_motion_refined_on_their_returns(
    driving, tmp_path
):
    blind = driving.slice(0, 24)
    blind.poses = None
    kwargs = {"occupancy_head": True, "constant_velocity_input": True, "zero_init_flow": False}
    folder = make_model_dir(tmp_path / "opt", ego_motion=True, poses_optional=True, **kwargs)
    predictor = Predictor(folder, GRID, check_odometry=False)
    occ, vis = blind.maps(GRID)
    refined = scan_motions(occ, recording_points(blind), GRID.res)
    maps_only = scan_motions(occ)
    # Past the window the returns refine every step, so the two sources differ.
    assert not np.allclose(np.nan_to_num(refined[12:]), np.nan_to_num(maps_only[12:]))
    stream = HandStream(predictor.backend.model)
    for t in range(len(blind)):
        known = None if np.isnan(refined[t]).any() else refined[t]
        a, b = predictor.update(blind.scan(t)), stream.step(occ[t], vis[t], known)
        np.testing.assert_allclose(a.probability, b.probability, atol=1e-5)
        assert a.ego_compensated == (known is not None)


@pytest.mark.slow
def test_poses_optional_models_stop_compensating_odometry_that_disagrees_with_the_scans(
    driving, tmp_path
):
    folder = make_model_dir(tmp_path / "opt", ego_motion=True, poses_optional=True)
    needing = Predictor(make_model_dir(tmp_path / "need", ego_motion=True), GRID)
    dropping = Predictor(folder, GRID, scan_odometry=False)
    occ, vis = driving.maps(GRID)
    mirrored = driving.poses * np.array([1, -1, -1])  # a pose source with its y axis flipped
    flags = [dropping.update((occ[t], vis[t]), mirrored[t]).ego_compensated for t in range(60)]
    assert flags[1] and not flags[-1]  # trusted at first, dropped once the scans disagree
    # With scan odometry (the default) the scans' own motion replaces the odometry once they
    # disagree: the drive stays compensated, by a motion close to the true one, not the mirror's.
    optional = Predictor(folder, GRID)
    flags = [optional.update((occ[t], vis[t]), mirrored[t]).ego_compensated for t in range(60)]
    assert flags[1] and sum(flags[-20:]) >= 15
    # The evaluation decides the same, frame by frame; a model that needs poses never drops them.
    method = ModelMethod("opt", optional.backend.model, res=GRID.res)
    motions = metres_to_cells(relative_motions(mirrored)[0], GRID.res)
    optional.reset()
    for t in range(60):
        p = optional.update((occ[t], vis[t]), mirrored[t])
        q = method.update(occ[t], vis[t], FrameInputs(motions[t] if t else None))
        np.testing.assert_allclose(p.probability, q, atol=1e-6)
    kept = [needing.update((occ[t], vis[t]), mirrored[t]).ego_compensated for t in range(60)]
    assert all(kept[1:])
    # Given the scans' returns, the evaluation's fallback is the refined motion: the true one.
    method.reset()
    returns = recording_points(driving.slice(0, 60))
    true = metres_to_cells(relative_motions(driving.poses)[0], GRID.res)
    errors = []
    for t in range(60):
        method.update(occ[t], vis[t], FrameInputs(motions[t] if t else None, returns=returns[t]))
        if not method.engine.odometry.trusted and method.motion is not None:
            errors.append(np.abs(method.motion - true[t]))
    assert len(errors) >= 15
    error = np.median(errors, axis=0)
    assert error[:2].max() < 0.1 and error[2] < np.deg2rad(0.2)


def test_evaluate_gives_the_model_the_returns_to_replace_odometry_that_disagrees(driving, tmp_path):
    folder = make_model_dir(tmp_path / "opt", ego_motion=True, poses_optional=True)
    mirrored = driving.slice(0, 60)
    mirrored.poses = mirrored.poses * np.array([1, -1, -1])
    method = ModelMethod("opt", Predictor(folder, GRID).backend.model, res=GRID.res)
    evaluate_recording(mirrored, [CopyLast(), method], GRID)
    # The last frame evaluated (58) was compensated by the scans' motion, not the mirror's.
    true = metres_to_cells(relative_motions(driving.poses)[0], GRID.res)[58]
    assert not method.engine.odometry.trusted and method.motion is not None
    np.testing.assert_allclose(method.motion[:2], true[:2], atol=0.15)


def test_a_pose_jump_is_not_compensated_in_the_predictor_or_the_evaluation(driving, tmp_path):
    from lidarflow.data.recording import Recording
    from lidarflow.motion.pacing import paces_after_long_steps
    from lidarflow.sim.platform import compose, relative

    folder = make_model_dir(tmp_path / "opt", ego_motion=True, poses_optional=True)
    true_poses = driving.poses.copy()
    # index: frame. An odometry reset at 30; at 42, right after 3 scans dropped, the poses move
    # 3 m and turn 0.8 rad (a relocalisation)
    jumps = {30: 30, 39: 42}
    kept = [t for t in range(50) if not 39 <= t <= 41]
    reset = true_poses.copy()
    reset[30:] = [relative(reset[30], p) for p in reset[30:]]
    reset[42:] = [compose((3.0, -1.5, 0.8), p) for p in reset[42:]]
    cut = Recording.from_scans([driving.scan(t) for t in kept], reset[kept], driving.meta)
    paces = paces_after_long_steps(cut.stamps_ns)
    assert list(paces) == [39]  # index 39 of the cut is frame 42
    occ, vis = cut.maps(GRID)
    true = metres_to_cells(relative_motions(true_poses[kept])[0], GRID.res)
    jumped = metres_to_cells(relative_motions(cut.poses)[0], GRID.res)
    predictor = Predictor(folder, GRID)
    method = ModelMethod("opt", predictor.backend.model, res=GRID.res)
    returns = recording_points(cut)
    for t in range(len(kept)):
        p = predictor.update(cut.scan(t), cut.poses[t])
        given = FrameInputs(jumped[t] if t else None, pace=paces.get(t), returns=returns[t])
        q = method.update(occ[t], vis[t], given)
        np.testing.assert_allclose(p.probability, q, atol=1e-6)  # the same decisions
        if t in jumps:  # a motion close to the true one, not the jump
            assert p.ego_compensated and method.engine.odometry.jumped
            np.testing.assert_allclose(
                method.motion[:2], true[t][:2], atol=0.3 * (1 + 3 * (t == 39))
            )
    assert method.engine.odometry.jumps == 2


def test_copy_last_ego_is_scored_beside_ego_models_with_or_without_poses(driving, tmp_path, capsys):
    # Without poses the model and copy_last_ego both get the motion matched from the scans, so
    # the baseline still shows what compensation alone buys: on a drive it beats copy-last.
    folder = make_model_dir(tmp_path / "opt", ego_motion=True, poses_optional=True)
    blind = driving.slice(0, 30)
    blind.poses = None
    for recording in (blind, driving.slice(0, 30)):
        out = tmp_path / "e.json"
        data = recording.save(tmp_path / "r.npz")
        args = ["evaluate", str(data), "-m", str(folder), "--grid", "40", "--res", "0.05"]
        code, _, err = run([*args, "--json", str(out), "--force"], capsys)
        assert code == 0, err
        entry = json.loads(out.read_text())["recordings"][0]
        methods = entry["methods"]
        assert "opt" in methods and "copy_last_ego" not in entry["against_baselines"]
        assert methods["copy_last_ego"]["f1"] > methods["copy_last"]["f1"] + 0.02


@pytest.mark.slow
def test_horizon_scores_roll_ego_models_forward_with_the_motion(driving):
    from lidarflow.evaluate.runner import horizon_scores

    occ, vis = driving.maps(GRID)
    motions = metres_to_cells(relative_motions(driving.poses)[0], GRID.res)
    model = build_model("flownet", occupancy_head=True, ego_motion=True, poses_optional=True)
    models = [ModelMethod("ego", model, res=GRID.res)]
    moved = horizon_scores(occ, vis, models, horizon=2, warmup=5, motions=motions)["f1"]
    still = horizon_scores(occ, vis, models, horizon=2, warmup=5)["f1"]
    # Untrained it is copy-last in its own frame: without motions exactly copy-last, with the
    # odometry the last map moved into the next frame(s), which is better on a drive.
    assert still["ego"] == pytest.approx(still["copy_last"])
    assert moved["ego"][0] > moved["copy_last"][0] + 0.03
    assert moved["ego"][1] > moved["copy_last"][1] + 0.03
    # Odometry with its y axis flipped is distrusted after a while; said to be odometry, it is
    # then replaced by the scans' own motion (refined on the returns), as the Predictor does.
    mirrored = metres_to_cells(relative_motions(driving.poses * [1, -1, -1])[0], GRID.res)
    returns = recording_points(driving)
    kwargs = {"horizon": 2, "warmup": 5, "motions": mirrored}
    dropped = horizon_scores(occ, vis, models, **kwargs)["f1"]
    replaced = horizon_scores(occ, vis, models, **kwargs, returns=returns, motions_from_poses=True)[
        "f1"
    ]
    assert replaced["ego"][0] > dropped["ego"][0] + 0.02


def _f1(predicted: np.ndarray, truth: np.ndarray) -> float:
    from lidarflow.evaluate.metrics import confusion

    return confusion(predicted, truth).f1


def test_after_a_gap_the_next_motion_is_guessed_for_one_step_not_for_the_gap(driving, tmp_path):
    # Six scans of a drive cut out: the motion into the frame after the cut spans seven steps.
    # Guessed again whole for the next step, an untrained ego model (copy-last moved by the
    # guess) falls below copy-last; scaled to one step it is the last map moved right.
    kept = [*range(30), *range(36, 60)]
    cut = driving.__class__.from_scans([driving.scan(k) for k in kept], driving.poses[kept])
    folder = make_model_dir(tmp_path / "ego", ego_motion=True)
    onnx = export_onnx(build_model("flownet", ego_motion=True), tmp_path / "ego.onnx", 40, 40)
    occupancy, _ = cut.maps(GRID)
    copy_last = _f1(occupancy[30], occupancy[31])
    for model in (folder, onnx):
        scores = {}
        for stamped in (True, False):
            predictor = Predictor(model, GRID, check_odometry=False, scan_odometry=False)
            for i in range(31):
                scan = cut.scan(i)
                if not stamped:  # no stamps: no gap can be seen
                    scan = scan.__class__(scan.ranges, scan.geometry, 0)
                prediction = predictor.update(scan, pose=cut.poses[i])
            scores[stamped] = _f1(prediction.occupied, occupancy[31])
        assert scores[True] > copy_last + 0.05 > scores[False] + 0.1, (model, scores, copy_last)
    # evaluate paces the guess the same way (the step across the gap itself is not scored)
    after: dict[str, np.ndarray] = {}

    def keep(name, t, probability, flow):
        if t == 30:
            after[name] = probability >= 0.4

    ego = ModelMethod("ego", build_model("flownet", ego_motion=True))
    evaluate_recording(cut, [CopyLast(), CopyLastEgo(), ego], GRID, on_prediction=keep)
    assert _f1(after["ego"], occupancy[31]) == pytest.approx(scores[True])
    assert _f1(after["copy_last_ego"], occupancy[31]) == pytest.approx(scores[True])
