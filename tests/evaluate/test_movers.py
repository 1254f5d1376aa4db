"""The mover metric: dynamic region, tolerant F1, AUC, soft IoU, and their place in evaluate."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lidarflow.evaluate.dynamic import (
    WorldCells,
    dynamic_cells,
    frame_region,
    recording_region,
    world_counts,
)
from lidarflow.evaluate.metrics import confusion
from lidarflow.evaluate.movers import MoverScore, TolerantCounts, near, roc_auc
from lidarflow.scan import GridSpec

masks = arrays(bool, (8, 9))


def blob(r: int, c: int, shape: tuple[int, int] = (20, 20)) -> np.ndarray:
    out = np.zeros(shape, bool)
    out[r : r + 2, c : c + 2] = True
    return out


def test_near_is_a_euclidean_disc():
    one = np.zeros((7, 7), bool)
    one[3, 3] = True
    assert near(one, 2).sum() == 13  # offsets with dr^2 + dc^2 <= 4
    assert near(one, 2)[1, 3] and not near(one, 2)[1, 1]  # (2, 2) is 2.83 cells away
    assert (near(one, 0) == one).all()
    with pytest.raises(ValueError, match="mask must be"):
        near(np.zeros(3, bool))


@given(masks, st.integers(0, 3))
def test_near_covers_the_mask_and_matches_brute_force(mask, radius):
    got = near(mask, radius)
    cells = np.argwhere(mask)
    for r, c in itertools.product(range(mask.shape[0]), range(mask.shape[1])):
        want = bool(len(cells)) and bool((((cells - (r, c)) ** 2).sum(1) <= radius**2).any())
        assert got[r, c] == want


@given(masks, masks, masks)
def test_tolerant_f1_is_never_below_exact_f1(predicted, target, region):
    exact = confusion(predicted, target, region)
    tolerant = TolerantCounts.of(predicted, target, region)
    assert tolerant.f1 >= exact.f1 - 1e-12
    assert tolerant.precision >= exact.precision - 1e-12
    assert tolerant.recall >= exact.recall - 1e-12
    assert TolerantCounts.of(predicted, target, region, radius=0).f1 == pytest.approx(exact.f1)


@given(masks, masks)
def test_exact_mover_f1_on_an_all_true_region_is_the_all_cell_f1(predicted, target):
    score = MoverScore()
    score.add(predicted.astype(np.float32), target, np.ones_like(target))
    assert score.summary()["f1"] == confusion(predicted, target).f1


def test_a_blob_predicted_one_cell_short_is_found_with_tolerance_only():
    truth, predicted, region = blob(5, 5), blob(5, 6), np.ones((20, 20), bool)
    score = MoverScore()
    score.add(predicted.astype(np.float32), truth, region)
    s = score.summary()
    assert s["f1"] == pytest.approx(0.5) and s["f1_tolerant"] == 1.0
    far = MoverScore()
    far.add(blob(5, 12).astype(np.float32), truth, region)
    assert far.summary()["f1_tolerant"] == 0.0  # 0.7 m off is a miss


def test_a_wall_outside_the_region_does_not_find_a_person_beside_it():
    wall = np.zeros((20, 20), bool)
    wall[:, 10] = True
    person = blob(5, 11)
    region = ~wall
    score = MoverScore()
    score.add(wall.astype(np.float32), person | wall, region)  # predicts the wall only
    assert score.summary()["f1_tolerant"] == 0.0


@given(st.lists(st.tuples(st.floats(0, 1), st.booleans()), min_size=1, max_size=40))
def test_auc_from_bins_is_the_pairwise_probability_of_ranking(cells):
    p = np.array([[c[0] for c in cells]])
    y = np.array([[c[1] for c in cells]])
    score = MoverScore()
    score.add(p, y, np.ones_like(y))
    auc = score.summary()["auc"]
    if y.all() or not y.any():
        assert auc is None
        return
    bins = np.minimum(np.floor(p * 200), 200)
    pos, neg = bins[y], bins[~y]
    pairs = (pos[:, None] > neg[None, :]) + 0.5 * (pos[:, None] == neg[None, :])
    assert auc == pytest.approx(pairs.mean())


def test_roc_auc_known_values():
    assert roc_auc(np.array([1, 0]), np.array([1, 0])) == 0.5
    assert roc_auc(np.array([1, 0]), np.array([0, 1])) == 0.0
    assert np.isnan(roc_auc(np.array([0, 0]), np.array([1, 0])))


def test_soft_iou_is_the_waymo_definition():
    p = np.array([[0.5, 1.0, 0.0]])
    y = np.array([[True, True, False]])
    score = MoverScore()
    score.add(p, y, np.ones_like(y))
    assert score.soft_iou == pytest.approx((0.5 + 1.0) / (1.0 + 1.0 + 0.0))


@settings(max_examples=30)
@given(masks, masks, masks, masks, masks)
def test_scores_add_up_as_if_scored_together(p1, t1, p2, t2, region):
    a, b, both = MoverScore(), MoverScore(), MoverScore()
    a.add(p1.astype(float), t1, region)
    b.add(p2.astype(float), t2, region)
    both.add(p1.astype(float), t1, region)
    both.add(p2.astype(float), t2, region)
    assert (a + b).summary() == both.summary()


def test_dynamic_cells_a_wall_is_not_dynamic_a_passer_by_is():
    n = 100
    occupancy = np.zeros((n, 20, 20), bool)
    occupancy[:, 2, :] = True  # a wall, always there
    for t in range(20):  # a person crossing once, one cell a frame: each cell 2 frames of 100
        occupancy[t] |= blob(10, t)
    visibility = np.ones_like(occupancy)
    cells = WorldCells(GridSpec(20, 20, 0.1), None, n)
    occupied, seen = world_counts(lambda t: (occupancy[t], visibility[t]), cells)
    region = frame_region(dynamic_cells(occupied, seen), cells)(0)
    assert not region[2].any()  # the wall
    assert region[10:12, :].all()  # where the person went
    assert region.sum() == 40


def test_dynamic_cells_needs_an_occupancy_and_a_low_share():
    assert dynamic_cells(np.array([0, 1, 5]), np.array([100, 100, 100])).tolist() == [
        False,
        True,
        False,
    ]
    with pytest.raises(ValueError, match="differ in shape"):
        dynamic_cells(np.zeros(2), np.zeros(3))


SMALL = GridSpec(40, 40, 0.1)


def driving_past_a_wall(n: int = 60, grid: GridSpec = SMALL):
    """A sensor driving forward one cell every two frames towards a wall across the map at
    world x = 3.55 m, and a 2 x 1 person crossing the map at world x = 1.55 m (a cell a frame)."""
    poses = np.zeros((n, 3))
    poses[:, 0] = np.arange(n) // 2 * grid.res
    occupancy = np.zeros((n, *grid.shape), bool)
    for t in range(n):
        # world x of row r: pose + (H - r - 0.5) * res  ->  r = H - 0.5 - (x - pose) / res
        wall = round(grid.height - 0.5 - (3.55 - poses[t, 0]) / grid.res)
        if 0 <= wall < grid.height:
            occupancy[t, wall, :] = True
        person = round(grid.height - 0.5 - (1.55 - poses[t, 0]) / grid.res)
        if 0 <= person < grid.height - 1:
            occupancy[t, person : person + 2, t % 40] = True
    return poses, occupancy


def test_the_region_is_counted_in_the_world_frame_on_a_moving_platform():
    grid = GridSpec(40, 40, 0.1)
    poses, occupancy = driving_past_a_wall(grid=grid)
    visibility = np.ones_like(occupancy)
    masks_of = lambda t: (occupancy[t], visibility[t])  # noqa: E731
    world = WorldCells(grid, poses, len(poses))
    region = frame_region(dynamic_cells(*world_counts(masks_of, world)), world)
    t = 10
    wall_row = np.flatnonzero(occupancy[t].all(axis=1))
    assert len(wall_row) == 1 and not region(t)[wall_row[0]].any()  # registered: static
    assert (region(t) & occupancy[t]).sum() == 2  # the person is in it
    # counted in the sensor frame, the wall sweeps over the map and reads as dynamic
    sensor = WorldCells(grid, None, len(poses))
    smeared = frame_region(dynamic_cells(*world_counts(masks_of, sensor)), sensor)
    assert smeared(t)[wall_row[0]].all()


def test_a_frame_of_unknown_pose_has_an_empty_region():
    grid = GridSpec(40, 40, 0.1)
    poses, occupancy = driving_past_a_wall(grid=grid)
    poses[5] = np.nan
    world = WorldCells(grid, poses, len(poses))
    region = frame_region(
        dynamic_cells(*world_counts(lambda t: (occupancy[t], np.ones_like(occupancy[t])), world)),
        world,
    )
    assert not region(5).any() and region(6).any()
    assert (world(5) == -1).all()


def test_a_simulated_recording_scores_its_true_movers():
    from lidarflow.baselines import CopyLast
    from lidarflow.evaluate.runner import evaluate_recording
    from lidarflow.evaluate.stream import ground_truth_moving, mover_region, recording_inputs
    from lidarflow.sim import SimConfig, simulate

    rec = simulate(24, seed=3, config=SimConfig(scenario="dynamic"))
    grid = GridSpec()
    moving = ground_truth_moving(rec, grid)
    assert moving is not None
    inputs = recording_inputs(rec, grid, [CopyLast()])
    region = mover_region(rec, grid, inputs)
    for t in range(len(rec)):  # every true moving cell lies in its frame's region
        held = moving(t) & np.asarray(inputs.occupancy[t], bool)
        assert not (held & ~region(t)).any()
    assert sum(int(region(t).sum()) for t in range(len(rec))) > 0
    again = recording_region(rec, grid, inputs.occupancy, inputs.visibility, moving)
    assert (again(7) == region(7)).all()
    movers = evaluate_recording(rec, [CopyLast()], grid, warmup=2)["copy_last"].summary()
    assert movers["movers"]["true_cells"] > 0
    assert movers["mover_f1_tolerant"] >= movers["mover_f1"]


def test_a_model_that_loses_on_movers_to_copy_last_does_not_win():
    from lidarflow.evaluate.report import against_baselines, format_comparison

    base = {"f1": 0.9, "changed_f1": 0.0, "mover_f1": 0.2, "mover_f1_tolerant": 0.8}
    methods = {
        "copy_last": base,
        "temporal_average": {**base, "changed_f1": 0.2, "mover_f1_tolerant": 0.5},
        "constant_velocity": base,
        "walls": {"f1": 0.95, "changed_f1": 0.3, "mover_f1": 0.1, "mover_f1_tolerant": 0.3},
        "movers": {"f1": 0.95, "changed_f1": 0.3, "mover_f1": 0.3, "mover_f1_tolerant": 0.85},
    }
    got = against_baselines(methods)
    assert not got["walls"]["wins"] and got["movers"]["wins"]
    assert got["walls"]["mover_f1_margin"] == pytest.approx(-0.5)
    assert "tolerant mover F1 -0.5000 (copy_last): loses" in format_comparison(got)
    # nothing moved: the mover metric does not decide
    assert against_baselines(methods, ["mover_f1"])["walls"]["wins"]


def test_the_horizon_verdict_needs_the_movers_k_steps_ahead_too():
    from lidarflow.evaluate.report import add_horizon_verdict

    entry = {
        "against_baselines": {"m": {"wins": True}},
        "horizon_mover_f1_tolerant": {"copy_last": [0.9, 0.5], "m": [0.95, 0.4]},
    }
    add_horizon_verdict(entry)
    verdict = entry["against_baselines"]["m"]
    assert verdict["wins"] is False
    assert verdict["mover_f1_horizon_margin"] == pytest.approx(-0.1)


def test_horizon_scores_the_movers_k_steps_ahead():
    from lidarflow.evaluate.runner import horizon_scores

    n = 25
    occupancy = np.zeros((n, 20, 30), np.float32)
    occupancy[:, 0, :] = 1  # a wall
    for t in range(n):  # a person crossing once, a cell every frame
        occupancy[t, 10:12, t] = 1
    visibility = np.ones_like(occupancy)
    cells = WorldCells(GridSpec(20, 30, 0.1), None, n)
    region = frame_region(
        dynamic_cells(*world_counts(lambda t: (occupancy[t], visibility[t]), cells)), cells
    )
    scores = horizon_scores(occupancy, visibility, [], horizon=3, warmup=2, region=region)
    exact, tolerant = scores["mover_f1"]["copy_last"], scores["mover_f1_tolerant"]["copy_last"]
    assert exact[0] == 0.0  # the person is always a cell further on
    assert tolerant[0] == 1.0 and tolerant[1] == 1.0 and tolerant[2] == 0.0  # 3 cells: too far
    assert scores["mover_true_cells"]["copy_last"][0] > 0


def test_the_table_and_the_html_report_show_the_mover_metric(tmp_path):
    from lidarflow.baselines import CopyLast, TemporalAverage
    from lidarflow.evaluate.report import build_report, format_table
    from lidarflow.evaluate.runner import evaluate_maps
    from lidarflow.viz.html import write_html_report

    n = 25
    occupancy = np.zeros((n, 20, 30), np.float32)
    occupancy[:, 0, :] = 1
    for t in range(n):
        occupancy[t, 10:12, t] = 1
    cells = WorldCells(GridSpec(20, 30, 0.1), None, n)
    region = frame_region(
        dynamic_cells(*world_counts(lambda t: (occupancy[t], occupancy[t] >= 0), cells)), cells
    )
    scores = evaluate_maps(
        occupancy, occupancy >= 0, [CopyLast(), TemporalAverage()], warmup=2, region=region
    )
    report = build_report([("scene", scores)])
    methods = report["recordings"][0]["methods"]
    copied = methods["copy_last"]
    assert copied["mover_f1"] == 0.0 and copied["mover_f1_tolerant"] == 1
    assert "mover_f1_tolerant" in format_table(methods).splitlines()[0]
    page = write_html_report(report, tmp_path / "index.html").read_text().replace("<wbr>", "")
    assert "mover_f1_tolerant" in page and "mover_soft_iou" in page
