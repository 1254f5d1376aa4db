"""Which candidate decides: per horizon and kind of cell, the one that scored best lately.

When frame ``t + k`` arrives, each candidate's decided map of it (made at ``t``) is scored by
decayed counts of three F1s: of all cells, of the cells changed since frame ``t``, and the
tolerant F1 in the region where movers went (as the mover metric counts it). The pair ``(a, b)``
chosen, ``a`` deciding the common cells and ``b`` the rare ones, maximises the margins of the
map they make together over the simple predictors among the candidates.
"""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import ready
from lidarflow.nearby import TOLERANCE, near, near_counts
from lidarflow.online.loops import best_pair_loop, score_counts_loop
from lidarflow.online.stacking import f1_of

__all__ = ["Arrived", "Leader", "choose_each", "score_counts", "score_counts_each"]

#: How much more a loss against the simple predictors weighs than a win of the same size.
LOSS_WEIGHT = 10.0


class Arrived:
    """The frame whose map came, as the leaders of every horizon score against it: its
    ``occupied`` cells, the ``region`` where movers went and ``movers``, its occupied cells
    there, ``(H, W)`` bool. The region's cells near one of the movers are found once
    (:meth:`near_truth`)."""

    def __init__(self, occupied: np.ndarray, region: np.ndarray) -> None:
        self.occupied = np.ascontiguousarray(occupied, bool)
        self.region = np.ascontiguousarray(region, bool)
        self.movers = self.occupied & self.region
        self._near: dict[int, np.ndarray] = {}

    def near_truth(self, radius: int) -> np.ndarray:
        """The region's cells within ``radius`` of one of the :attr:`movers`
        (:func:`lidarflow.nearby.near`)."""
        if radius not in self._near:
            self._near[radius] = near(self.movers, radius) & self.region
        return self._near[radius]


class Leader:
    """The choice for one horizon among ``candidates`` decided maps, starting on ``first``.
    With ``baselines`` (the simple predictors among the candidates) the pair chosen maximises
    its margins as a model is judged: all-cell and changed-cell F1 over the best of them,
    tolerant F1 over the first, each loss weighing :data:`LOSS_WEIGHT` times a win. Without,
    it maximises the sum of the F1s."""

    def __init__(
        self,
        candidates: int,
        first: int = 0,
        decay: float = 0.99,
        tolerance: int = TOLERANCE,
        baselines: tuple[int, ...] = (),
    ) -> None:
        self.candidates, self.first, self.decay = candidates, first, decay
        self.tolerance, self.baselines = tolerance, baselines
        self._baselines = np.array(baselines, np.int64)  # as the compiled choice takes them
        self.reset()

    def reset(self) -> None:
        self._f1 = np.zeros((self.candidates, 2, 2, 3))  # candidate, all/changed, kind, tp/fp/fn
        self._tolerant = np.zeros((self.candidates, 4))  # right, wrong, found, missed
        self.choice = (self.first, self.first)

    def state(self) -> dict[str, np.ndarray]:
        """The decayed counts and the choice (:meth:`load_state` takes them back)."""
        return {
            "f1_counts": self._f1.copy(),
            "tolerant_counts": self._tolerant.copy(),
            "choice": np.array(self.choice),
        }

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state`'s arrays (a ``ValueError`` where they do not fit)."""
        shapes = {"f1_counts": self._f1.shape, "tolerant_counts": self._tolerant.shape}
        for key, shape in shapes.items():
            if key not in state or np.shape(state[key]) != shape:
                raise ValueError(f"leader state: {key} missing or not of shape {shape}")
        choice = tuple(int(c) for c in np.asarray(state["choice"]).reshape(2))
        if not all(0 <= c < self.candidates for c in choice):
            raise ValueError(f"leader state: choice {choice} out of range")
        self._f1 = np.array(state["f1_counts"], np.float64)
        self._tolerant = np.array(state["tolerant_counts"], np.float64)
        self.choice = (choice[0], choice[1])

    def score(
        self, decided: np.ndarray, rare: np.ndarray, before: np.ndarray, arrived: Arrived
    ) -> None:
        """Count the candidates' ``decided`` maps ``(C, H, W)`` bool against the frame that
        ``arrived``: F1 on the common and the ``rare`` cells apart, of all cells and of those
        changed since the map they were predicted from (``before``), and the tolerant F1 inside
        its region (where movers went); then choose anew."""
        self.add(*score_counts(decided, rare, before, arrived, self.tolerance))

    def add(self, f1: np.ndarray, tolerant: np.ndarray, choose: bool = True) -> None:
        """Add one frame's counts (:func:`score_counts`' pair), the older ones decayed; then
        choose anew (``choose=False``: left to the caller, :func:`choose_each`)."""
        self._f1 *= self.decay
        self._tolerant *= self.decay
        self._f1 += f1.reshape(self._f1.shape)
        self._tolerant += tolerant
        if choose:
            self.choice = self._best()

    def _best(self) -> tuple[int, int]:
        return _best_of([self])[0]


def choose_each(leaders: list[Leader]) -> None:
    """Each of ``leaders`` (alike: the same candidates, first and baselines) chooses its pair
    anew from its counts, all in one NumPy pass."""
    for leader, pair in zip(leaders, _best_of(leaders), strict=True):
        leader.choice = pair


def _best_of(leaders: list[Leader]) -> list[tuple[int, int]]:
    """The pair each of ``leaders`` (alike) would choose from its counts now."""
    if not leaders:
        return []
    one = leaders[0]
    assert all(
        (x.candidates, x.first, x.baselines) == (one.candidates, one.first, one.baselines)
        for x in leaders
    )
    counts = [(x._f1, x._tolerant, one.first, one._baselines, LOSS_WEIGHT) for x in leaders]
    if ready(best_pair_loop, *counts[0]):
        pairs = [best_pair_loop(*c) for c in counts]
    else:
        f1 = np.stack([x._f1 for x in leaders])
        pairs = _best_pairs(f1, np.stack([x._tolerant for x in leaders]), one.first, one.baselines)
    return [(int(a), int(b)) for a, b in pairs]


def _best_pairs(
    f1_counts: np.ndarray, tolerant_counts: np.ndarray, first: int, baselines: tuple[int, ...]
) -> list[tuple[int, int]]:
    """The pair (common, rare) each of ``K`` leaders chooses from its decayed counts
    ``(K, C, 2, 2, 3)`` and ``(K, C, 4)`` (see :class:`Leader`)."""
    # F1 of all / changed cells for the pair (a common, b rare): counts of a's common cells plus
    # b's rare ones, (K, a, b, metric, 3)
    common, rare = f1_counts[:, :, :, 0], f1_counts[:, :, :, 1]
    total = common[:, :, None] + rare[:, None, :]
    f1 = f1_of(total[..., 0], total[..., 1] + total[..., 2])  # (K, a, b, metric)
    right, wrong, found, missed = np.moveaxis(tolerant_counts, -1, 0)  # each (K, b)
    precision = _ratio(right, right + wrong)
    recall = _ratio(found, found + missed)
    tolerant = _ratio(2 * precision * recall, precision + recall)  # (K, b)
    if not baselines:
        score = f1.sum(axis=-1) + tolerant[:, None, :]
    else:  # margins over the simple predictors, as a model is judged, losses weighed more
        alone = np.arange(f1.shape[1])
        best = f1[:, alone, alone][:, list(baselines)].max(axis=1)  # (K, metric)
        margins = [f1[..., m] - best[:, m, None, None] for m in (0, 1)]
        reference = tolerant[:, baselines[0], None, None]  # the tolerant F1 against the first
        margins.append(np.broadcast_to(tolerant[:, None, :] - reference, f1.shape[:3]))
        score = sum(m + LOSS_WEIGHT * np.minimum(m, 0.0) for m in margins)
    chosen = np.argmax(score.reshape(len(score), -1), axis=1)
    a, b = np.unravel_index(chosen, score.shape[1:])
    nothing = ~f1.reshape(len(f1), -1).any(axis=1) & ~tolerant.any(axis=1)
    return [
        (first, first) if none else (int(i), int(j))
        for none, i, j in zip(nothing, a, b, strict=True)
    ]


def score_counts(
    decided: np.ndarray,
    rare: np.ndarray,
    before: np.ndarray,
    arrived: Arrived,
    radius: int = TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:
    """One frame's counts of the candidates' ``decided`` maps ``(C, H, W)`` bool against the
    frame that ``arrived``, as :meth:`Leader.score` adds them: ``(C, 4, 3)`` true positives,
    false positives and false negatives over the common cells, the ``rare`` ones, and the same
    among those changed since ``before``; and ``(C, 4)`` the tolerant F1's right, wrong, found
    and missed cells inside its region, a cell near another within ``radius``
    (:func:`lidarflow.nearby.near`). float64 holding integers; compiled where available, the
    same counts."""
    f1, tolerant = score_counts_each(decided[None], rare[None], before[None], arrived, radius)
    return f1[0], tolerant[0]


def score_counts_each(
    decided: np.ndarray,
    rare: np.ndarray,
    before: np.ndarray,
    arrived: Arrived,
    radius: int = TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`score_counts` of ``K`` horizons' candidates against the one frame that
    ``arrived`` (each made from another frame): ``decided`` ``(K, C, H, W)``, ``rare`` and
    ``before`` ``(K, H, W)`` bool; the counts ``(K, C, 4, 3)`` and ``(K, C, 4)``, in one pass
    on the NumPy path."""
    region, occupied = arrived.region, arrived.occupied
    decided, rare, before = (np.ascontiguousarray(a, bool) for a in (decided, rare, before))
    shared = (region.view(np.uint8), occupied.view(np.uint8))  # 0 or 1: the loop adds them
    each = [
        (d.view(np.uint8), r.view(np.uint8), b.view(np.uint8))
        for d, r, b in zip(decided, rare, before, strict=True)
    ]
    if each and radius >= 0 and ready(score_counts_loop, *each[0][:2], *shared, each[0][2], radius):
        out = [score_counts_loop(d, r, *shared, b, radius) for d, r, b in each]
        return np.stack([f1 for f1, _ in out]), np.stack([tolerant for _, tolerant in out])
    horizons, candidates = decided.shape[:2]
    # only the cells some horizon's candidate guessed, or true, add to any count
    support = np.flatnonzero(decided.any(axis=(0, 1)) | occupied)
    kind = rare.reshape(horizons, -1)[:, support]
    changed = occupied.reshape(-1)[support] != before.reshape(horizons, -1)[:, support]
    # the cells counts are over, as rows: (metric, kind) in Leader._f1's order, then the region
    # and its cells near a true one there
    masks = np.empty((horizons, 6, len(support)), np.float32)
    masks[:, 0], masks[:, 1] = ~kind, kind
    masks[:, 2], masks[:, 3] = ~kind & changed, kind & changed
    masks[:, 4] = region.reshape(-1)[support]
    masks[:, 5] = arrived.near_truth(radius).reshape(-1)[support]
    flat = decided.reshape(horizons, candidates, -1)[:, :, support].astype(np.float32)
    truth = occupied.reshape(-1)[support].astype(np.float32)
    # exact: float32 holds counts up to 2**24, so the products' order does not matter
    predicted = flat @ masks.transpose(0, 2, 1)  # (K, C, 6)
    tp = flat @ (masks[:, :4] * truth).transpose(0, 2, 1)  # (K, C, 4)
    true = (masks[:, :4] @ truth)[:, None]  # (K, 1, 4)
    counts = np.stack([tp, predicted[..., :4] - tp, true - tp], axis=-1)  # (K, C, 4, 3)
    guessed, right = predicted[..., 4], predicted[..., 5]
    # true cells with a guess near
    found = near_counts((decided & region).reshape(-1, *region.shape), arrived.movers, radius)
    found = found.reshape(horizons, candidates)
    movers = np.count_nonzero(arrived.movers)
    tolerant = np.stack([right, guessed - right, found, movers - found], axis=-1)
    return counts.astype(np.float64), tolerant.astype(np.float64)


def _ratio(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.where(b > 0, a / np.where(b > 0, b, 1.0), 0.0)
