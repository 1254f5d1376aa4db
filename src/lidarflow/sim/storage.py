"""How ground-truth flow is stored in a recording's ``extras``, and reading it back densely.

Two layouts, both with the frame as the first axis so that ``Recording.slice`` and loading work
unchanged (``meta["flow_storage"]`` says which):

* ``dense`` (default): ``flow_backward`` and ``flow_forward``, float16 ``(N, 2, H, W)``; index ``t``
  holds ``B^t`` / ``F^t`` in cells (channel 0 column, 1 row).
* ``sparse``: only the cells where the flow is not zero (flow is zero off the occupied cells, and
  on static structure seen from a standing robot), padded per frame to the largest count ``K``:
  ``flow_backward_cells`` / ``flow_forward_cells`` int32 ``(N, K)`` flat cell index
  ``r * W + c`` or -1, and ``flow_backward_values`` / ``flow_forward_values`` float16
  ``(N, K, 2)``.

:func:`dense_flow` returns ``(B^t, F^t)`` as ``(2, H, W)`` float32 from either layout.
"""

from __future__ import annotations

import numpy as np

from lidarflow.data.recording import Recording
from lidarflow.errors import RecordingError

__all__ = ["FLOW_STORAGES", "dense_flow", "fill_dense", "to_sparse"]

FLOW_STORAGES = ("dense", "sparse")


def to_sparse(flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Dense ``(N, 2, H, W)`` flow -> ``(cells (N, K) int32, values (N, K, 2) float16)``."""
    n = flow.shape[0]
    flat = flow.reshape(n, 2, -1)
    f, cell = np.nonzero((flat[:, 0] != 0) | (flat[:, 1] != 0))
    counts = np.bincount(f, minlength=n)
    k = int(counts.max()) if n else 0
    rank = np.arange(len(f)) - np.repeat(np.cumsum(counts) - counts, counts)
    cells = np.full((n, k), -1, dtype=np.int32)
    values = np.zeros((n, k, 2), dtype=np.float16)
    cells[f, rank] = cell
    values[f, rank] = flat[f, :, cell]
    return cells, values


def fill_dense(flow: np.ndarray, cells: np.ndarray, values: np.ndarray) -> None:
    """Write :func:`to_sparse`'s ``cells``/``values`` into zeroed ``flow`` ``(N, 2, H, W)``."""
    flat = flow.reshape(len(flow), 2, -1)
    f, k = np.nonzero(cells >= 0)
    flat[f, :, cells[f, k]] = values[f, k]


def _dense(cells: np.ndarray, values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    out = np.zeros((1, 2, *shape), dtype=np.float32)
    fill_dense(out, cells[None], values[None])
    return out[0]


def dense_flow(recording: Recording, t: int) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth ``(B^t, F^t)`` of frame ``t``, each ``(2, H, W)`` float32 in cells (channel
    0 column, 1 row), whichever layout the recording stores; ``B^t`` lives on the occupied cells
    of ``O^{t+1}``, ``F^t`` on those of ``O^t`` (design notes, section 3)."""
    extras = recording.extras
    if not -len(recording) <= t < len(recording):
        raise RecordingError(f"frame {t} is out of range: the recording has {len(recording)}")
    if "flow_forward" in extras and "flow_backward" in extras:
        return (
            extras["flow_backward"][t].astype(np.float32),
            extras["flow_forward"][t].astype(np.float32),
        )
    if "flow_forward_cells" not in extras or "flow_backward_cells" not in extras:
        raise RecordingError(
            "this recording has no ground-truth flow (only simulated recordings do); "
            "make one with `lidarflow simulate`"
        )
    grid = recording.meta.get("grid")
    if not grid:
        raise RecordingError("sparse ground-truth flow needs meta['grid'] to know the map size")
    shape = (int(grid["height"]), int(grid["width"]))
    return (
        _dense(extras["flow_backward_cells"][t], extras["flow_backward_values"][t], shape),
        _dense(extras["flow_forward_cells"][t], extras["flow_forward_values"][t], shape),
    )
