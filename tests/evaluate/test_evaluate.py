"""Baselines, scoring and the streaming evaluator on maps whose answers are known."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarflow.baselines import (
    ConstantVelocity,
    CopyLast,
    Takes,
    TemporalAverage,
    best_rigid_shift,
    shift_map,
)
from lidarflow.errors import EvaluateError
from lidarflow.evaluate.report import build_report, format_table
from lidarflow.evaluate.runner import evaluate_maps
from lidarflow.evaluate.scoring import Scorer
from lidarflow.scan import GridSpec


def moving_square(n: int = 20, size: int = 24, step: int = 1) -> np.ndarray:
    maps = np.zeros((n, size, size), bool)
    for t in range(n):
        c = 2 + (t * step) % (size - 6)
        maps[t, 8:12, c : c + 3] = True
    maps[:, 20, 2:20] = True  # a static wall
    return maps


class Oracle:
    """Knows the future: predicts exactly the next map."""

    name = "oracle"
    takes = Takes()

    def __init__(self, maps: np.ndarray) -> None:
        self.maps = maps
        self.t = 0

    def reset(self) -> None:
        self.t = 0

    def update(self, occupancy, visibility, given=None):
        self.t += 1
        return self.maps[min(self.t, len(self.maps) - 1)].astype(np.float32)


def test_shift_map_moves_content_and_fills_zeros():
    image = np.arange(9).reshape(3, 3) + 1
    assert shift_map(image, 0, 1).tolist() == [[0, 0, 0], [1, 2, 3], [4, 5, 6]]
    assert shift_map(image, -1, 0).tolist() == [[2, 3, 0], [5, 6, 0], [8, 9, 0]]
    assert not shift_map(image, 5, 0).any()


@pytest.mark.parametrize("shift", [(0, 0), (2, -1), (-3, 3)])
def test_best_rigid_shift_recovers_a_known_shift(shift):
    rng = np.random.default_rng(1)
    prev = rng.random((30, 30)) < 0.1
    cur = shift_map(prev, *shift)
    assert best_rigid_shift(prev, cur) == shift


def test_constant_velocity_extrapolates_a_rigid_motion():
    maps = np.zeros((3, 20, 20), bool)
    for t in range(3):
        maps[t, 5:8, 3 + 2 * t : 5 + 2 * t] = True
    cv = ConstantVelocity()
    cv.update(maps[0], maps[0])
    prediction = cv.update(maps[1], maps[1])
    assert np.array_equal(prediction >= 0.4, maps[2])


def test_temporal_average_threshold_maps_to_decision_threshold():
    ta = TemporalAverage(window=5, threshold=0.4)
    frames = [np.array([[1, 0]], bool), np.array([[1, 0]], bool), np.array([[0, 0]], bool)]
    for f in frames:
        p = ta.update(f, f)
    assert p[0, 0] >= 0.4 and p[0, 1] == 0.0  # mean 2/3 >= 0.4
    ta = TemporalAverage(window=5, threshold=0.8)
    for f in frames:
        p = ta.update(f, f)
    assert p[0, 0] < 0.4  # mean 2/3 < 0.8


def test_oracle_scores_one_and_copy_last_scores_zero_on_changed_cells():
    maps = moving_square()
    scorers = evaluate_maps(maps, maps, [Oracle(maps), CopyLast()], warmup=3)
    oracle, copy = scorers["oracle"].summary(), scorers["copy_last"].summary()
    assert oracle["f1"] == 1.0 and oracle["changed_f1"] == 1.0 and oracle["ap"] == 1.0
    assert copy["changed_f1"] == 0.0 and 0.5 < copy["f1"] < 1.0
    assert scorers["oracle"].frames == len(maps) - 1 - 3


def test_copy_last_counts_by_hand():
    maps = np.zeros((4, 1, 4), bool)
    maps[:, 0, 0] = True
    maps[3, 0, 1] = True  # appears in the last frame only
    s = evaluate_maps(maps, maps, [CopyLast()], warmup=1)["copy_last"]
    # predictions after frames 1 and 2: frame 1 -> 2 all right; frame 2 -> 3 misses one cell
    assert (s.counts.tp, s.counts.fp, s.counts.fn) == (2, 0, 1)
    assert (s.changed.tp, s.changed.fp, s.changed.fn) == (0, 0, 1)


def test_average_precision_of_a_binary_predictor():
    s = Scorer()
    prob = np.array([1.0, 1.0, 0.0, 0.0])
    target = np.array([True, False, True, False])
    s.add(prob, target, target)
    # one operating point (P=0.5, R=0.5), then everything (P=0.5, R=1): AP = 0.5
    assert s.average_precision() == pytest.approx(0.5)
    _, precision, recall = s.pr_curve()
    assert recall[-1] == 1.0 and precision[0] == 0.5


def test_micro_average_over_recordings_and_json_shape(tmp_path):
    a = evaluate_maps(moving_square(), moving_square(), [CopyLast()], warmup=2)
    b = evaluate_maps(moving_square(step=2), moving_square(step=2), [CopyLast()], warmup=2)
    report = build_report([("a", a), ("b", b)])
    total = a["copy_last"].counts + b["copy_last"].counts
    assert report["overall"]["copy_last"]["f1"] == total.f1
    entry = report["recordings"][0]
    assert entry["path"] == "a" and entry["frames_evaluated"] == 17
    assert set(entry["methods"]["copy_last"]) >= {"f1", "precision", "recall", "ap", "changed_f1"}
    json.dumps(report)
    assert "copy_last" in format_table(report["overall"])


def test_too_short_recording_is_an_evaluate_error():
    maps = np.zeros((11, 4, 4), bool)
    with pytest.raises(EvaluateError, match="at least 12 frames"):
        evaluate_maps(maps, maps, [CopyLast()], warmup=10)


class FlowOracle:
    """Copies the last map but reports the simulator's true backward flow."""

    name = "flow_oracle"
    takes = Takes()

    def __init__(self, flow_of):
        self.flow_of, self.t = flow_of, -1
        self.backward_flow = None

    def reset(self):
        self.t = -1

    def update(self, occupancy, visibility, given=None):
        self.t += 1
        self.backward_flow = self.flow_of(self.t)
        return occupancy.astype(np.float32)


def test_flow_end_point_error_on_simulated_data():
    from lidarflow.evaluate.runner import evaluate_recording
    from lidarflow.evaluate.stream import ground_truth_backward_flow
    from lidarflow.sim import SimConfig, simulate

    rec = simulate(16, seed=3, config=SimConfig(scenario="dynamic"))
    truth = ground_truth_backward_flow(rec, GridSpec())
    assert truth is not None
    zero = FlowOracle(lambda t: np.zeros((2, 100, 100)))
    zero.name = "zero_flow"
    scores = evaluate_recording(rec, [FlowOracle(truth), zero], GridSpec(), warmup=2)
    assert scores["flow_oracle"].summary()["epe"] == pytest.approx(0.0, abs=1e-6)
    assert scores["zero_flow"].summary()["epe"] > 0.05  # the robot drives: the world moves
    assert (
        "epe"
        not in evaluate_recording(rec, [CopyLast()], GridSpec(), warmup=2)["copy_last"].summary()
    )
    assert ground_truth_backward_flow(rec, GridSpec(50, 50, 0.2)) is None


def two_scenes(n: int = 30, cut: int = 15) -> np.ndarray:
    """A still scene, then at frame ``cut`` another, disjoint one (as after a gap)."""
    maps = np.zeros((n, 6, 6), bool)
    maps[:cut, 1, 1:3] = True
    maps[cut:, 4, 3:5] = True
    return maps


class Counting(CopyLast):
    name = "counting"

    def __init__(self) -> None:
        self.seen = 0

    def reset(self) -> None:
        self.seen = 0

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: object = None
    ) -> np.ndarray:
        self.seen += 1
        return super().update(occupancy, visibility)


def test_the_step_across_a_gap_is_not_scored_but_every_frame_is_seen():
    maps = two_scenes()
    counting = Counting()
    across = evaluate_maps(maps, maps, [CopyLast()], warmup=2)["copy_last"]
    assert across.frames == 27 and across.counts.f1 < 1.0  # the jump counted as a miss
    skipped = evaluate_maps(maps, maps, [CopyLast(), counting], warmup=2, gaps=[15])
    assert skipped["copy_last"].frames == 26 and skipped["copy_last"].counts.f1 == 1.0
    assert counting.seen == 29  # the state carries across: nothing reset, nothing left out


def test_a_recording_with_every_step_across_a_gap_is_an_evaluate_error():
    maps = np.zeros((12, 4, 4), bool)
    with pytest.raises(EvaluateError, match="across a gap"):
        evaluate_maps(maps, maps, [CopyLast()], warmup=10, gaps=[11])


def test_evaluate_recording_finds_the_gaps_in_its_stamps():
    import dataclasses

    from lidarflow.data.recording import Recording
    from lidarflow.evaluate.runner import evaluate_recording
    from tests.conftest import make_recording

    steady = make_recording(n=30)
    scans = [
        dataclasses.replace(s, stamp_ns=s.stamp_ns + (5 * 10**9 if i >= 20 else 0))
        for i, s in enumerate(steady)
    ]
    gapped = Recording.from_scans(scans)
    a = evaluate_recording(steady, [CopyLast()], GridSpec(), warmup=2)["copy_last"]
    b = evaluate_recording(gapped, [CopyLast()], GridSpec(), warmup=2)["copy_last"]
    assert (a.frames, b.frames) == (27, 26)


def test_horizon_scores_no_roll_out_across_a_gap():
    import torch

    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.evaluate.runner import horizon_scores
    from lidarflow.models import build_model

    maps = two_scenes()
    model = [ModelMethod("m", build_model("deeptracking"))]
    torch.manual_seed(0)
    across = horizon_scores(maps, maps, model, horizon=3, warmup=2)["f1"]
    skipped = horizon_scores(maps, maps, model, horizon=3, warmup=2, gaps=[15])["f1"]
    assert min(across["copy_last"]) < 1.0
    assert skipped["copy_last"] == [1.0, 1.0, 1.0]
    with pytest.raises(EvaluateError, match="without a gap"):
        horizon_scores(maps[:8], maps[:8], model, horizon=3, warmup=2, gaps=[4, 6])["f1"]


def test_against_baselines_wins_only_above_the_best_baseline_on_both_terms():
    from lidarflow.evaluate.report import against_baselines, format_comparison

    methods = {
        "copy_last": {"f1": 0.92, "changed_f1": 0.0},
        "temporal_average": {"f1": 0.89, "changed_f1": 0.30},
        "constant_velocity": {"f1": 0.91, "changed_f1": 0.10},
        "copy_last_ego": {"f1": 0.99, "changed_f1": 0.99},  # a baseline, not a model
        "good_oracle": {"f1": 0.99, "changed_f1": 0.99},  # knows the next pose: no verdict
        "good": {"f1": 0.93, "changed_f1": 0.31},
        "f1_only": {"f1": 0.95, "changed_f1": 0.29},
        "changed_only": {"f1": 0.919, "changed_f1": 0.5},
    }
    got = against_baselines(methods)
    assert set(got) == {"good", "f1_only", "changed_only"}
    assert got["good"]["wins"] and not got["f1_only"]["wins"] and not got["changed_only"]["wins"]
    assert got["f1_only"]["f1_baseline"] == "copy_last"
    assert got["f1_only"]["changed_f1_baseline"] == "temporal_average"
    assert got["good"]["f1_margin"] == pytest.approx(0.01)
    assert got["f1_only"]["changed_f1_margin"] == pytest.approx(-0.01)
    line = format_comparison({"good": got["good"]})
    assert line == (
        "good against the best baseline: F1 +0.0100 (copy_last), "
        "changed-cell F1 +0.0100 (temporal_average): wins"
    )
    assert against_baselines({"good": methods["good"]}) == {}


def test_report_counts_the_recordings_each_model_won():
    maps = moving_square()
    oracle_only = evaluate_maps(maps, maps, [Oracle(maps), CopyLast()], warmup=2)
    report = build_report([("a", oracle_only), ("b", oracle_only)])
    assert report["recordings"][0]["against_baselines"]["oracle"]["wins"]
    overall = report["against_baselines"]["oracle"]
    assert (overall["recordings_won"], overall["recordings"], overall["wins"]) == (2, 2, True)


def test_frame_blocks_are_the_arrays_they_stand_for(sample_recording):
    from lidarflow.data.blocks import FrameBlocks

    rec, grid = sample_recording.slice(0, 23), GridSpec()
    occupancy = rec.maps(grid)[0]
    calls = []

    def compute(a, b):
        calls.append((a, b))
        return rec.maps(grid, a, b)[0]

    blocks = FrameBlocks(compute, len(rec), block=5)
    assert len(blocks) == 23
    for t in range(23):  # as the evaluation reads them: t, then t + 1
        np.testing.assert_array_equal(blocks[t], occupancy[t])
        if t + 1 < 23:
            np.testing.assert_array_equal(blocks[t + 1], occupancy[t + 1])
    assert calls == [(0, 5), (5, 10), (10, 15), (15, 20), (20, 23)]  # each block once
    np.testing.assert_array_equal(blocks[-1], occupancy[-1])
    assert len(blocks[2:9]) == 7 and len(list(blocks)) == 23
    with pytest.raises(IndexError):
        blocks[23]


@pytest.mark.slow
def test_evaluate_recording_streamed_in_blocks_scores_as_on_whole_arrays(
    sample_recording, monkeypatch
):
    from lidarflow.data import blocks
    from lidarflow.evaluate.dynamic import recording_region
    from lidarflow.evaluate.ego import recording_motions
    from lidarflow.evaluate.methods import methods_and_config
    from lidarflow.evaluate.runner import evaluate_recording

    rec, grid = sample_recording.slice(0, 40), GridSpec()
    methods, _ = methods_and_config([None])
    occupancy, visibility = rec.maps(grid)
    whole = evaluate_maps(
        occupancy, visibility, methods, motions=recording_motions(rec, grid, methods, occupancy),
        subcell=rec.subcell_maps(grid),
        region=recording_region(rec, grid, occupancy, visibility),
    )  # fmt: skip
    monkeypatch.setattr(blocks, "BLOCK_FRAMES", 7)
    streamed = evaluate_recording(rec, methods, grid)
    for name, scorer in whole.items():
        assert streamed[name].summary() == scorer.summary(), name


def test_no_win_or_loss_is_claimed_on_a_metric_with_nothing_to_find():
    from lidarflow.evaluate.report import format_comparison

    blind = np.zeros((8, 24, 24), bool)
    scored = evaluate_maps(blind, blind, [Oracle(blind), CopyLast()], warmup=2)
    maps = moving_square()
    seeing = evaluate_maps(maps, maps, [Oracle(maps), CopyLast()], warmup=2)
    report = build_report([("blind", scored), ("seeing", seeing)])
    entry = report["recordings"][0]
    assert entry["undefined"] == ["f1", "recall", "ap", "changed_f1"]
    assert entry["methods"]["oracle"]["f1"] == 1.0  # Counts' 0/0 convention is kept
    assert entry["against_baselines"]["oracle"]["wins"] is None
    assert "undefined" not in report["recordings"][1] and "undefined" not in report
    overall = report["against_baselines"]["oracle"]
    assert (overall["recordings_won"], overall["recordings_undecided"]) == (1, 1)
    assert format_comparison(entry["against_baselines"]).endswith(": undecided (nothing to find)")
    assert "won 1 of 2 recordings (1 undecided)" in format_comparison(report["against_baselines"])


def test_a_run_folder_named_like_an_oracle_is_still_judged(sample_recording, tmp_path, capsys):
    from tests.conftest import make_model_dir
    from tests.test_cli import run

    folder = make_model_dir(tmp_path / "mine_oracle")
    data = sample_recording.slice(0, 15).save(tmp_path / "r.npz")
    out = tmp_path / "e.json"
    code, _, err = run(["evaluate", str(data), "-m", str(folder), "--json", str(out)], capsys)
    assert code == 0, err
    report = json.loads(out.read_text())
    assert "mine_oracle" in report["recordings"][0]["against_baselines"]
    # the report says which temporal average, and how it was chosen
    average = report["config"]["temporal_average"]
    assert (average["window"], average["threshold"]) == (3, 0.4)
    assert average["chosen"].startswith("the default: of a grid of windows and thresholds")


def test_flow_error_split_into_moving_and_static_cells():
    from lidarflow.evaluate.runner import evaluate_recording
    from lidarflow.evaluate.stream import ground_truth_backward_flow
    from lidarflow.sim import SimConfig, simulate

    rec = simulate(16, seed=2, config=SimConfig(scenario="dynamic"))  # people in view
    truth = ground_truth_backward_flow(rec, GridSpec())
    zero = FlowOracle(lambda t: np.zeros((2, 100, 100)))
    zero.name = "zero_flow"
    scores = evaluate_recording(rec, [FlowOracle(truth), zero], GridSpec(), warmup=2)
    exact = scores["flow_oracle"].summary()
    assert exact["epe_moving"] == pytest.approx(0.0, abs=1e-6)
    assert exact["epe_static"] == pytest.approx(0.0, abs=1e-6)
    z = scores["zero_flow"]
    # the split covers every scored cell once: the two means pool back to the overall one
    assert z.epe_moving_cells + z.epe_static_cells == z.epe_cells > 0
    assert (z.epe_moving_sum + z.epe_static_sum) / z.epe_cells == pytest.approx(z.summary()["epe"])
    # walls move with the driving robot: zero flow errs there too, but people move more
    assert z.epe_moving_cells > 0 and z.summary()["epe_static"] > 0.05
    # a robot standing still: zero flow is exact on every static cell
    still = simulate(16, seed=0, config=SimConfig(scenario="static"))
    s = evaluate_recording(still, [zero], GridSpec(), warmup=2)["zero_flow"].summary()
    assert s["epe_static"] < 0.15 < s.get("epe_moving", 1.0)
