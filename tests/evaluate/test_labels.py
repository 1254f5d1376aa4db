"""Labelled movers: the files read against a recording, and recall and precision per k."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarflow.baselines import CopyLast
from lidarflow.cli import main
from lidarflow.data import load_recording
from lidarflow.errors import BagError, EvaluateError
from lidarflow.evaluate.evaluation import score_one
from lidarflow.evaluate.labels import (
    CEILING,
    LabelCounts,
    Labels,
    LabelScore,
    frames_by_stamps,
    label_counts,
    read_labels,
)
from lidarflow.scan import GridSpec, cell_centres
from tests.bagutil import write_bag, write_legs_bag, write_people_bag
from tests.conftest import make_recording

GRID = GridSpec(10, 10, 0.1)  # x in [0, 1), y in [-0.5, 0.5)
#: The centre of cell (2, 3) of GRID: x = (10 - 2 - 0.5) * 0.1, y = (5 - 3 - 0.5) * 0.1.
CELL, CENTRE = (2, 3), (0.75, 0.15)


def _decided(*cells: tuple[int, int]) -> np.ndarray:
    out = np.zeros(GRID.shape, bool)
    for r, c in cells:
        out[r, c] = True
    return out


def test_a_leg_on_an_occupied_cell_is_found_and_the_cell_is_near_it():
    legs = np.array([CENTRE, (CENTRE[0] - 0.29, CENTRE[1]), (CENTRE[0] - 0.31, CENTRE[1])])
    counts = label_counts(_decided(CELL), legs, np.ones(GRID.shape, bool), GRID)
    assert counts == LabelCounts(found=2, labelled=3, near=1, predicted=1, frames=1)


def test_labels_outside_the_grid_are_not_counted_but_still_make_a_cell_near():
    beyond = np.array([[1.05, 0.15]])  # past the far edge, 0.3 m from the cell at row 0
    counts = label_counts(_decided((0, 3)), beyond, np.ones(GRID.shape, bool), GRID)
    assert (counts.labelled, counts.found, counts.near, counts.predicted) == (0, 0, 1, 1)
    assert counts.recall is None and counts.precision == 1.0


def test_precision_counts_only_the_occupied_cells_of_the_region():
    decided = _decided(CELL, (9, 9))  # one near the leg, one far from it
    region = np.zeros(GRID.shape, bool)
    region[9, 9] = True
    counts = label_counts(decided, np.array([CENTRE]), region, GRID)
    assert (counts.found, counts.near, counts.predicted) == (1, 0, 1)
    assert label_counts(decided, np.zeros((0, 2)), region, GRID).precision == 0.0


def test_label_counts_refuses_maps_of_another_grid():
    with pytest.raises(ValueError, match="grid"):
        label_counts(np.zeros((5, 5), bool), np.zeros((0, 2)), np.zeros((5, 5), bool), GRID)


def test_each_k_is_scored_against_the_labels_of_frame_t_plus_k():
    score = LabelScore({5: np.array([CENTRE])}, GRID, 3, lambda t: np.ones(GRID.shape, bool))
    ahead = np.zeros((3, *GRID.shape), np.float32)
    ahead[1][CELL] = 1.0  # k = 2 from t = 3: frame 5
    ahead[2][CELL] = 0.39  # under the decision
    score.add("m", 3, ahead)
    out = score.summary()["m"]
    assert out["recall"] == [None, 1.0, None]
    assert out["precision"] == [None, 1.0, None]
    assert out["frames"] == [0, 1, 0] and out["labelled"] == [0, 1, 0]
    score.add("m", 2, ahead)  # frame 5 is now k = 3 away, where nothing is decided
    assert score.summary()["m"]["recall"] == [None, 1.0, 0.0]


def _legs_of(recording, frame: int, grid: GridSpec) -> list[tuple[float, float]]:
    """A 'leg' on an occupied cell of ``frame``."""
    occupancy, _ = recording.maps(grid)
    x, y = cell_centres(grid)
    r, c = np.argwhere(occupancy[frame] > 0)[0]
    return [(float(x[r, c]), float(y[r, c]))]


def test_score_one_scores_the_labels_beside_the_scan_itself_at_every_horizon():
    recording, grid = make_recording(20), GridSpec(100, 100, 0.1)
    positions = {f: np.array(_legs_of(recording, f, grid)) for f in (12, 14)}
    for horizon in (1, 3):
        scored = score_one("r", recording, [CopyLast()], grid, 10, horizon, labels=Labels(
            positions, "legs"
        ))  # fmt: skip
        legs = scored.notes["legs"]
        assert list(legs) == ["copy_last", CEILING] and scored.notes["legs_kind"] == "legs"
        assert legs[CEILING]["recall"] == [1.0] * horizon
        assert len(legs["copy_last"]["precision"]) == horizon
        assert sum(legs[CEILING]["frames"]) > 0


def test_legs_are_given_to_the_frames_whose_ranges_their_scans_have(tmp_path):
    recording = make_recording(12)
    scans = [recording.scan(i).ranges for i in (3, 7, 9)] + [np.full(181, 2.0, np.float32)]
    legs = [[(1.0, 0.5)], [], [(2.0, -0.5), (2.5, 0.0)], [(3.0, 0.0)]]
    for legs_first in (True, False):
        path = write_legs_bag(tmp_path / f"legs_{legs_first}.bag", scans, legs, legs_first)
        labels = read_labels(path, recording)
        assert sorted(labels.positions) == [3, 7, 9] and labels.unmatched == 1
        assert labels.kind == "legs" and labels.positions[7].shape == (0, 2)
        np.testing.assert_allclose(labels.positions[9], [(2.0, -0.5), (2.5, 0.0)])


def test_legs_that_cannot_be_paired_or_matched_are_refused(tmp_path):
    recording = make_recording(12)
    scans = [recording.scan(i).ranges for i in (3, 7)]
    unpaired = write_legs_bag(tmp_path / "unpaired.bag", scans, [[(1.0, 0.0)]])
    with pytest.raises(EvaluateError, match="cannot be paired"):
        read_labels(unpaired, recording)
    other = write_legs_bag(tmp_path / "other.bag", scans, [[(1.0, 0.0)]] * 2)
    with pytest.raises(EvaluateError, match="none of its 2 labelled scans"):
        read_labels(other, make_recording(12, seed=1))
    with pytest.raises(EvaluateError, match="no labels"):
        read_labels(write_bag(tmp_path / "plain.bag"), recording)
    (tmp_path / "junk.bag").write_bytes(b"not a bag")
    with pytest.raises(BagError):
        read_labels(tmp_path / "junk.bag", recording)


def test_people_are_given_to_the_scan_a_period_before_their_log_time(tmp_path):
    recording = make_recording(12)  # a scan every 0.1 s from 1 s
    period, stamps = 10**8, recording.stamps_ns
    path = write_people_bag(
        tmp_path / "people.bag",
        [(int(stamps[4]) + period, 1.0, 0.0), (int(stamps[4]) + period + 10, 2.0, 0.5),
         (int(stamps[-1]) + 5 * period, 3.0, 0.0)],
    )  # fmt: skip
    labels = read_labels(path, recording)
    assert labels.kind == "people" and labels.unmatched == 1
    np.testing.assert_allclose(labels.positions[4], [(1.0, 0.0), (2.0, 0.5)])
    assert frames_by_stamps(np.array([5]), np.zeros(0, np.int64), 1).tolist() == [-1]


def _run(argv, capsys):
    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out = capsys.readouterr()
    return code, out.out, out.err


#: ``evaluate`` of the short real recording, scored from its third frame 2 ahead.
EVALUATE = ["evaluate", "--baselines-only", "--warmup", "2", "--horizon", "2"]


def _short_legs(short, tmp_path):
    """A label file of the short recording: a leg on an occupied cell of frames 4..6."""
    recording, grid, frames = load_recording(short), GridSpec(), (4, 5, 6)
    return write_legs_bag(
        tmp_path / "legs.bag",
        [recording.scan(f).ranges for f in frames],
        [_legs_of(recording, f, grid) for f in frames],
    )


@pytest.mark.slow
def test_evaluate_legs_prints_and_writes_the_labelled_table(short, tmp_path, capsys):
    legs, out_json = _short_legs(short, tmp_path), tmp_path / "scores.json"
    argv = [*EVALUATE, str(short), "--legs", str(legs), "-o", str(out_json)]
    code, out, err = _run(argv, capsys)
    assert code == 0, err
    assert "labelled legs within 0.3 m" in out and "scan (ceiling)" in out
    entry = json.loads(out_json.read_text())["recordings"][0]
    assert entry["legs"][CEILING]["recall"] == [1.0, 1.0]
    assert set(entry["legs"]["copy_last"]) == {"recall", "precision", "labelled", "frames"}


def test_evaluate_refuses_a_bad_label_file_in_one_line(short, tmp_path, capsys):
    code, _, err = _run([*EVALUATE, str(short), "--legs", str(short)], capsys)  # no bag
    assert code == 1 and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    legs = _short_legs(short, tmp_path)
    code, _, err = _run([*EVALUATE, str(short), "--legs", str(legs), "--legs", str(legs)], capsys)
    assert code == 2 and "one --legs per recording" in err


def test_the_legs_intervals_compare_each_method_with_copy_last_on_the_same_frames():
    # a leg on CELL at every frame 1..40; copy-last finds it every other frame, "m" always,
    # "same" exactly as copy-last: recall 2x copy-last's, then 1x, precision alike
    everywhere = np.ones(GRID.shape, bool)
    score = LabelScore({t: np.array([CENTRE]) for t in range(1, 41)}, GRID, 1, lambda t: everywhere)
    found = np.zeros(GRID.shape, np.float32)
    found[CELL] = 1.0
    for t in range(40):
        score.add("copy_last", t, found if t % 2 else np.zeros_like(found))
        score.add("same", t, found if t % 2 else np.zeros_like(found))
        score.add("m", t, found)
    intervals = score.intervals()
    assert set(intervals) == {"same", "m"}
    assert intervals["same"] == {"recall_ratio": [[1.0, 1.0]], "precision_margin": [[0.0, 0.0]]}
    low, high = intervals["m"]["recall_ratio"][0]
    assert 1.5 < low <= 2.0 <= high < 2.5  # 2x, give or take the frames drawn
    assert intervals["m"]["precision_margin"] == [[0.0, 0.0]]  # every cell it decides is a leg
    rows = np.array([c.row() for c in score.frames["m"][0].values()])
    assert (
        tuple(rows.sum(0))
        == (40, 40, 40, 40)
        == tuple(
            getattr(score.counts["m"][0], f) for f in ("found", "labelled", "near", "predicted")
        )
    )
    assert LabelScore({}, GRID, 1, lambda t: everywhere).intervals() == {}
