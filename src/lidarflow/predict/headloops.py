"""The compiled loop of a head-only model's step (:mod:`lidarflow.compiled`): the memories
updated, the features gathered and the two 1x1 layers applied, in one pass over blocks of cells
(measured no faster than NumPy's step: docs/research/compiled_kernels/, fourth round)."""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import kernel

__all__ = ["head_cells_loop"]

BLOCK = 256


@kernel
def head_cells_loop(
    occupancy: np.ndarray,
    extra: np.ndarray,
    state: np.ndarray,
    decays: np.ndarray,
    d_col: int,
    d_row: int,
    hidden_weight: np.ndarray,
    hidden_bias: np.ndarray,
    out_weight: np.ndarray,
    out_bias: np.float32,
    features: np.ndarray,
    hidden: np.ndarray,
    residual: np.ndarray,
    kept: np.ndarray,
) -> None:
    """One step of the head (see the module docstring); ``features`` and ``hidden`` written
    only where they have ``H*W`` columns."""
    k = decays.shape[0]
    h, w = occupancy.shape
    for c in range(k):
        d = decays[c]
        e = np.float32(1.0) - d
        for r in range(h):
            rs = r - d_row
            for q in range(w):
                qs = q - d_col
                past = np.float32(0.0)
                if 0 <= rs < h and 0 <= qs < w:
                    past = state[c, rs, qs]
                kept[c, r, q] = d * past + e * occupancy[r, q]
    kept[k] = occupancy
    units, inputs = hidden_weight.shape
    n = h * w
    block = np.zeros((inputs, BLOCK), np.float32)
    unit = np.empty(BLOCK, np.float32)
    out = np.empty(BLOCK, np.float32)
    traced = features.shape[1] == n
    for start in range(0, n, BLOCK):
        m = min(n - start, BLOCK)
        for i in range(m):
            r, q = divmod(start + i, w)
            block[0, i] = occupancy[r, q]
            rs, qs = r - d_row, q - d_col
            inside = 0 <= rs < h and 0 <= qs < w
            for c in range(k + 1):
                block[1 + c, i] = kept[c, rs, qs] if inside else np.float32(0.0)
            for c in range(extra.shape[0]):
                block[k + 2 + c, i] = extra[c, r, q]
        if traced:
            for c in range(inputs):
                for i in range(m):
                    features[c, start + i] = block[c, i]
        for i in range(BLOCK):
            out[i] = np.float32(0.0)
        for j in range(units):
            for i in range(BLOCK):
                unit[i] = np.float32(0.0)
            for c in range(inputs):
                weight = hidden_weight[j, c]
                row = block[c]
                for i in range(BLOCK):
                    unit[i] += weight * row[i]
            bias, weight = hidden_bias[j], out_weight[j]
            for i in range(BLOCK):
                a = unit[i] + bias
                a = a if a > np.float32(0.0) else np.float32(0.0)
                unit[i] = a
                out[i] += weight * a
            if traced:
                for i in range(m):
                    hidden[j, start + i] = unit[i]
        for i in range(m):
            residual[start + i] = out[i] + out_bias
