"""Calibration and moving-object segmentation in the streaming evaluator and its reports."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarflow.baselines import CopyLast, Takes
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.report import build_report, format_table, format_uncertainty_table
from lidarflow.evaluate.runner import evaluate_maps, evaluate_recording
from lidarflow.evaluate.stream import ground_truth_moving
from lidarflow.models.presets import resolve_model
from lidarflow.predict.moving import moving_mask
from lidarflow.scan import GridSpec
from tests.conftest import make_model_dir
from tests.evaluate.test_evaluate import moving_square

OLD_KEYS = {"f1", "precision", "recall", "ap", "changed_f1", "frames"}


class MovingFromTruth:
    """Copies the last map and reports ``moving_of(t)`` as its moving cells (frame t given)."""

    takes = Takes()

    def __init__(self, name, moving_of):
        self.name, self.moving_of, self.t = name, moving_of, -1
        self.moving = None

    def reset(self):
        self.t = -1

    def update(self, occupancy, visibility, given=None):
        self.t += 1
        self.moving = self.moving_of(self.t) & occupancy.astype(bool)
        return occupancy.astype(np.float32)


def square_truth(maps):
    truth = np.zeros_like(maps)
    truth[:, 8:12] = maps[:, 8:12]  # the square moves, the wall (row 20) does not
    return truth


def test_segmentation_scored_against_truth_of_the_frame_just_given():
    maps = moving_square()
    truth = square_truth(maps)
    methods = [
        MovingFromTruth("oracle", lambda t: truth[t]),
        MovingFromTruth("late", lambda t: truth[max(t - 1, 0)]),  # one frame behind
        MovingFromTruth("nothing", lambda t: np.zeros_like(truth[t])),
        CopyLast(),
    ]
    seen = []
    scorers = evaluate_maps(
        maps,
        maps,
        methods,
        warmup=3,
        gt_moving=lambda t: truth[t],
        on_moving=lambda name, t, m, gt: seen.append((name, t)),
    )
    oracle = scorers["oracle"].summary()["segmentation"]
    assert oracle["iou"] == 1.0 and oracle["frames"] == len(maps) - 1 - 3
    assert scorers["late"].summary()["segmentation"]["iou"] < 1.0
    nothing = scorers["nothing"].summary()["segmentation"]
    assert nothing["iou"] == 0.0 and nothing["recall"] == 0.0 and nothing["fn"] > 0
    assert "segmentation" not in scorers["copy_last"].summary()
    assert ("oracle", 3) in seen and not any(name == "copy_last" for name, _ in seen)


def test_every_method_gets_calibration_and_old_keys_stay():
    maps = moving_square()
    scorers = evaluate_maps(maps, maps, [CopyLast()], warmup=2)
    summary = scorers["copy_last"].summary()
    assert set(summary) >= OLD_KEYS | {"calibration"}
    cal = summary["calibration"]
    # copy-last is binary: ECE is the share of the cells whose value changes, over all cells
    changed = sum(int((maps[t] != maps[t + 1]).sum()) for t in range(2, len(maps) - 1))
    assert cal["cells"] == (len(maps) - 3) * maps[0].size
    assert cal["ece"] == pytest.approx(changed / cal["cells"])
    assert cal["brier"] == pytest.approx(changed / cal["cells"])
    assert [b["count"] > 0 for b in cal["bins"]] == [True] + [False] * 8 + [True]


def test_report_adds_up_and_tables_show_the_new_columns():
    maps = moving_square()
    truth = square_truth(maps)
    methods = [MovingFromTruth("oracle", lambda t: truth[t]), CopyLast()]
    a = evaluate_maps(maps, maps, methods, warmup=2, gt_moving=lambda t: truth[t])
    b = evaluate_maps(maps, maps, methods, warmup=2, gt_moving=lambda t: truth[t])
    report = build_report([("a", a), ("b", b)])
    json.dumps(report)
    overall = report["overall"]
    assert overall["oracle"]["segmentation"]["frames"] == 2 * a["oracle"].moving_frames
    assert overall["copy_last"]["calibration"]["cells"] == 2 * a["copy_last"].calibration.cells
    table = format_uncertainty_table(overall)
    assert "ece_active" in table and "moving_iou" in table and "1.0000" in table
    assert "calibration" not in format_table(overall)  # the first table is unchanged
    assert format_uncertainty_table({"x": {"f1": 1.0}}) == ""


def test_best_calibration_is_the_lowest():
    methods = {
        "a": {"calibration": {"ece": 0.2, "brier": 0.1}},
        "b": {"calibration": {"ece": 0.1, "brier": 0.3}},
    }
    lines = format_uncertainty_table(methods).splitlines()[1:]  # below its title
    assert "0.1000*" in lines[1] and "0.2000 " in lines[1]  # a: brier best
    assert lines[2].split()[1] == "0.1000*"  # b: ece best


def test_simulated_moving_truth_lines_up_with_the_frames():
    from lidarflow.sim import SimConfig, simulate

    rec = simulate(16, seed=0, config=SimConfig(scenario="static"))  # people walk from frame 0
    truth = ground_truth_moving(rec, GridSpec())
    assert truth is not None and ground_truth_moving(rec, GridSpec(50, 50, 0.2)) is None
    methods = [MovingFromTruth("oracle", truth), MovingFromTruth("next", lambda t: truth(t + 1))]
    scores = evaluate_recording(rec, methods, GridSpec(), warmup=2)
    seg = scores["oracle"].summary()["segmentation"]
    assert seg["iou"] == 1.0 and seg["tp"] > 100  # frame t is scored against truth t
    assert scores["next"].summary()["segmentation"]["iou"] < 0.9


def test_model_method_exposes_flows_and_moving(tmp_path):
    net, _ = resolve_model(make_model_dir(tmp_path / "f", zero_init_flow=False))
    method = ModelMethod("f", net, moving_threshold=0.2)
    maps = moving_square(n=3, size=100)
    method.update(maps[0], maps[0])
    assert method.forward_flow.shape == (2, 100, 100)
    expected = moving_mask(maps[0], method.forward_flow, 0.2)
    np.testing.assert_array_equal(method.moving, expected)
    assert not (method.moving & ~maps[0]).any()
    method.reset()
    assert method.moving is None and method.forward_flow is None
    dt, _ = resolve_model(make_model_dir(tmp_path / "dt", name="deeptracking"))
    deep = ModelMethod("dt", dt)
    deep.update(maps[0], maps[0])
    assert deep.moving is None and deep.backward_flow is None


def test_moving_cells_are_scored_on_every_frame_even_before_a_gap():
    # a gap ends the next-map step from frame 9, not frame 9's own moving cells
    maps = moving_square()
    truth = square_truth(maps)
    seen = []
    scorers = evaluate_maps(
        maps, maps, [MovingFromTruth("oracle", lambda t: truth[t])], warmup=3,
        gt_moving=lambda t: truth[t], on_moving=lambda name, t, m, gt: seen.append(t), gaps=[10],
    )  # fmt: skip
    assert seen == list(range(3, len(maps) - 1))
    oracle = scorers["oracle"]
    assert oracle.moving_frames == len(maps) - 1 - 3 and oracle.frames == len(maps) - 1 - 3 - 1


def test_the_table_is_titled_by_what_it_holds():
    calibration = {"a": {"calibration": {"ece": 0.2, "brier": 0.1}}}
    assert format_uncertainty_table(calibration).splitlines()[0] == "calibration"
    moving = {"a": {"segmentation": {"iou": 0.5, "precision": 0.5, "recall": 0.5, "frames": 1}}}
    header = format_uncertainty_table({**calibration, **moving}, "overall ").splitlines()[0]
    assert header.startswith("overall calibration and moving segmentation")
