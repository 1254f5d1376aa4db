"""Prediction metrics (design notes, section 5).

F1 is micro-averaged: one TP/FP/FN count summed over every cell of every evaluated frame (and,
for "overall", every recording), then one F1 from the sums. Changed-cell F1 counts only cells
whose value differs between ``O^t`` and ``O^{t+1}``; copying the last map scores 0 there.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TypeVar

import numpy as np

from lidarflow.predict.offsets import THRESHOLD

__all__ = ["THRESHOLD", "Counts", "confusion", "summed"]

_Sums = TypeVar("_Sums")


@dataclass
class Counts:
    """True/false positives and false negatives, summed over cells."""

    tp: int = 0
    fp: int = 0
    fn: int = 0

    def __add__(self, other: Counts) -> Counts:
        return summed(self, other)

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else 0.0

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else 0.0

    @property
    def f1(self) -> float:
        """``2TP / (2TP + FP + FN)``; 1.0 when there is nothing to find and nothing predicted."""
        denom = 2 * self.tp + self.fp + self.fn
        return 2 * self.tp / denom if denom else 1.0

    @property
    def iou(self) -> float:
        """Intersection over union ``TP / (TP + FP + FN)`` of the positive class; 1.0 when
        there is nothing to find and nothing predicted (as :attr:`f1`)."""
        denom = self.tp + self.fp + self.fn
        return self.tp / denom if denom else 1.0

    def row(self) -> tuple[int, int, int]:
        """``(tp, fp, fn)``."""
        return self.tp, self.fp, self.fn

    def to_dict(self) -> dict[str, float | int]:
        return {
            "f1": self.f1,
            "precision": self.precision,
            "recall": self.recall,
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
        }


def summed(a: _Sums, b: _Sums) -> _Sums:
    """A dataclass of sums (counts over frames) whose every field is ``a``'s plus ``b``'s:
    how scores add up over recordings (micro-averaging)."""
    return type(a)(*(getattr(a, f.name) + getattr(b, f.name) for f in fields(a)))


def confusion(predicted: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> Counts:
    """Counts of a boolean prediction against a boolean target, optionally within ``mask``.

    >>> confusion(np.array([1, 1, 0], bool), np.array([1, 0, 1], bool))
    Counts(tp=1, fp=1, fn=1)
    """
    p = np.asarray(predicted, dtype=bool)
    t = np.asarray(target, dtype=bool)
    if p.shape != t.shape:
        raise ValueError(f"prediction {p.shape} and target {t.shape} differ in shape")
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        p, t = p & m, t & m
    return Counts(
        tp=int(np.count_nonzero(p & t)),
        fp=int(np.count_nonzero(p & ~t)),
        fn=int(np.count_nonzero(~p & t)),
    )
