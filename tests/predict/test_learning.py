"""The head learning on the stream: its gradient is the loss's, the guard restores the shipped
weights when learning goes wrong, what it learnt can be saved and continued, and it learns from
real frames only."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.predict.engine import Engine, Frame
from lidarflow.predict.headstep import HeadStepBackend
from lidarflow.predict.learning import HeadLearning, LearningConfig
from lidarflow.predict.step import StepInputs
from tests.predict.test_headstep import HEADS, frames, head_model

MOTION = np.array([0.7, -0.4, 0.03], np.float32)


def _bce(p: np.ndarray, y: np.ndarray) -> float:
    p = np.clip(p.astype(np.float64), 1e-6, 1 - 1e-6)
    return float(-np.mean(y * np.log(p) + (1 - y) * np.log(1 - p)))


@pytest.mark.parametrize("ego", [True, False], ids=["ego", "no_ego"])
def test_the_gradient_is_the_losss(ego) -> None:
    """Each layer's analytic gradient, carried back through the move into the next frame,
    matches central differences of the cross-entropy of the step's prediction."""
    from lidarflow.predict.learning import _backward

    backend = HeadStepBackend(head_model(HEADS["bundled_like"], ego, seed=3))
    for weight, bias in backend.layers:  # off saturation, where differences are exact enough
        weight *= 0.3
        bias *= 0.3
    rng = np.random.default_rng(0)
    maps = frames(rng, 4)
    state = backend.init_state(24, 20)
    for m in maps[:4]:
        state = backend.run(StepInputs(m, MOTION), state).state
    target = maps[5][0, 0]

    def loss() -> float:
        return _bce(backend.run(StepInputs(maps[4], MOTION), state).probability[0, 0], target)

    loss()
    trace = backend.trace
    grad = ((trace.probability.astype(np.float64) - target) / target.size)
    if trace.sampler is not None:
        grad = trace.sampler.adjoint(grad)
    grads = _backward(backend.layers, trace.inputs, grad.reshape(1, -1))
    params = [a for layer in backend.layers for a in layer]
    for param, analytic in zip(params, grads, strict=True):
        for index in list(np.ndindex(param.shape))[:: max(1, param.size // 7)]:
            saved = param[index]
            param[index] = saved + 3e-3
            up = loss()
            param[index] = saved - 3e-3
            down = loss()
            param[index] = saved
            # float32 predictions: differences are good to a few % of the layer's largest
            scale = np.abs(analytic).max()
            assert analytic[index] == pytest.approx((up - down) / 6e-3, rel=0.02, abs=0.02 * scale)


def _stream(engine: Engine, n: int, seed: int = 0) -> list[np.ndarray]:
    """``n`` frames of a blob drifting one cell a frame; the decided maps."""
    rng = np.random.default_rng(seed)
    out = []
    for t in range(n):
        occupancy = (rng.random((24, 20)) > 0.97).astype(np.float32)
        occupancy[4:8, (t % 14) : (t % 14) + 4] = 1.0
        visibility = np.ones((24, 20), np.float32)
        subcell = np.full((2, 24, 20), 0.5, np.float32)
        out.append(engine.step(Frame(occupancy, visibility, subcell)).decided)
    return out


def test_learning_lowers_the_loss_on_the_stream() -> None:
    backend = HeadStepBackend(head_model(HEADS["bundled_like"], False, seed=1))
    learning = HeadLearning(backend, LearningConfig(rate=1e-2, window=20))
    _stream(Engine(backend, learning=learning), 120)
    assert learning.frames == 119 and learning.fallbacks == 0
    assert learning.loss < 0.8 * learning.shipped_loss
    layers = zip(backend.layers, learning.shipped, strict=True)
    assert all(not np.array_equal(w, w0) for (w, _), (w0, _) in layers)


class _Uphill(HeadLearning):
    """Learning gone wrong: every step up the loss."""

    def _step(self, grads: list[np.ndarray]) -> None:
        super()._step([-g for g in grads])


def test_the_guard_restores_the_shipped_weights_when_learning_goes_wrong() -> None:
    backend = HeadStepBackend(head_model(HEADS["bundled_like"], False, seed=1))
    learning = _Uphill(backend, LearningConfig(rate=0.1, window=10, margin=0.0))
    _stream(Engine(backend, learning=learning), 60)
    assert learning.fallbacks >= 2
    assert learning.loss <= learning.shipped_loss


def test_what_it_learnt_is_saved_and_continued() -> None:
    def engine() -> tuple[Engine, HeadLearning]:
        backend = HeadStepBackend(head_model(HEADS["bundled_like"], False, seed=1))
        learning = HeadLearning(backend, LearningConfig(rate=1e-2))
        return Engine(backend, learning=learning), learning

    a, learnt = engine()
    _stream(a, 40)
    b, fresh = engine()
    fresh.load_state(learnt.state())
    for (wa, ba), (wb, bb) in zip(learnt.backend.layers, fresh.backend.layers, strict=True):
        np.testing.assert_array_equal(wa, wb)
        np.testing.assert_array_equal(ba, bb)
    assert (fresh.steps, fresh.frames) == (learnt.steps, learnt.frames)
    a.reset(), b.reset()  # a new stream, what was learnt kept
    np.testing.assert_array_equal(np.stack(_stream(a, 10, 5)), np.stack(_stream(b, 10, 5)))
    learnt.reset()
    for (w, b_), (w0, b0) in zip(learnt.backend.layers, learnt.shipped, strict=True):
        np.testing.assert_array_equal(w, w0)
        np.testing.assert_array_equal(b_, b0)
    with pytest.raises(ValueError, match="do not fit"):
        other = HeadStepBackend(head_model(HEADS["hidden_visibility"], False))
        HeadLearning(other).load_state(learnt.state())


def test_it_learns_from_real_frames_only() -> None:
    """A roll-out between frames changes nothing of what is learnt, and a frame after a long
    step in time is not a label."""
    def run(horizon: int, pace_at: int | None = None) -> list[np.ndarray]:
        backend = HeadStepBackend(head_model(HEADS["bundled_like"], False, seed=1))
        learning = HeadLearning(backend, LearningConfig(rate=1e-2))
        engine = Engine(backend, learning=learning)
        rng = np.random.default_rng(2)
        for t in range(30):
            occupancy = (rng.random((24, 20)) > 0.9).astype(np.float32)
            frame = Frame(occupancy, np.ones_like(occupancy), np.zeros((2, 24, 20), np.float32),
                          pace=0.5 if t == pace_at else None)  # fmt: skip
            step = engine.step(frame)
            engine.roll(step, horizon)
        assert learning.frames == (28 if pace_at else 29)
        return [a.copy() for layer in backend.layers for a in layer]

    for a, b in zip(run(1), run(4), strict=True):
        np.testing.assert_array_equal(a, b)
    assert any(not np.array_equal(a, b) for a, b in zip(run(1), run(1, pace_at=9), strict=True))


def test_the_engine_refuses_a_learner_of_another_head() -> None:
    one = HeadStepBackend(head_model(HEADS["memories"], False))
    other = HeadStepBackend(head_model(HEADS["memories"], False))
    with pytest.raises(ValueError, match="must be the backend"):
        Engine(one, learning=HeadLearning(other))


def test_the_predictor_learns_saves_loads_and_resets(sample_recording, tmp_path) -> None:
    from lidarflow.predict import Predictor

    frames = [sample_recording.scan(i) for i in range(20)]
    predictor = Predictor(horizon=2, learn=LearningConfig(rate=1e-2))
    first = [predictor.update(f) for f in frames]
    learning = predictor.learning
    assert learning is not None and learning.frames == 19
    learnt = {k: v.copy() for k, v in learning.state().items()}
    path = predictor.save_learned(tmp_path / "learnt.npz")
    predictor.reset()
    assert learning.frames == 0
    for (w, b), (w0, b0) in zip(learning.backend.layers, learning.shipped, strict=True):
        np.testing.assert_array_equal(w, w0)
        np.testing.assert_array_equal(b, b0)
    again = [predictor.update(f) for f in frames]
    for a, b in zip(first, again, strict=True):  # from the shipped weights, the same stream
        np.testing.assert_array_equal(a.horizon, b.horizon)
    other = Predictor(horizon=2, learn=True)
    other.load_learned(path)
    for key, value in learnt.items():
        np.testing.assert_array_equal(other.learning.state()[key], value)


def test_learning_on_a_model_it_cannot_learn_is_refused() -> None:
    from lidarflow.errors import PredictError
    from lidarflow.models.presets import bundled_onnx
    from lidarflow.predict import Predictor

    with pytest.raises(PredictError, match="needs a head-only model"):
        Predictor(bundled_onnx()[0], learn=True)


def test_evaluate_and_predict_learn_on_the_command_line(sample_recording, tmp_path, capsys):
    import json

    from lidarflow.data import sample_bag_path
    from tests.test_cli import run

    short = sample_recording.slice(0, 30).save(tmp_path / "short.npz")
    code, out, err = run(
        ["evaluate", str(short), "--learn", "--horizon", "2", "--warmup", "5",
         "-o", str(tmp_path / "r.json")], capsys,
    )  # fmt: skip
    assert code == 0, err
    scored = json.loads((tmp_path / "r.json").read_text())["recordings"][0]
    assert {"bundled", "bundled_learning"} <= set(scored["horizon_f1"])
    assert "bundled_learning" in out
    bag = tmp_path / "out.bag"
    code, _, err = run(["predict", str(sample_bag_path()), "-o", str(bag), "--learn"], capsys)
    assert code == 0, err
    assert bag.exists()
