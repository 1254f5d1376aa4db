"""The tracked objects a decision policy carries: the tracker's frozen objects, the
engine laying them over the model's map one frame and ``k`` frames on, and the policy's record
travelling with a model (model.json, ONNX marks)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from lidarflow.models.config import Capabilities
from lidarflow.models.weights import decision_record
from lidarflow.predict.decision import DecisionPolicy
from lidarflow.predict.engine import HELD_FRAMES, Engine, Frame
from lidarflow.predict.step import StepInputs, StepOutput
from lidarflow.tracking import Tracker
from tests.tracking.test_tracker import SEEN, _blob, _walker, _wall


def _people_only(frame: np.ndarray) -> np.ndarray:
    return (frame > 0) & ~(_wall() > 0)


def test_tracks_are_the_tracked_objects_k_ahead_without_the_background():
    tracker = Tracker(res=0.1)
    frames = [_walker(t, 0, 1) for t in range(20)]
    for f in frames[:16]:
        tracker.update(f, SEEN)
    tracks = tracker.tracks()
    for k in range(1, 5):
        assert np.array_equal(tracks.at(k) >= 0.4, _people_only(frames[15 + k])), k
    # frozen: the next frames move the tracker on, not what it handed out
    before = [tracks.at(k).copy() for k in (1, 2)]
    for f in frames[16:]:
        tracker.update(f, SEEN)
    assert all(np.array_equal(a, tracks.at(k)) for a, k in zip(before, (1, 2), strict=True))


def test_a_newcomer_beside_a_wall_is_held_for_hold_frames_not_tracked():
    tracker = Tracker(res=0.1)
    for _ in range(10):
        tracker.update(_wall(), SEEN)
    beside = _wall()
    beside[4, 20] = 1  # one cell under the wall's row: its neighbourhood is background
    tracker.update(beside, SEEN)
    assert tracker.tracks().objects == []
    tracks = tracker.tracks(hold=1)
    assert np.argwhere(tracks.at(1) >= 0.4).tolist() == [[4, 20]]
    assert not tracks.at(2).any()
    assert not tracker.tracks(hold=0).at(1).any()
    # the tracker's own map keeps it in the background part, every step ahead
    assert all(a[4, 20] == 1 for a in tracker.ahead(3))


@dataclass
class _Eraser:
    """A head that predicts nothing, and records the occupancy it was fed."""

    capabilities: Capabilities = field(
        default_factory=lambda: Capabilities(flow=False, occupancy_head=True)
    )
    gain: float | None = None
    decision: dict[str, Any] | None = None
    fed: list[np.ndarray] = field(default_factory=list)

    def init_state(self, height: int, width: int) -> Any:
        return None

    def run(self, inputs: StepInputs, state: Any) -> StepOutput:
        self.fed.append(inputs.maps[0, 0].copy())
        shape = inputs.maps.shape[-2:]
        zeros = np.zeros((1, 1, *shape), np.float32), np.zeros((1, 4, *shape), np.float32)
        return StepOutput(*zeros, state)


@pytest.mark.parametrize("tracks", [False, True])
def test_the_engine_lays_the_tracks_over_the_model_and_does_not_feed_them_back(tracks):
    backend = _Eraser()
    engine = Engine(backend, 0.1, DecisionPolicy(tracks=tracks))
    frames = [_walker(t, 0, 1) for t in range(20)]
    for f in frames[:16]:
        step = engine.step(Frame(f, SEEN))
    rolled = engine.roll(step, 4)
    for k, decided in enumerate(rolled.decided, start=1):
        assert np.array_equal(decided >= 0.4, _people_only(frames[15 + k]) & tracks), k
    assert np.array_equal(rolled.decided[0], step.decided)
    # the roll-out fed the model its own (empty) maps, never the tracker's
    assert not any(f.any() for f in backend.fed[16:])
    assert (engine.tracker is not None) == tracks
    engine.reset()
    if engine.tracker is not None:  # reset forgets every track: none until the next frame
        with pytest.raises(RuntimeError, match="before any update"):
            engine.tracker.tracks()


def test_the_engine_holds_a_newcomer_beside_a_wall_one_frame():
    engine = Engine(_Eraser(), 0.1, DecisionPolicy(tracks=True))
    for _ in range(10):
        engine.step(Frame(_wall(), SEEN))
    beside = _wall()
    _blob(beside, 4, 20)
    step = engine.step(Frame(beside, SEEN))
    rolled = engine.roll(step, 3)
    assert HELD_FRAMES == 1
    assert rolled.decided[0][4, 20] == 1 and not rolled.decided[1:].any()


def test_the_policy_record_carries_tracks_and_older_records_have_none():
    policy = DecisionPolicy.from_record({"offset": 0.5, "online": True, "movers": True})
    assert policy.tracks and policy.to_record()["movers"] is True
    assert policy.with_online(False).tracks and policy.with_online(True).tracks
    assert not DecisionPolicy.from_record({"offset": 0.5, "online": True}).tracks
    assert decision_record({"decision": {"offset": 0.0, "online": False, "movers": True}})[
        "movers"
    ]
    assert decision_record({"model_kwargs": {}})["movers"] is False


def test_tracks_travel_through_the_onnx_export(tmp_path, sample_recording):
    from lidarflow.models.presets import resolve_model
    from lidarflow.outputs.export import export_onnx
    from lidarflow.predict import Predictor
    from tests.head_only_pair import head_only, save_model_dir

    folder = save_model_dir(
        head_only(), tmp_path / "m", decision={"offset": 0.0, "online": False, "movers": True}
    )
    net, card = resolve_model(folder)
    assert card["decision"]["movers"] is True
    onnx_path = export_onnx(net, tmp_path / "m.onnx", decision=DecisionPolicy(tracks=True))
    torch_p, onnx_p = Predictor(folder), Predictor(onnx_path)
    assert torch_p.decision.tracks and onnx_p.decision.tracks
    assert torch_p.engine.tracker is not None and onnx_p.engine.tracker is not None
    for scan in [sample_recording.scan(i) for i in range(15)]:
        a, b = torch_p.update(scan), onnx_p.update(scan)
        near = np.abs(a.probability - 0.4) < 1e-3
        assert np.array_equal(a.occupied[~near], b.occupied[~near])
