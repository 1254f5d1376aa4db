"""The head keeps learning on the robot, from the scans that arrive.

The prediction made at frame ``t`` is of the map at ``t + 1``; when that scan arrives it is the
label (the paper's self-supervision, here on the stream). :class:`HeadLearning` takes one Adam
step per frame on the occupancy head's 1x1 layers
(:class:`~lidarflow.predict.headstep.HeadStepBackend`), down the cross-entropy of that
prediction against the scan over every cell (the training's ``occupancy_bce``), the gradient
carried back through the move into the next frame (:meth:`lidarflow.geometry.Sampler.adjoint`).
The gain stays as shipped: the online decision measures against it.

The guard: the shipped weights predict every frame beside the learnt ones (the same features,
one more pass of the layers), and both losses are averaged over the last ``window`` frames or
so. When the learnt weights' average is above the shipped ones' by more than ``margin`` (or is
not finite), the head goes back to the shipped weights and learns again from there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarflow.predict.headstep import HeadStepBackend, HeadTrace

__all__ = ["HeadLearning", "LearningConfig"]

_EPS = 1e-6
_Layers = list[tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class LearningConfig:
    """``rate``: Adam's step size; ``window``: the frames the guard's loss averages span;
    ``margin``: how far (relative) the learnt weights' average loss may rise above the shipped
    ones' before the guard restores them; ``pull``: an L2 pull of the weights towards the
    shipped ones (0: none)."""

    rate: float = 1e-3
    window: int = 100
    margin: float = 0.05
    pull: float = 0.0

    def __post_init__(self) -> None:
        if not (self.rate > 0 and self.window >= 1 and self.margin >= 0 and self.pull >= 0):
            raise ValueError(f"rate > 0, window >= 1, margin >= 0, pull >= 0, got {self}")


class HeadLearning:
    """Online learning of ``backend``'s layers (module docstring): :meth:`learn` once per
    frame with the trace of the previous frame's step and this frame's occupancy."""

    def __init__(self, backend: HeadStepBackend, config: LearningConfig | None = None) -> None:
        self.backend = backend
        self.config = config or LearningConfig()
        self.shipped: _Layers = [(w.copy(), b.copy()) for w, b in backend.layers]
        self.reset()

    def reset(self) -> None:
        """Back to the shipped weights, and forget the losses and the counts."""
        self._restore()
        self.frames = 0  #: frames learnt from in all
        self.fallbacks = 0  #: times the guard restored the shipped weights
        self.loss = self.shipped_loss = float("nan")  #: the guard's running averages

    def _restore(self) -> None:
        """The shipped weights again, the optimiser started afresh."""
        for (weight, bias), (w0, b0) in zip(self.backend.layers, self.shipped, strict=True):
            weight[...], bias[...] = w0, b0
        self._moments = [np.zeros((2, *a.shape)) for layer in self.shipped for a in layer]
        self.steps = 0  #: Adam steps taken since the shipped weights were last restored

    def learn(self, trace: HeadTrace, target: np.ndarray) -> None:
        """One step on the prediction ``trace`` made, against ``target`` ``(H, W)``, the
        occupancy (0 or 1) of the frame it predicted."""
        occupied = np.asarray(target) > 0.5
        p = trace.probability
        shipped = self._shipped_probability(trace)
        if self._judge(_bce(p, occupied), _bce(shipped, occupied)):
            return  # restored: this prediction came from the weights just dropped
        grad = (p - occupied) / np.float32(p.size)
        if trace.sampler is not None:
            grad = trace.sampler.adjoint(grad)
        self._step(_backward(self.backend.layers, trace.inputs, grad.reshape(1, -1)))
        self.frames += 1

    def _shipped_probability(self, trace: HeadTrace) -> np.ndarray:
        """What the shipped weights predicted on the same features."""
        residual = self.backend.residual(self.shipped, trace.inputs[0])
        residual = residual.reshape(1, *trace.probability.shape)
        logit = self.backend.moved_logit(residual, np.zeros_like(residual), trace.sampler)[0][0]
        gain = np.float32(self.backend.gain)
        return 1.0 / (1.0 + np.exp(-(gain * trace.weighed + logit)))

    def _judge(self, loss: float, shipped: float) -> bool:
        """Update the running losses; restore the shipped weights where the learnt ones fell
        behind (module docstring), and say whether it did."""
        alpha = 1.0 / self.config.window
        if np.isnan(self.shipped_loss):
            self.loss, self.shipped_loss = loss, shipped
        else:
            self.loss += alpha * (loss - self.loss)
            self.shipped_loss += alpha * (shipped - self.shipped_loss)
        behind = self.loss > self.shipped_loss * (1.0 + self.config.margin)
        if not np.isfinite(self.loss) or behind:
            self._restore()
            self.fallbacks += 1
            self.loss = self.shipped_loss
            return True
        return False

    def _step(self, grads: list[np.ndarray]) -> None:
        """One Adam step (the usual 0.9 / 0.999) on every layer, in place."""
        self.steps += 1
        rate = self.config.rate * np.sqrt(1 - 0.999**self.steps) / (1 - 0.9**self.steps)
        params = [a for layer in self.backend.layers for a in layer]
        anchors = [a for layer in self.shipped for a in layer]
        for param, anchor, grad, moments in zip(params, anchors, grads, self._moments, strict=True):
            if self.config.pull:
                grad = grad + self.config.pull * (param - anchor)
            moments[0] += 0.1 * (grad - moments[0])
            moments[1] += 0.001 * (grad * grad - moments[1])
            param -= (rate * moments[0] / (np.sqrt(moments[1]) + 1e-8)).astype(param.dtype)

    def state(self) -> dict[str, np.ndarray]:
        """What was learnt, as arrays (:meth:`load_state` continues from it)."""
        params = [a for layer in self.backend.layers for a in layer]
        out = {f"layer{i}": a.copy() for i, a in enumerate(params)}
        out.update({f"moments{i}": m for i, m in enumerate(self._moments)})
        out["counts"] = np.array([self.steps, self.frames, self.fallbacks])
        out["losses"] = np.array([self.loss, self.shipped_loss])
        return out

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state`; a ``ValueError`` if it does not fit this head."""
        params = [a for layer in self.backend.layers for a in layer]
        new = [np.asarray(state[f"layer{i}"]) for i in range(len(params))]
        moments = [np.asarray(state[f"moments{i}"]) for i in range(len(params))]
        if any(n.shape != p.shape for n, p in zip(new, params, strict=True)) or any(
            m.shape != (2, *p.shape) for m, p in zip(moments, params, strict=True)
        ):
            raise ValueError("the learnt layers do not fit this model's head")
        for param, value in zip(params, new, strict=True):
            param[...] = value
        self._moments = [m.astype(np.float64) for m in moments]
        self.steps, self.frames, self.fallbacks = (int(c) for c in state["counts"])
        self.loss, self.shipped_loss = (float(v) for v in state["losses"])


def _bce(p: np.ndarray, occupied: np.ndarray) -> float:
    """The mean binary cross-entropy of the probabilities ``p`` against the 0/1 labels
    ``occupied``: one log per cell, of the probability given to what happened."""
    likely = np.clip(np.where(occupied, p, 1.0 - p), _EPS, None)
    return float(-np.log(likely).mean(dtype=np.float64))


def _backward(
    layers: _Layers, inputs: tuple[np.ndarray, ...], grad: np.ndarray
) -> list[np.ndarray]:
    """The gradients ``[weight, bias, ...]`` of each layer (float64), from ``grad`` ``(1, N)``
    on the last layer's output and each layer's input (a ReLU between layers, as
    :func:`lidarflow.predict.headstep._forward`). The products run in float32, the layers'
    precision, on one thread."""
    grads: list[np.ndarray] = []
    grad = np.asarray(grad, np.float32)
    for i in range(len(layers) - 1, -1, -1):
        x = inputs[i]
        grads[:0] = [
            _one_thread_product(grad, x.T).astype(np.float64),
            grad.sum(axis=1, keepdims=True, dtype=np.float64),
        ]
        if i:
            grad = layers[i][0].T @ grad
            grad *= x > 0
    return grads


def _one_thread_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for a short ``a`` ``(m, N)`` and ``b`` ``(N, n)``, summed over slices of ``N``
    small enough that BLAS keeps to one thread (see ``headstep._layer``)."""
    step = 8192
    out = a[:, :step] @ b[:step]
    for start in range(step, a.shape[1], step):
        out += a[:, start : start + step] @ b[start : start + step]
    return out
