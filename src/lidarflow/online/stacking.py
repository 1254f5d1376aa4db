"""Experts' maps combined per cell by a logistic regression learnt on the stream.

For one horizon ``k``, each frame ``t`` brings ``E`` experts' probabilities ``(E, H, W)`` in
[0, 1] of frame ``t + k`` and a mask of its *rare* cells (where movers go). The combined
probability of a cell is

    p = sigmoid(w . f),   f = [1, rare, l_1 .. l_E, rare * l_1 .. rare * l_E]

with ``l_e`` the expert's logit (its probability clipped to ``[clip, 1 - clip]``, over the
clip's logit, so in [-1, 1]): rare cells get weights of their own.

When frame ``t + k`` arrives, its occupancy labels the maps kept since ``t`` and ``w`` takes one
AdaGrad step on the mean log-loss over all cells (:meth:`HorizonStacking.learn`): what is
predicted for ``t + k`` depends on no frame after ``t``. The decision thresholds (one for rare
cells, one for the rest) maximise the decayed F1 of all cells plus that of the rare cells; the
decided map is the probability rescaled so that they fall on the metric's 0.4 (:func:`rescaled`).

Cells where every expert says below ``clip`` share one feature vector per rare flag, so they are
counted, not computed: the cost grows with the cells some expert finds possibly occupied.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarflow.compiled import ready
from lidarflow.online.loops import (
    active_loop,
    decided_grid_loop,
    decision_counts_loop,
    quantised_design_loop,
    quiet_kinds_loop,
    thresholds_loop,
)

__all__ = [
    "HorizonStacking",
    "StackingConfig",
    "best_thresholds",
    "best_thresholds_each",
    "choose_thresholds",
    "f1_of",
    "rescaled",
]

#: The metric's threshold: a decided probability counts as occupied at or above it.
DECIDED = 0.4


@dataclass(frozen=True)
class StackingConfig:
    """``learning_rate``: AdaGrad's step; ``clip``: experts' probabilities are clipped to
    ``[clip, 1 - clip]`` (a binary expert's logit is then +-1 after scaling); ``decay``: the
    weight each frame's decision statistics keep per frame (0.99: about the last 100 frames);
    ``bins``: the thresholds tried, evenly in (0, 1); ``rare_weight``: the weight of the rare
    cells' F1 beside all cells' in choosing the thresholds."""

    learning_rate: float = 0.3
    clip: float = 0.02
    decay: float = 0.99
    bins: int = 40
    rare_weight: float = 1.0

    def __post_init__(self) -> None:
        valid = 0 < self.clip < 0.5 and 0 < self.decay <= 1 and self.bins >= 2
        if not valid or self.learning_rate <= 0 or self.rare_weight < 0:
            raise ValueError(f"invalid stacking configuration: {self}")


def rescaled(probability: np.ndarray, threshold: np.ndarray | float) -> np.ndarray:
    """``probability`` mapped piecewise-linearly so that ``threshold`` (per cell or one) falls
    on :data:`DECIDED`, 0 and 1 staying put: deciding the result at 0.4 is deciding
    ``probability`` at ``threshold``. float32."""
    p = np.asarray(probability, np.float64)
    t = np.clip(np.asarray(threshold, np.float64), 1e-6, 1 - 1e-6)
    low = p * (DECIDED / t)
    high = DECIDED + (p - t) * ((1 - DECIDED) / (1 - t))
    return np.where(p < t, low, high).astype(np.float32)


class HorizonStacking:
    """The combination for one horizon (see the module docstring): ``experts`` maps per frame;
    ``prior``: the expert whose logit the weights start on (the combination starts as that
    expert alone)."""

    def __init__(self, experts: int, config: StackingConfig | None = None, prior: int = 0) -> None:
        if not 0 <= prior < experts:
            raise ValueError(f"prior expert {prior} is not one of {experts}")
        self.experts, self.config, self.prior = experts, config or StackingConfig(), prior
        self._limit = float(np.log((1 - self.config.clip) / self.config.clip))
        # the two cells that stand for all quiet ones (not rare, rare): their features
        self._quiet = self._design(self._logits(np.zeros((experts, 2))), np.array([False, True]))
        # quantised probabilities q (p = q / 255): over the clip where q > this, and the logit
        # of each
        levels = np.arange(256) / 255.0
        self._quantised_clip = np.uint8(np.count_nonzero(levels <= self.config.clip) - 1)
        self._quantised_logits = self._logits(levels)
        self.reset()

    def reset(self) -> None:
        """Back to the start: the prior expert's logit alone, nothing counted."""
        features = 2 + 2 * self.experts
        self.weights = np.zeros(features)
        self.weights[2 + self.prior] = self._limit  # sigmoid(limit * l) is the expert's own p
        self._squares = np.zeros(features)
        bins = self.config.bins
        # decayed counts per (rare, bin of the combined probability) of occupied and free cells
        self._occupied = np.zeros((2, bins))
        self._free = np.zeros((2, bins))
        self.thresholds = np.array([DECIDED, DECIDED])
        self.learned = 0

    def state(self) -> dict[str, np.ndarray]:
        """What was learnt (:meth:`load_state` takes it back)."""
        return {
            "weights": self.weights.copy(),
            "squares": self._squares.copy(),
            "occupied": self._occupied.copy(),
            "free": self._free.copy(),
            "thresholds": self.thresholds.copy(),
            "learned": np.array(self.learned),
        }

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state`'s arrays (a ``ValueError`` where they do not fit)."""
        shapes = {"weights": self.weights.shape, "occupied": self._occupied.shape}
        for key, shape in shapes.items():
            if key not in state or np.shape(state[key]) != shape:
                raise ValueError(f"stacking state: {key} missing or not of shape {shape}")
        self.weights = np.array(state["weights"], np.float64)
        self._squares = np.array(state["squares"], np.float64).reshape(self.weights.shape)
        self._occupied = np.array(state["occupied"], np.float64)
        self._free = np.array(state["free"], np.float64).reshape(self._occupied.shape)
        self.thresholds = np.array(state["thresholds"], np.float64).reshape(2)
        self.learned = int(state["learned"])

    def _logits(self, probabilities: np.ndarray) -> np.ndarray:
        """The experts' scaled logits of ``probabilities`` (float64 of any shape)."""
        clip = self.config.clip
        p = np.clip(np.asarray(probabilities, np.float64), clip, 1 - clip)
        return np.log(p / (1 - p)) / self._limit  # type: ignore[no-any-return]

    def _design(self, logits: np.ndarray, rare: np.ndarray) -> np.ndarray:
        """The features ``(F, N)`` of ``N`` cells: the experts' ``logits`` ``(E, N)``, ``rare``
        ``(N,)`` bool."""
        r = rare.astype(np.float64)
        return np.concatenate([np.ones_like(r)[None], r[None], logits, logits * r[None]])

    def _split(self, probabilities: np.ndarray, rare: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The flat cells some expert finds possibly occupied (``active``) and their design.
        ``probabilities`` ``(E, H, W)`` float, or uint8 quantised (``p = q / 255``)."""
        flat = np.asarray(probabilities).reshape(self.experts, -1)
        if flat.dtype != np.uint8 and flat.dtype.kind != "f":
            flat = flat.astype(np.float64)  # compared as the float it stands for
        if flat.dtype == np.uint8:  # the logit of each of the 256 levels, looked up
            active = active_cells(flat, self._quantised_clip)
            args = (flat, active, self._quantised_logits, rare.ravel())
            if ready(quantised_design_loop, *args):
                return active, quantised_design_loop(*args)
            logits = self._quantised_logits[flat[:, active]]
        else:
            active = active_cells(flat, flat.dtype.type(self.config.clip))  # as `flat > clip`
            logits = self._logits(flat[:, active])
        return active, self._design(logits, rare.ravel()[active])

    def _combined(self, design: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The combined probability of the cells of ``design`` and of the quiet ones (not
        rare, rare)."""
        return _sigmoid(self.weights @ design), _sigmoid(self.weights @ self._quiet)

    def _decide(self, p: np.ndarray, rare: np.ndarray) -> np.ndarray:
        return rescaled(p, np.where(rare, self.thresholds[1], self.thresholds[0]))

    def decided(self, probabilities: np.ndarray, rare: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The combined probability ``(H, W)`` float64 of the experts' ``probabilities``
        ``(E, H, W)`` (float, or uint8 quantised: ``p = q / 255``) with ``rare`` ``(H, W)``
        bool, and the decided one (:func:`rescaled` at the thresholds of the cell's kind)."""
        rare = np.asarray(rare, bool)
        active, design = self._split(probabilities, rare)
        p, quiet_p = self._combined(design)
        decided = self._decided_grid(active, p, quiet_p, rare)
        return _grid(active, p, quiet_p, rare), decided

    def _decided_grid(
        self, active: np.ndarray, p: np.ndarray, quiet_p: np.ndarray, rare: np.ndarray
    ) -> np.ndarray:
        """The decided grid ``(H, W)``: the ``active`` cells' ``p`` and the quiet ones'
        ``quiet_p`` (not rare, rare) rescaled, cell by cell as the whole grid would be."""
        flat_rare = rare.ravel()
        args = (active, p, quiet_p, flat_rare, self.thresholds, DECIDED)
        if ready(decided_grid_loop, *args):
            return decided_grid_loop(*args).reshape(rare.shape)  # type: ignore[no-any-return]
        kinds = np.concatenate([flat_rare[active], [False, True]])
        decided = self._decide(np.concatenate([p, quiet_p]), kinds)
        return _grid(active, decided[:-2], decided[-2:], rare)

    def learn(
        self,
        probabilities: np.ndarray,
        rare: np.ndarray,
        occupied: np.ndarray,
        choose: bool = True,
    ) -> np.ndarray:
        """One step on a pair whose label has arrived: the experts' ``probabilities``
        ``(E, H, W)`` (float, or uint8 quantised: ``p = q / 255``) and ``rare`` mask as they
        were predicted, and the map that came (``occupied`` ``(H, W)``, nonzero where
        occupied); then the thresholds chosen anew (``choose=False``: left to the caller,
        :func:`choose_thresholds`). Returns the decided probability ``(H, W)`` the combination
        gave that pair before the step, as :meth:`decided`."""
        target = np.asarray(occupied).ravel() > 0.5
        rare = np.asarray(rare, bool)
        flat_rare = rare.ravel()
        active, design = self._split(probabilities, rare)
        p, quiet_p = self._combined(design)
        decided = self._decided_grid(active, p, quiet_p, rare)
        # every cell not active: its features are quiet[:, rare], its label free or occupied;
        # counted as all cells less the active ones
        y = target[active].astype(np.float64)
        counts = _quiet_kinds(flat_rare, target, active)
        gradient = design @ (p - y)
        for kind in (0, 1):
            gradient += self._quiet[:, kind] * (
                counts[kind, 0] * quiet_p[kind] + counts[kind, 1] * (quiet_p[kind] - 1)
            )
        gradient /= target.size
        self._squares += gradient**2
        self.weights -= self.config.learning_rate * gradient / (np.sqrt(self._squares) + 1e-12)
        self._count(p, y > 0.5, flat_rare[active], quiet_p, counts)
        self.learned += 1
        if choose:
            choose_thresholds([self])
        return decided

    def _count(
        self,
        p: np.ndarray,
        occupied: np.ndarray,
        rare: np.ndarray,
        quiet_p: np.ndarray,
        quiet_counts: np.ndarray,
    ) -> None:
        """Add one pair's cells to the decision statistics."""
        args = (self._occupied, self._free, self.config.decay, p, occupied, rare, quiet_p,
                quiet_counts)  # fmt: skip
        if ready(decision_counts_loop, *args):
            decision_counts_loop(*args)
        else:
            bins = self.config.bins
            self._occupied *= self.config.decay
            self._free *= self.config.decay
            index = np.minimum((p * bins).astype(int), bins - 1)
            cell = rare.astype(int) * bins + index
            self._occupied += np.bincount(cell[occupied], minlength=2 * bins).reshape(2, bins)
            self._free += np.bincount(cell[~occupied], minlength=2 * bins).reshape(2, bins)
            quiet_index = np.minimum((quiet_p * bins).astype(int), bins - 1)
            for k in (0, 1):
                self._free[k, quiet_index[k]] += quiet_counts[k, 0]
                self._occupied[k, quiet_index[k]] += quiet_counts[k, 1]


def choose_thresholds(stacks: list[HorizonStacking]) -> None:
    """Each of ``stacks`` (of one ``rare_weight``) chooses its thresholds anew from its
    decision statistics (:func:`best_thresholds`), all in one NumPy pass."""
    if not stacks:
        return
    weight = stacks[0].config.rare_weight
    assert all(stack.config.rare_weight == weight for stack in stacks)
    occupied = np.stack([stack._occupied for stack in stacks])
    free = np.stack([stack._free for stack in stacks])
    for stack, thresholds in zip(stacks, best_thresholds_each(occupied, free, weight), strict=True):
        stack.thresholds = thresholds


def best_thresholds(occupied: np.ndarray, free: np.ndarray, rare_weight: float) -> np.ndarray:
    """The thresholds ``(common, rare)`` (bin edges in (0, 1)) that maximise F1 over all
    cells plus ``rare_weight`` times the rare cells' F1, from counts ``(2, bins)`` of occupied
    and free cells per kind (0 common, 1 rare) and bin of the probability. A cell at or above
    the threshold's bin counts as predicted occupied."""
    return best_thresholds_each(occupied[None], free[None], rare_weight)[0]


def best_thresholds_each(occupied: np.ndarray, free: np.ndarray, rare_weight: float) -> np.ndarray:
    """:func:`best_thresholds` of ``K`` pairs of counts ``(K, 2, bins)``: ``(K, 2)``."""
    occupied, free = np.asarray(occupied, np.float64), np.asarray(free, np.float64)
    bins = occupied.shape[-1]
    totals = occupied.sum(axis=-1)  # (K, 2)
    args = [(o, f, t, float(rare_weight)) for o, f, t in zip(occupied, free, totals, strict=True)]
    if args and ready(thresholds_loop, *args[0]):
        chosen = np.array([thresholds_loop(*a) for a in args], np.intp).reshape(-1, 2)
    else:
        chosen = _best_pairs(occupied, free, totals, rare_weight)
    edges = np.maximum(np.arange(bins) / bins, 0.5 / bins)
    out = edges[chosen]
    out[~occupied.any(axis=(1, 2))] = DECIDED  # nothing occupied yet: the metric's own
    return out  # type: ignore[no-any-return]


def _best_pairs(
    occupied: np.ndarray, free: np.ndarray, totals: np.ndarray, rare_weight: float
) -> np.ndarray:
    """:func:`best_thresholds_each`' bin indices ``(K, 2)`` (common, rare), from the counts and
    ``totals`` (``occupied.sum(axis=-1)``)."""
    # predicted occupied at threshold index i: the bins i .. bins - 1
    tp = np.cumsum(occupied[..., ::-1], axis=-1)[..., ::-1]  # (K, 2, bins)
    fp = np.cumsum(free[..., ::-1], axis=-1)[..., ::-1]
    wrong = fp + (totals[..., None] - tp)  # false positives and negatives
    # all cells: every pair (i common, j rare)
    f1_all = f1_of(
        tp[:, 0, :, None] + tp[:, 1, None, :], wrong[:, 0, :, None] + wrong[:, 1, None, :]
    )
    score = f1_all + rare_weight * f1_of(tp[:, 1], wrong[:, 1])[:, None, :]
    flat = np.argmax(score.reshape(len(score), -1), axis=1)
    return np.stack(np.unravel_index(flat, score.shape[1:]), axis=1)


def f1_of(tp: np.ndarray, wrong: np.ndarray) -> np.ndarray:
    """F1 from true positives and wrong cells (false positives plus false negatives),
    elementwise; 0 where there is nothing either way."""
    denominator = 2 * tp + wrong
    return np.where(denominator > 0, 2 * tp / np.where(denominator > 0, denominator, 1.0), 0.0)


def active_cells(flat: np.ndarray, level: np.generic) -> np.ndarray:
    """The indices of the columns of ``flat`` ``(E, N)`` where some value is above ``level``
    (a scalar of ``flat``'s type): ``np.flatnonzero((flat > level).any(axis=0))``, compiled
    where available."""
    if ready(active_loop, flat, level, variant=(flat.dtype.str, flat.flags.c_contiguous)):
        return active_loop(flat, level)  # type: ignore[no-any-return]
    return np.flatnonzero((flat > level).any(axis=0))


def _grid(
    active: np.ndarray, values: np.ndarray, quiet: np.ndarray, rare: np.ndarray
) -> np.ndarray:
    """The grid ``(H, W)`` of ``rare``'s shape holding ``values`` at the flat ``active``
    cells and ``quiet`` (not rare, rare) elsewhere."""
    grid = np.where(rare.ravel(), quiet[1], quiet[0])
    grid[active] = values
    return grid.reshape(rare.shape)


def _quiet_kinds(rare: np.ndarray, occupied: np.ndarray, active: np.ndarray) -> np.ndarray:
    """The cells ``(2, 2)`` float64 per kind (common, rare) and label (free, occupied) of the
    flat bool ``rare`` and ``occupied`` but the ``active`` ones. Compiled where available."""
    args = (rare.view(np.uint8), occupied.view(np.uint8), active)
    if ready(quiet_kinds_loop, *args):
        return quiet_kinds_loop(*args)  # type: ignore[no-any-return]
    return _kinds(rare, occupied) - _kinds(rare[active], occupied[active])


def _kinds(rare: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """The cells ``(2, 2)`` float64 per kind (common, rare) and label (free, occupied) of the
    flat bool ``rare`` and ``occupied``."""
    both = np.count_nonzero(rare & occupied)
    rare_cells, occupied_cells = np.count_nonzero(rare), np.count_nonzero(occupied)
    common = rare.size - rare_cells - occupied_cells + both
    return np.array([[common, occupied_cells - both], [rare_cells - both, both]], np.float64)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(x, -30, 30)))
