"""A calibrated probability's logit and the decided probability back from a shifted logit
(:mod:`lidarflow.predict.offsets`, :mod:`lidarflow.predict.decision`), each elementwise chain
evaluated once per value that most cells share. NumPy only: the ONNX Predictor runs without
PyTorch.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = [
    "LOGIT_LIMIT",
    "calibrated_logit",
    "decided_probability",
    "once_per_common_value",
    "shifted_probability",
    "sigmoid32",
]

#: float32 probabilities saturate near 0 and 1; logits beyond this are far from every offset's
#: threshold anyway.
LOGIT_LIMIT = 15.0
# The probabilities whose logits are +-LOGIT_LIMIT.
_LOWEST, _HIGHEST = 1.0 / (1.0 + np.exp(LOGIT_LIMIT)), 1.0 / (1.0 + np.exp(-LOGIT_LIMIT))
_EXP_LIMIT = 700.0


def once_per_common_value(
    elementwise: Callable[[np.ndarray], np.ndarray], x: np.ndarray
) -> np.ndarray:
    """``elementwise(x)``, shape kept, for a function of each element alone (ufuncs, no
    reductions, ``+0`` and ``-0`` alike), evaluated once for all the elements equal to ``x``'s
    first and on the others one by one (on all at once where most differ from it): the
    same values, to the bit.

    Why: without poses a model's probability map holds one value on most cells (those far from
    every return, the corner among them), and the logarithms and exponentials of the decision
    on every cell were a third of its time.

    >>> once_per_common_value(np.exp, np.array([[0.0, 0.0], [1.0, 0.0]])).tolist()
    [[1.0, 1.0], [2.718281828459045, 1.0]]
    """
    flat = np.ravel(x)
    if flat.size == 0:
        return elementwise(x)
    differ = flat != flat[0]
    if np.count_nonzero(differ) > flat.size // 2:  # (a map moved by poses: gathering costs more)
        return elementwise(x)
    others = np.flatnonzero(differ)
    first = elementwise(flat[:1])  # through the same ufunc loops as the others
    out = np.empty(flat.shape, first.dtype)
    out[:] = first
    out[others] = elementwise(flat[others])
    return out.reshape(np.shape(x))


def _logit_within_limit(p: np.ndarray) -> np.ndarray:
    return np.clip(np.log(p) - np.log1p(-p), -LOGIT_LIMIT, LOGIT_LIMIT)


def calibrated_logit(probability: np.ndarray) -> np.ndarray:
    """``log(p / (1 - p))`` in float64, within :data:`LOGIT_LIMIT`: a calibrated probability's
    logit, which the decision offsets shift."""
    p = np.clip(np.asarray(probability, np.float64), 1e-12, 1.0 - 1e-12)
    return once_per_common_value(_logit_within_limit, p)


def sigmoid32(logit: np.ndarray) -> np.ndarray:
    """``1 / (1 + exp(-logit))`` in float64, then float32: the decided probability of a
    logit the offsets have shifted."""
    return once_per_common_value(_sigmoid, logit).astype(np.float32)


def _sigmoid(logit: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-logit))  # type: ignore[no-any-return]


def decided_probability(probability: np.ndarray, offset: float) -> np.ndarray:
    """``sigmoid(logit(p) + offset)`` float32: the probability a fixed decision offset
    thresholds at 0.4 (``p`` itself for offset 0)."""
    if offset == 0.0:
        return np.asarray(probability, np.float32)
    return shifted_probability(probability, offset)


def shifted_probability(probability: np.ndarray, shift: np.ndarray | float) -> np.ndarray:
    """``sigmoid32(calibrated_logit(probability) + shift)`` within a float32 rounding, by
    ``p e^s / (p e^s + 1 - p)`` with ``p`` clipped to the probabilities of the logit's limits:
    one exponential a cell where that chain takes three (a roll-out's every step decides its
    whole map so). ``1 - p`` is exact for a float32 ``p`` above 0.5 in float64, so there is no
    cancellation near 1.

    >>> float(shifted_probability(np.array([0.5], np.float32), np.log(3.0))[0])
    0.75
    """
    p = np.clip(np.asarray(probability, np.float64), _LOWEST, _HIGHEST)
    # beyond +-700 the answer is 0 or 1 already, and exp(710) would overflow
    shift = np.clip(np.asarray(shift, np.float64), -_EXP_LIMIT, _EXP_LIMIT)
    scaled = p * once_per_common_value(np.exp, shift)
    return (scaled / (scaled + (1.0 - p))).astype(np.float32)  # type: ignore[no-any-return]
