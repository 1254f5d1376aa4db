"""The mover metric (design notes §5): how well a prediction foresees what moves, scored inside
the *dynamic region* of its target frame only (:mod:`lidarflow.evaluate.dynamic`), where walls
and edge flicker do not drown it: exact and tolerant F1, AUC and soft IoU, micro-averaged
(definitions: ``docs/guide/conventions.md``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion, summed
from lidarflow.nearby import TOLERANCE, near

__all__ = ["BINS", "TOLERANCE", "MoverScore", "TolerantCounts", "near", "roc_auc", "tolerant_f1"]

#: Bins of the probability for the AUC.
BINS = 200


@dataclass
class TolerantCounts:
    """Counts of the tolerant F1: predicted cells right / wrong, true cells found / missed."""

    right: int = 0
    wrong: int = 0
    found: int = 0
    missed: int = 0

    def __add__(self, other: TolerantCounts) -> TolerantCounts:
        return summed(self, other)

    @property
    def precision(self) -> float:
        predicted = self.right + self.wrong
        return self.right / predicted if predicted else 0.0

    @property
    def recall(self) -> float:
        true = self.found + self.missed
        return self.found / true if true else 0.0

    @property
    def f1(self) -> float:
        """Harmonic mean of precision and recall; 1.0 with nothing to find nor predicted."""
        return float(tolerant_f1(self.right, self.wrong, self.found, self.missed))

    def row(self) -> tuple[int, int, int, int]:
        """The counts in :func:`tolerant_f1`'s order."""
        return self.right, self.wrong, self.found, self.missed

    @classmethod
    def of(
        cls, predicted: np.ndarray, target: np.ndarray, region: np.ndarray, radius: int = TOLERANCE
    ) -> TolerantCounts:
        """Counts of bool ``predicted`` against ``target`` inside ``region`` (one shape), with
        a tolerance of ``radius`` cells."""
        p = np.asarray(predicted, bool) & region
        t = np.asarray(target, bool) & region
        right = int(np.count_nonzero(p & near(t, radius)))
        found = int(np.count_nonzero(t & near(p, radius)))
        return cls(right, int(np.count_nonzero(p)) - right, found, int(np.count_nonzero(t)) - found)


def tolerant_f1(
    right: np.ndarray, wrong: np.ndarray, found: np.ndarray, missed: np.ndarray
) -> np.ndarray:
    """:attr:`TolerantCounts.f1` of counts (arrays alike), elementwise: the harmonic mean of
    ``right / (right + wrong)`` and ``found / (found + missed)`` (each 0 without a cell), 1
    where nothing was predicted nor true.

    >>> tolerant_f1(np.array([3, 0]), np.array([1, 0]), np.array([2, 0]), np.array([2, 0]))
    array([0.6, 1. ])
    """
    right, wrong, found, missed = (np.asarray(v, np.float64) for v in (right, wrong, found, missed))
    predicted, true = right + wrong, found + missed
    p = np.divide(right, predicted, out=np.zeros_like(right), where=predicted > 0)
    r = np.divide(found, true, out=np.zeros_like(found), where=true > 0)
    f1 = np.divide(2 * p * r, p + r, out=np.zeros_like(p), where=p + r > 0)
    return np.where(predicted + true > 0, f1, 1.0)


def roc_auc(positives: np.ndarray, negatives: np.ndarray) -> float:
    """Area under the ROC curve from histograms of the positive and the negative cells'
    probabilities over the same bins (low to high), ties in a bin half; NaN when either class
    is empty.

    >>> roc_auc(np.array([0, 1]), np.array([1, 0]))
    1.0
    """
    positives = np.asarray(positives, np.float64)
    negatives = np.asarray(negatives, np.float64)
    n_pos, n_neg = positives.sum(), negatives.sum()
    if not n_pos or not n_neg:
        return float("nan")
    below = np.concatenate([[0.0], np.cumsum(negatives)[:-1]])  # negatives in lower bins
    return float((positives * (below + 0.5 * negatives)).sum() / (n_pos * n_neg))


@dataclass
class MoverScore:
    """The mover metric of one method, summed over the frames it scored (see the module)."""

    exact: Counts = field(default_factory=Counts)
    tolerant: TolerantCounts = field(default_factory=TolerantCounts)
    positives: np.ndarray = field(default_factory=lambda: np.zeros(BINS + 1, np.int64))
    negatives: np.ndarray = field(default_factory=lambda: np.zeros(BINS + 1, np.int64))
    soft_intersection: float = 0.0
    soft_union: float = 0.0
    cells: int = 0  # region cells scored, over all frames
    frames: int = 0

    def add(
        self,
        probability: np.ndarray,
        target: np.ndarray,
        region: np.ndarray,
        threshold: float = THRESHOLD,
    ) -> TolerantCounts:
        """Score one predicted map ``probability`` ``(H, W)`` against the true map ``target``
        inside ``region`` (bool, the target frame's dynamic region); returns the frame's
        tolerant counts."""
        p = np.asarray(probability, np.float64)
        y = np.asarray(target, bool)
        region = np.asarray(region, bool)
        if not p.shape == y.shape == region.shape:
            raise ValueError(
                f"probability {p.shape}, target {y.shape} and region {region.shape} differ"
            )
        decided = p >= threshold
        self.exact = self.exact + confusion(decided, y, region)
        tolerant = TolerantCounts.of(decided, y, region)
        self.tolerant = self.tolerant + tolerant
        inside, truth = np.clip(p[region], 0.0, 1.0), y[region]
        bins = np.minimum(np.floor(inside * BINS), BINS).astype(int)
        self.positives += np.bincount(bins[truth], minlength=BINS + 1)
        self.negatives += np.bincount(bins[~truth], minlength=BINS + 1)
        both = inside * truth
        self.soft_intersection += float(both.sum())
        self.soft_union += float((inside + truth - both).sum())
        self.cells += int(region.sum())
        self.frames += 1
        return tolerant

    def __add__(self, other: MoverScore) -> MoverScore:
        return summed(self, other)

    @property
    def defined(self) -> bool:
        """Whether any true cell lay in the region: without one the scores say nothing."""
        return self.exact.tp + self.exact.fn > 0

    @property
    def soft_iou(self) -> float:
        return self.soft_intersection / self.soft_union if self.soft_union else 1.0

    def summary(self) -> dict[str, Any]:
        """``f1`` (exact), ``f1_tolerant``, their precision and recall, ``auc`` (``None``
        without both classes), ``soft_iou``, ``true_cells``, region ``cells`` and ``frames``."""
        auc = roc_auc(self.positives, self.negatives)
        return {
            "f1": self.exact.f1,
            "precision": self.exact.precision,
            "recall": self.exact.recall,
            "f1_tolerant": self.tolerant.f1,
            "precision_tolerant": self.tolerant.precision,
            "recall_tolerant": self.tolerant.recall,
            "auc": None if np.isnan(auc) else auc,
            "soft_iou": self.soft_iou,
            "true_cells": self.exact.tp + self.exact.fn,
            "cells": self.cells,
            "frames": self.frames,
        }
