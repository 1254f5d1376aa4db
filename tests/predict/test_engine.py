"""The per-frame pipeline on its own (lidarflow.predict.engine), on a backend that records what
it is given: the state carried from frame to frame, a roll-out that never leaks into it, the
motion handed to ego-motion models only, and the model's input built as its capabilities say."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from lidarflow.models.config import Capabilities
from lidarflow.predict.decision import DecisionPolicy
from lidarflow.predict.engine import Engine, Frame
from lidarflow.predict.step import StepInputs, StepOutput

SHAPE = (6, 8)


@dataclass
class Recorder:
    """A model whose state counts the steps it took, and whose probability is its input's
    occupancy map; every call recorded."""

    capabilities: Capabilities = field(default_factory=Capabilities)
    gain: float | None = None
    decision: dict[str, Any] | None = None
    calls: list[dict[str, Any]] = field(default_factory=list)
    inits: int = 0

    def init_state(self, height: int, width: int) -> Any:
        self.inits += 1
        return 0

    def run(self, inputs: StepInputs, state: Any) -> StepOutput:
        maps, motion, next_motion = inputs.maps, inputs.motion, inputs.next_motion
        self.calls.append(
            {"maps": maps.copy(), "state": state, "motion": motion, "next": next_motion}
        )
        out = np.zeros((1, self.capabilities.out_channels, *maps.shape[-2:]), np.float32)
        return StepOutput(maps[:, :1].astype(np.float32), out, state + 1)


def frame(seed: int, **kwargs: Any) -> Frame:
    rng = np.random.default_rng(seed)
    occupancy = (rng.random(SHAPE) < 0.3).astype(np.float32)
    return Frame(occupancy, np.ones(SHAPE, np.float32), **kwargs)


def test_the_state_is_carried_from_frame_to_frame_and_reset_starts_over():
    backend = Recorder()
    engine = Engine(backend)
    for seed in range(3):
        engine.step(frame(seed))
    assert [c["state"] for c in backend.calls] == [0, 1, 2] and backend.inits == 1
    engine.reset()
    engine.step(frame(3))
    assert backend.calls[-1]["state"] == 0 and backend.inits == 2


def test_a_roll_out_feeds_back_its_decided_maps_and_never_leaks_into_the_stream():
    backend = Recorder()
    engine = Engine(backend)
    first = frame(0)
    step = engine.step(first)
    rollout = engine.roll(step, 4)
    assert rollout.probability.shape == (4, *SHAPE) and rollout.decided.shape == (4, *SHAPE)
    np.testing.assert_array_equal(rollout.probability[0], step.probability)
    fed = [c["maps"][0] for c in backend.calls[1:]]
    assert [c["state"] for c in backend.calls[1:]] == [1, 2, 3]  # on from the step's state
    for k, maps in enumerate(fed):
        np.testing.assert_array_equal(maps[0], rollout.decided[k])  # the decided map, fed back
        np.testing.assert_array_equal(maps[1], first.visibility)  # with the frame's visibility
    engine.step(frame(1))
    assert backend.calls[-1]["state"] == 1  # the stream continues from its last real frame


def test_motion_goes_to_ego_motion_models_only_and_the_next_is_guessed_from_the_last():
    motion = np.array([0.5, 0.0, 0.1])
    plain = Recorder()
    Engine(plain).step(frame(0, motion=motion))
    assert plain.calls[0]["motion"] is None and plain.calls[0]["next"] is None
    ego = Recorder(Capabilities(ego_motion=True))
    step = Engine(ego).step(frame(0, motion=motion))
    np.testing.assert_array_equal(ego.calls[0]["motion"], motion)
    assert ego.calls[0]["next"] is None  # the model's default: the same motion again
    np.testing.assert_array_equal(step.ahead, motion)  # and so does a roll-out
    paced = Recorder(Capabilities(ego_motion=True))
    step = Engine(paced).step(frame(0, motion=motion, pace=0.5))  # twice the typical step
    np.testing.assert_allclose(paced.calls[0]["next"], motion * 0.5)
    np.testing.assert_allclose(step.ahead, motion * 0.5)


def test_the_oracle_takes_the_true_next_motion():
    truth = np.array([0.2, 0.1, 0.0])
    ego = Recorder(Capabilities(ego_motion=True))
    engine = Engine(ego, oracle=True)
    engine.step(frame(0, motion=np.zeros(3), next_motion=truth))
    np.testing.assert_array_equal(ego.calls[0]["next"], truth)


def test_the_input_holds_the_sub_cell_maps_where_the_model_takes_them():
    backend = Recorder(Capabilities(input_channels=4))
    engine = Engine(backend)
    engine.step(frame(0))
    maps = backend.calls[0]["maps"]
    assert maps.shape == (1, 4, *SHAPE) and maps.dtype == np.float32
    assert not maps[0, 2:].any()  # zeros where none were given
    subcell = np.full((2, *SHAPE), 0.25)
    engine.step(frame(1, subcell=subcell))
    np.testing.assert_array_equal(backend.calls[1]["maps"][0, 2:], subcell)


def test_a_decision_offset_needs_an_occupancy_head():
    with pytest.raises(ValueError, match="needs a model with an occupancy head"):
        Engine(Recorder(), policy=DecisionPolicy(offset=0.5))
    head = Recorder(Capabilities(flow=False, occupancy_head=True))
    step = Engine(head, policy=DecisionPolicy(offset=0.5)).step(frame(0))
    assert not np.array_equal(step.decided, step.probability)  # the offset moved it
