"""The tracking baseline on hand-made scenes (issue 44)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lidarflow.baselines import FrameInputs
from lidarflow.tracking import (
    Tracker,
    TrackerConfig,
    Tracks,
    associate,
    cluster_labels,
    composed_motion,
    foreground,
)

H = W = 40
SEEN = np.ones((H, W), np.float32)


def _wall() -> np.ndarray:
    m = np.zeros((H, W), np.float32)
    m[3, 2:38] = 1
    m[3:30, 2] = 1
    return m


def _blob(m: np.ndarray, row: int, col: int) -> None:
    """A person: two legs 0.3 m (3 cells) apart, each one cell."""
    for r, c in ((row, col), (row, col + 3)):
        if 0 <= r < H and 0 <= c < W:
            m[r, c] = 1


def _walker(t: int, d_row: int, d_col: int) -> np.ndarray:
    m = _wall()
    _blob(m, 20 + d_row * (t - 15), 15 + d_col * (t - 15))
    return m


def _run(tracker: Tracker, frames: list[np.ndarray]) -> list[np.ndarray]:
    return [tracker.update(f, SEEN) for f in frames]


def test_a_static_wall_stays_and_gets_no_velocity():
    tracker = Tracker(res=0.1)
    predictions = _run(tracker, [_wall()] * 20)
    assert all(np.array_equal(p >= 0.4, _wall() > 0) for p in predictions)
    assert tracker.tracks().objects == []
    assert all(np.array_equal(a >= 0.4, _wall() > 0) for a in tracker.ahead(5))


@settings(max_examples=12, deadline=None)
@given(st.integers(-2, 2), st.integers(-2, 2).filter(bool))
def test_a_constant_velocity_blob_is_predicted_exactly_k_ahead(d_row, d_col):
    # it walks in from outside the map (a blob there from the first frame is background)
    tracker = Tracker(res=0.1)
    frames = [_walker(t, d_row, d_col) for t in range(20)]
    _run(tracker, frames[:16])  # entering at rest, then converged
    for k, ahead in enumerate(tracker.ahead(4), start=1):
        assert np.array_equal(ahead >= 0.4, frames[15 + k] > 0), k
    ((state, cells),) = tracker.tracks().objects
    assert state[2:] == pytest.approx([-d_row, -d_col], abs=0.1)  # x forward = up the rows
    assert len(cells) == 2


def test_two_legs_03_m_apart_are_one_track_and_one_metre_apart_two():
    tracker = Tracker(res=0.1)
    m = np.zeros((H, W), np.float32)
    tracker.update(m, SEEN)
    _blob(m, 20, 10)  # legs 3 cells apart
    m[20, 30] = m[21, 30] = 1  # another object 1.7 m away
    tracker.update(m, SEEN)
    assert sorted(len(cells) for _, cells in tracker.tracks().objects) == [2, 2]


def test_two_people_crossing_keep_their_own_velocities():
    def frame(t: int) -> np.ndarray:
        m = np.zeros((H, W), np.float32)
        _blob(m, 12, 2 + t)  # walks right along row 12
        _blob(m, 20, 34 - t)  # walks left along row 20, 0.8 m away: never one cluster
        return m

    tracker = Tracker(res=0.1)
    frames = [frame(t) for t in range(30)]
    _run(tracker, frames[:26])  # they passed each other around t = 16
    velocities = sorted(float(state[3]) for state, _ in tracker.tracks().objects)
    assert velocities == pytest.approx([-1.0, 1.0], abs=0.1)  # y left: rightwards is -1
    for k, ahead in enumerate(tracker.ahead(3), start=1):
        assert np.array_equal(ahead >= 0.4, frames[25 + k] > 0)


def test_a_person_appearing_starts_at_rest_and_leaving_ends_the_track():
    config = TrackerConfig(max_missed=2)
    tracker = Tracker(config, res=0.1)
    empty = _wall()
    with_person = _wall()
    _blob(with_person, 20, 15)
    _run(tracker, [empty] * 5)
    tracker.update(with_person, SEEN)
    ((state, _),) = tracker.tracks().objects
    assert state[2:] == pytest.approx([0.0, 0.0])
    _run(tracker, [with_person] * 3 + [empty])
    assert tracker.tracks().objects == []  # unseen this frame: not predicted
    assert np.array_equal(tracker.ahead(1)[0] >= 0.4, empty > 0)
    _run(tracker, [empty] * config.max_missed)
    assert tracker._tracks == []  # missed more than max_missed frames: ended


def test_a_moving_platform_in_a_static_world_gives_no_movers():
    world = np.zeros((H + 40, W), np.float32)
    world[::7, 5:35] = 1  # rows of shelves the platform drives past
    world[:, 3] = world[:, 36] = 1

    def seen_from(t: int) -> np.ndarray:  # one cell forward per frame: the map slides down
        return world[40 - t : 40 - t + H].copy()

    tracker = Tracker(res=0.1)
    motion = np.array([1.0, 0.0, 0.0], np.float32)
    for t in range(25):
        moved = FrameInputs(motion=None if t == 0 else motion)
        prediction = tracker.update(seen_from(t), SEEN, moved)
        if t >= 2:
            assert all(np.hypot(*state[2:]) < 0.3 for state, _ in tracker.tracks().objects)
            # everything the next frame shows that was in view already is predicted
            truth = seen_from(t + 1) > 0
            assert np.array_equal((prediction >= 0.4)[1:], truth[1:])


def test_reset_clears_the_state():
    walker = [_walker(t, 0, 1) for t in range(16)]
    other = [_walker(t, 1, 0) for t in range(16)]
    fresh = _run(Tracker(res=0.1), other)
    used = Tracker(res=0.1)
    _run(used, walker)
    used.reset()
    assert all(np.array_equal(a, b) for a, b in zip(_run(used, other), fresh, strict=True))


def test_causal_later_frames_do_not_change_earlier_predictions():
    rng = np.random.default_rng(0)
    frames = [_walker(t, 1, -1) for t in range(20)]
    changed = [f.copy() for f in frames]
    for f in changed[12:]:
        f[rng.random((H, W)) < 0.05] = 1
    a, b = _run(Tracker(res=0.1), frames), _run(Tracker(res=0.1), changed)
    assert all(np.array_equal(x, y) for x, y in zip(a[:12], b[:12], strict=True))
    assert not all(np.array_equal(x, y) for x, y in zip(a[12:], b[12:], strict=True))


def _components_by_search(mask: np.ndarray, link: float) -> list[set[tuple[int, int]]]:
    cells = [tuple(c) for c in np.argwhere(mask)]
    left, out = set(cells), []
    while left:
        todo, part = [left.pop()], set()
        while todo:
            p = todo.pop()
            part.add(p)
            near = {q for q in left if (p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 <= link * link}
            left -= near
            todo += near
        out.append(part)
    return out


@settings(max_examples=40, deadline=None)
@given(arrays(bool, (9, 11)), st.sampled_from([0.0, 1.0, 1.5, 2.0, 3.2]))
def test_cluster_labels_are_the_components_within_the_link(mask, link):
    cells, labels = cluster_labels(mask, link)
    got = [{tuple(c) for c in cells[labels == i]} for i in range(len(set(labels.tolist())))]
    want = _components_by_search(mask, link)
    assert sorted(map(sorted, got)) == sorted(map(sorted, want))


@settings(max_examples=40, deadline=None)
@given(
    arrays(float, (5, 2), elements=st.floats(-10, 10)),
    arrays(float, (4, 2), elements=st.floats(-10, 10)),
    st.floats(0.1, 20),
)
def test_association_uses_each_once_within_the_gate(tracks, clusters, gate):
    pairs = associate(tracks, clusters, gate)
    assert len({t for t, _ in pairs}) == len(pairs) == len({c for _, c in pairs})
    assert all(np.linalg.norm(tracks[t] - clusters[c]) <= gate for t, c in pairs)
    # greedy is maximal: no left-over track and cluster within the gate of each other
    free_t = set(range(5)) - {t for t, _ in pairs}
    free_c = set(range(4)) - {c for _, c in pairs}
    assert all(np.linalg.norm(tracks[t] - clusters[c]) > gate for t in free_t for c in free_c)


@given(st.floats(-3, 3), st.floats(-3, 3), st.integers(0, 6))
def test_repeated_translation_composes_to_its_multiple(dx, dy, k):
    assert composed_motion(np.array([dx, dy, 0.0]), k) == pytest.approx([k * dx, k * dy, 0.0])


def test_foreground_ignores_a_wall_return_that_crossed_a_cell_edge():
    background = _wall().astype(np.float64)
    flicker = np.roll(_wall(), 1, axis=0)  # the wall one cell further: edge flicker
    assert not foreground(flicker, background, 0.2).any()


def test_bad_config_and_ahead_before_update_are_refused():
    with pytest.raises(ValueError, match="alpha"):
        TrackerConfig(alpha=0.0)
    with pytest.raises(ValueError, match="gate"):
        TrackerConfig(gate=0.0)
    with pytest.raises(RuntimeError, match="before any update"):
        Tracker().ahead(1)


def test_the_horizon_scores_the_trackers_own_k_ahead():
    from lidarflow.evaluate.runner import horizon_scores

    occupancy = np.stack([_walker(t, 0, 1) for t in range(24)])
    scores = horizon_scores(occupancy, np.ones_like(occupancy), [Tracker()], horizon=3, warmup=12)
    assert scores["f1"]["tracker"] == pytest.approx([1.0, 1.0, 1.0])
    assert scores["f1"]["copy_last"][2] < 0.99  # the walker moved: copying misses it


def test_evaluate_scores_the_tracker_among_the_baselines():
    from lidarflow.evaluate.methods import methods_and_config

    methods, config = methods_and_config([])
    names = [m.name for m in methods]
    assert names == ["copy_last", "temporal_average", "constant_velocity", "tracker"]
    assert "ego_motion" not in config and config["tracker"]["link"] == 0.5


def test_cluster_labels_all_against_all_is_the_offset_search(monkeypatch) -> None:
    """The two ways of finding the pairs within ``link`` (few cells / many) label alike."""
    import lidarflow.tracking.clusters as tracker

    rng = np.random.default_rng(0)
    for _ in range(100):
        h, w = rng.integers(3, 40, 2)
        mask = rng.random((h, w)) < rng.uniform(0.01, 0.3)
        link = float(rng.choice([0.0, 1.0, 1.5, 3.3, 5.0]))
        dense = tracker.cluster_labels(mask, link)
        monkeypatch.setattr(tracker, "_DENSE_CELLS", -1)
        searched = tracker.cluster_labels(mask, link)
        monkeypatch.undo()
        assert np.array_equal(dense[0], searched[0])
        assert np.array_equal(dense[1], searched[1])


def test_tracks_at_is_computed_once_per_k_read_only_and_as_computed_afresh():
    """A roll-out and the combination's experts both ask ``Tracks.at(k)``: the second gets the
    first's array, which nobody can change, equal to one made afresh."""
    from lidarflow.tracking.tracks import Tracks

    state, cells = np.array([50.0, 50.0, 1.0, -1.0]), np.array([[50, 50], [51, 50]], np.int64)
    held = np.zeros((100, 100), bool)
    held[10, 10] = True

    def tracks() -> Tracks:
        return Tracks((100, 100), [(state, cells)], np.array([1.0, 0.5, 0.05]), held, hold=2)

    once = tracks()
    first = once.at(2)
    assert once.at(2) is first and not first.flags.writeable
    with pytest.raises(ValueError):
        first[0, 0] = 1.0
    for k in (1, 2, 3):  # held cells up to hold only, each k its own motion
        np.testing.assert_array_equal(once.at(k), tracks().at(k))


def test_maps_moved_beside_the_prediction_are_moved_as_the_tracks_move_them():
    """``ahead(beside=...)``: the prediction first, as without them, then each map of the last
    frame moved ``k`` guessed steps on, as the tracks move a map; on a moving platform."""
    tracker = Tracker(res=0.1)
    motion = np.array([0.7, 0.2, 0.03])
    for t in range(6):
        tracker.update(_walker(t, 1, 0), SEEN, FrameInputs(motion=None if t == 0 else motion))
    rng = np.random.default_rng(0)
    beside = rng.random((2, *SEEN.shape)) < np.array([0.05, 0.7])[:, None, None]
    alone, both = tracker.ahead(3), tracker.ahead(3, beside=beside)
    tracks = tracker.tracks()
    for k, (a, b) in enumerate(zip(alone, both, strict=True), start=1):
        assert b.shape == (3, *SEEN.shape)
        np.testing.assert_array_equal(b[0], a)
        np.testing.assert_array_equal(b[1:], tracks.moved_to_sensor(beside, k))
    assert not np.array_equal(both[0][1], beside[0])  # the platform moved: so did the maps
    # from a later frame on: the same maps, the earlier ones left out
    later = tracker.ahead(3, beside=beside, first=2)
    assert len(later) == 2
    for a, b in zip(later, both[1:], strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.usefixtures("compile_now")
@pytest.mark.parametrize("numba_off", [False, True])
def test_a_bool_map_is_moved_as_its_float32_copy_to_the_bit(numba_off, monkeypatch):
    """``Tracks.moved_to_sensor`` moves bool maps without the float copy's clip: the same
    float32 numbers, at any motion, dense or sparse, one map or a stack."""
    if numba_off:
        import lidarflow.geometry as geometry

        monkeypatch.setattr(geometry, "ready", lambda *args, **kwargs: False)
    rng = np.random.default_rng(7)
    for _ in range(60):
        motion = rng.normal(0.0, [3.0, 3.0, 0.3])
        tracks = Tracks((H, W), [], motion)
        share = rng.choice([0.01, 0.2, 0.9])
        maps = rng.random((2, H, W)) < share
        for image, k in ((maps[0], int(rng.integers(1, 9))), (maps, 1)):
            got = tracks.moved_to_sensor(image, k)
            assert got.dtype == np.float32
            np.testing.assert_array_equal(got, tracks.moved_to_sensor(image.astype(np.float32), k))
            assert got.min() >= 0.0 and got.max() <= 1.0
