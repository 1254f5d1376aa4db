"""The tracker's per-frame geometry: foreground cells, their clusters, and the pairing of
clusters with tracks (:class:`lidarflow.tracking.Tracker`'s steps 2-4)."""

from __future__ import annotations

import numpy as np

__all__ = ["associate", "cluster_labels", "foreground"]


def foreground(occupancy: np.ndarray, background: np.ndarray, threshold: float) -> np.ndarray:
    """The occupied cells of ``occupancy`` ``(H, W)`` whose ``background`` rate, the largest
    over their 3 x 3 neighbourhood, is under ``threshold``: ``(H, W)`` bool.

    >>> wall = np.zeros((3, 4)); wall[1, 0] = 1.0
    >>> foreground(np.array([[0, 0, 0, 1], [1, 0, 0, 0], [0, 0, 0, 0]]), wall, 0.5).astype(int)
    array([[0, 0, 0, 1],
           [0, 0, 0, 0],
           [0, 0, 0, 0]])
    """
    padded = np.pad(np.asarray(background, np.float64), 1)
    h, w = np.shape(occupancy)
    # the 3 x 3 maximum as a maximum over rows, then columns (max is exact in any order)
    rows = np.maximum(np.maximum(padded[0:h], padded[1 : h + 1]), padded[2 : h + 2])
    near = np.maximum(np.maximum(rows[:, 0:w], rows[:, 1 : w + 1]), rows[:, 2 : w + 2])
    return np.asarray(occupancy, bool) & (near < threshold)


def cluster_labels(mask: np.ndarray, link: float) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of the ``True`` cells of ``mask`` ``(H, W)``, two cells joined when
    their centres lie within ``link`` cells: ``(cells, labels)``, ``cells`` ``(N, 2)`` the
    ``(row, col)`` of the ``N`` true cells in row-major order and ``labels`` ``(N,)`` int from
    0, numbered by each component's first cell.

    >>> m = np.array([[1, 0, 0, 1, 0, 1]], bool)
    >>> cluster_labels(m, 2.0)[1].tolist()
    [0, 1, 1]
    """
    cells = np.argwhere(mask)
    n = len(cells)
    if n == 0:
        return cells, np.zeros(0, np.int64)
    if n <= _DENSE_CELLS:
        return cells, _dense_labels(cells, link)
    h, w = mask.shape
    index = np.full((h, w), -1, np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(n)
    reach = int(np.floor(link))
    first, second = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    # each pair once: the offsets of a half disc (later rows, or the same row to the right)
    for dr in range(0, reach + 1):
        for dc in range(-reach, reach + 1):
            if (dr == 0 and dc <= 0) or dr * dr + dc * dc > link * link:
                continue
            r, c = cells[:, 0] + dr, cells[:, 1] + dc
            inside = (r < h) & (c >= 0) & (c < w)
            other = np.full(n, -1, np.int64)
            other[inside] = index[r[inside], c[inside]]
            found = other >= 0
            first.append(np.flatnonzero(found))
            second.append(other[found])
    parent = np.arange(n)
    a, b = np.concatenate(first), np.concatenate(second)
    # min-label propagation with pointer jumping: every cell ends at its component's least index
    while True:
        low = np.minimum(parent[a], parent[b])
        updated = parent.copy()
        np.minimum.at(updated, a, low)
        np.minimum.at(updated, b, low)
        updated = updated[updated]
        if np.array_equal(updated, parent):
            break
        parent = updated
    _, labels = np.unique(parent, return_inverse=True)
    return cells, labels.astype(np.int64)


#: Up to this many foreground cells (a few dozen a frame on the recordings) the pairs within
#: ``link`` are found all against all, in a handful of NumPy calls, not offset by offset.
_DENSE_CELLS = 256


def _dense_labels(cells: np.ndarray, link: float) -> np.ndarray:
    """:func:`cluster_labels`' labels from the all-against-all distances of ``cells`` ``(N, 2)``
    (the same pairs: integer offsets within ``link``)."""
    d = cells[:, None, :] - cells[None, :, :]
    near = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] <= link * link
    n = len(cells)
    parent = np.arange(n)
    # min-label propagation with pointer jumping: every cell ends at its component's least index
    while True:
        updated = np.where(near, parent[None, :], n).min(axis=1)
        updated = updated[updated]
        if np.array_equal(updated, parent):
            break
        parent = updated
    _, labels = np.unique(parent, return_inverse=True)
    return labels.astype(np.int64)


def associate(predicted: np.ndarray, measured: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """Greedy nearest-neighbour pairs ``(track, cluster)`` between ``predicted`` ``(T, 2)`` and
    ``measured`` ``(C, 2)`` centroids, closest first, each used once, none farther than
    ``gate``.

    >>> associate(np.array([[0.0, 0.0], [5.0, 0.0]]), np.array([[4.0, 0.0], [0.5, 0.0]]), 2.0)
    [(0, 1), (1, 0)]
    """
    if len(predicted) == 0 or len(measured) == 0:
        return []
    distance = np.linalg.norm(predicted[:, None, :] - measured[None, :, :], axis=2)
    pairs, used_t, used_c = [], set(), set()
    for flat in np.argsort(distance, axis=None, kind="stable"):
        t, c = divmod(int(flat), distance.shape[1])
        if distance[t, c] > gate:
            break
        if t not in used_t and c not in used_c:
            pairs.append((t, c))
            used_t.add(t)
            used_c.add(c)
    return sorted(pairs)
