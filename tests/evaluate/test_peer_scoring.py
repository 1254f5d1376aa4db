"""The peers' metrics through the streamed evaluation: a method's WMSE and SSIM in the report are
the metrics of its own predictions, averaged over the scored frames, per recording, overall and
per horizon step."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.baselines import CopyLast
from lidarflow.evaluate.peer_metrics import ssim, wmse
from lidarflow.evaluate.report import build_report, format_peer_table
from lidarflow.evaluate.runner import evaluate_maps, horizon_scores


def _walker(n: int = 14, size: int = 16) -> np.ndarray:
    """A wall and a 2 x 2 block walking one column a frame: big enough for SSIM's window."""
    occupancy = np.zeros((n, size, size), bool)
    occupancy[:, 1, :] = True
    for t in range(n):
        occupancy[t, 8:10, t % (size - 1) : t % (size - 1) + 2] = True
    return occupancy


class Blurred:
    """A method whose probability is known: the last map at 0.7, a 0.2 haze elsewhere."""

    name = "blurred"

    def reset(self) -> None:
        pass

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: object = None
    ) -> np.ndarray:
        return np.where(occupancy, 0.7, 0.2).astype(np.float32)


def test_a_methods_wmse_and_ssim_are_those_of_its_predictions():
    occupancy = _walker()
    warmup = 3
    scorers = evaluate_maps(occupancy, np.ones_like(occupancy), [CopyLast(), Blurred()], warmup)
    frames = range(warmup, len(occupancy) - 1)
    for name, predict in (
        ("copy_last", lambda o: o.astype(np.float32)),
        ("blurred", lambda o: np.where(o, 0.7, 0.2)),
    ):
        summary = scorers[name].summary()
        assert summary["frames"] == len(frames)
        by_hand = [float(wmse(predict(occupancy[t]), occupancy[t + 1])) for t in frames]
        assert summary["wmse"] == pytest.approx(np.mean(by_hand), rel=1e-6)
        by_hand = [float(ssim(predict(occupancy[t]), occupancy[t + 1])) for t in frames]
        assert summary["ssim"] == pytest.approx(np.mean(by_hand), rel=1e-6)
    # the haze costs the blurred map on the free cells, its 0.7 on the occupied ones
    assert scorers["blurred"].summary()["wmse"] != scorers["copy_last"].summary()["wmse"]


def test_overall_averages_every_frame_of_every_recording_once():
    long, short = _walker(20), _walker(8)
    a = evaluate_maps(long, np.ones_like(long), [CopyLast()], warmup=2)
    b = evaluate_maps(short, np.ones_like(short), [CopyLast()], warmup=2)
    report = build_report([("a", a), ("b", b)])
    fa, fb = a["copy_last"].frames, b["copy_last"].frames
    for key in ("wmse", "ssim"):
        va, vb = (r["methods"]["copy_last"][key] for r in report["recordings"])
        assert report["overall"]["copy_last"][key] == pytest.approx((fa * va + fb * vb) / (fa + fb))


def test_a_grid_under_the_ssim_window_has_wmse_but_no_ssim():
    occupancy = _walker(size=16)[:, :10, :]
    summary = evaluate_maps(occupancy, np.ones_like(occupancy), [CopyLast()], 2)["copy_last"]
    assert "wmse" in summary.summary() and "ssim" not in summary.summary()


def test_horizon_scores_have_wmse_and_ssim_per_step():
    occupancy = _walker(16)
    visibility = np.ones_like(occupancy)
    horizon, warmup = 3, 4
    scores = horizon_scores(occupancy, visibility, [Blurred()], horizon, warmup)
    assert list(scores) == ["f1", "changed_f1", "wmse", "ssim"]
    scored = range(warmup, len(occupancy) - horizon)
    for k in range(horizon):
        truths = [occupancy[t + 1 + k] for t in scored]
        # copy-last's k-step prediction is O^t
        copy = [occupancy[t].astype(float) for t in scored]
        assert scores["wmse"]["copy_last"][k] == pytest.approx(
            np.mean([float(wmse(p, y)) for p, y in zip(copy, truths, strict=True)])
        )
        assert scores["ssim"]["copy_last"][k] == pytest.approx(
            np.mean([float(ssim(p, y)) for p, y in zip(copy, truths, strict=True)]), rel=1e-6
        )
    # the blurred method fed its decided map back (0.7 >= 0.4: the last map) blurs it again at
    # every step: its own output k ahead is the haze over O^t
    blurred = [np.where(occupancy[t], 0.7, 0.2) for t in scored]
    for k in range(horizon):
        truths = [occupancy[t + 1 + k] for t in scored]
        expected = np.mean([float(wmse(p, y)) for p, y in zip(blurred, truths, strict=True)])
        assert scores["wmse"]["blurred"][k] == pytest.approx(expected)
    assert all(len(v) == horizon for per in scores.values() for v in per.values())


def test_the_peer_table_marks_the_lowest_wmse_and_the_highest_ssim():
    methods = {
        "a": {"f1": 0.5, "wmse": 0.10, "ssim": 0.40},
        "b": {"f1": 0.6, "wmse": 0.20, "ssim": 0.70},
    }
    lines = format_peer_table(methods, "peers").splitlines()
    assert lines[0] == "peers" and lines[1].split() == ["method", "wmse", "ssim"]
    assert lines[2].split() == ["a", "0.1000*", "0.4000"]
    assert lines[3].split() == ["b", "0.2000", "0.7000*"]
    assert format_peer_table({"a": {"f1": 0.5}}) == ""
