"""The tracker's per-frame geometry: foreground cells, their clusters, and the pairing of
clusters with tracks (:class:`lidarflow.tracking.Tracker`'s steps 2-4)."""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import kernel, ready
from lidarflow.geometry import cell_to_metric

__all__ = ["associate", "cluster_labels", "clusters", "foreground"]


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


def clusters(mask: np.ndarray, link: float) -> tuple[list[np.ndarray], np.ndarray]:
    """The clusters of :func:`cluster_labels` (``link`` >= 0 cells), as the tracker takes them:
    ``(groups, centroids)``, per cluster in label order its cells ``(N_i, 2)`` ``(row, col)``
    in row-major order, and ``(C, 2)`` float64 their centroids ``(x, y)`` in the sensor frame
    (:func:`~lidarflow.geometry.cell_to_metric`, cells). Compiled where available (the groups
    are then views into one array: read them, do not write), else in NumPy (the reference).

    >>> groups, centroids = clusters(np.array([[1, 0, 0, 1, 0, 1]], bool), 2.0)
    >>> [g.tolist() for g in groups], centroids.tolist()
    ([[[0, 0]], [[0, 3], [0, 5]]], [[0.5, 2.5], [0.5, -1.5]])
    """
    mask = np.ascontiguousarray(mask, bool)
    h, w = mask.shape
    # the offsets reach no farther than the map (a huge link would only loop for nothing)
    reach = min(int(np.floor(link)), max(h, w))
    if not ready(_clusters_loop, mask, float(link), reach):
        return _clusters_numpy(mask, link)
    cells, starts, sums = _clusters_loop(mask, float(link), reach)
    groups = [cells[starts[i] : starts[i + 1]] for i in range(len(starts) - 1)]
    # The sums are exact: halves (cell centres), far below 2**52; so is the reference's mean,
    # its sum in any order, then the same one division.
    return groups, sums / np.diff(starts)[:, None]


def _clusters_numpy(mask: np.ndarray, link: float) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`clusters` in NumPy (the reference)."""
    h, w = mask.shape
    cells, labels = cluster_labels(mask, link)
    groups = [cells[labels == i] for i in range(int(labels.max()) + 1 if len(labels) else 0)]
    xy = [np.stack(cell_to_metric(g[:, 0], g[:, 1], h, w), axis=-1) for g in groups]
    return groups, np.array([p.mean(axis=0) for p in xy]).reshape(-1, 2)


@kernel
def _clusters_loop(
    mask: np.ndarray, link: float, reach: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`clusters` as ``(cells, starts, sums)``: the cells ``(N, 2)`` grouped by label
    (row-major within each), cluster ``i`` at ``starts[i]:starts[i + 1]``, and per cluster the
    sum of its cells' ``(x, y)``. Union-find over the half disc of offsets within ``link``
    (:func:`cluster_labels`' pairs), each root its component's least index."""
    h, w = mask.shape
    index = np.full((h, w), -1, np.int64)
    n = 0
    for r in range(h):
        for c in range(w):
            if mask[r, c]:
                index[r, c] = n
                n += 1
    cells = np.empty((n, 2), np.int64)
    parent = np.arange(n)
    for r in range(h):
        for c in range(w):
            if index[r, c] >= 0:
                cells[index[r, c], 0], cells[index[r, c], 1] = r, c
    for i in range(n):
        r, c = cells[i, 0], cells[i, 1]
        for dr in range(0, min(reach, h - 1 - r) + 1):
            for dc in range(max(-reach, -c), min(reach, w - 1 - c) + 1):
                if (dr == 0 and dc <= 0) or dr * dr + dc * dc > link * link:
                    continue
                j = index[r + dr, c + dc]
                if j >= 0:
                    _union(parent, i, j)
    return _grouped(cells, parent, h, w)


@kernel
def _union(parent: np.ndarray, i: int, j: int) -> None:
    """Joins the sets of ``i`` and ``j``, the larger root under the smaller (so every root
    stays its set's least index); path halving on the way."""
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    while parent[j] != j:
        parent[j] = parent[parent[j]]
        j = parent[j]
    if i < j:
        parent[j] = i
    elif j < i:
        parent[i] = j


@kernel
def _grouped(
    cells: np.ndarray, parent: np.ndarray, h: int, w: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_clusters_loop`'s outputs from the union-find ``parent`` of ``cells``: labels in
    the order of each set's least index (the reference's ``np.unique`` of the roots)."""
    n = len(cells)
    labels = np.empty(n, np.int64)
    k = 0
    for i in range(n):
        root = i
        while parent[root] != root:
            root = parent[root]
        if root == i:
            labels[i] = k
            k += 1
        else:  # the root is a smaller index, labelled already
            labels[i] = labels[root]
    starts = np.zeros(k + 1, np.int64)
    for i in range(n):
        starts[labels[i] + 1] += 1
    for i in range(k):
        starts[i + 1] += starts[i]
    filled = starts[:k].copy()
    out = np.empty((n, 2), np.int64)
    sums = np.zeros((k, 2), np.float64)
    for i in range(n):
        label = labels[i]
        out[filled[label]] = cells[i]
        filled[label] += 1
        # cell_to_metric's (height - 0.5 - row, width / 2 - 0.5 - col), res 1
        sums[label, 0] += h - 0.5 - cells[i, 0]
        sums[label, 1] += w / 2 - 0.5 - cells[i, 1]
    return out, starts, sums


def associate(predicted: np.ndarray, measured: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """Greedy nearest-neighbour pairs ``(track, cluster)`` between ``predicted`` ``(T, 2)`` and
    ``measured`` ``(C, 2)`` centroids, closest first, each used once, none farther than
    ``gate``.

    >>> associate(np.array([[0.0, 0.0], [5.0, 0.0]]), np.array([[4.0, 0.0], [0.5, 0.0]]), 2.0)
    [(0, 1), (1, 0)]
    """
    if len(predicted) == 0 or len(measured) == 0:
        return []
    wide = [np.asarray(a, np.float64) for a in (predicted, measured)]
    if ready(_associate_loop, *wide, float(gate)):
        return sorted(map(tuple, _associate_loop(*wide, float(gate)).tolist()))
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


@kernel
def _associate_loop(predicted: np.ndarray, measured: np.ndarray, gate: float) -> np.ndarray:
    """:func:`associate`'s pairs ``(P, 2)`` (unsorted). The distances are NumPy's ``norm``:
    ``sqrt(dx * dx + dy * dy)``, the square root correctly rounded in both; a stable sort
    orders ties by their flat index as the reference's."""
    t_n, c_n = len(predicted), len(measured)
    distance = np.empty(t_n * c_n)
    for t in range(t_n):
        for c in range(c_n):
            dx = predicted[t, 0] - measured[c, 0]
            dy = predicted[t, 1] - measured[c, 1]
            distance[t * c_n + c] = np.sqrt(dx * dx + dy * dy)
    used_t, used_c = np.zeros(t_n, np.bool_), np.zeros(c_n, np.bool_)
    pairs = np.empty((min(t_n, c_n), 2), np.int64)
    k = 0
    for flat in np.argsort(distance, kind="mergesort"):
        if distance[flat] > gate:
            break
        t, c = flat // c_n, flat % c_n
        if not used_t[t] and not used_c[c]:
            pairs[k, 0], pairs[k, 1] = t, c
            used_t[t], used_c[c] = True, True
            k += 1
    return pairs[:k]
