"""Calibration of predicted occupancy probabilities: of the cells given probability ``p``, a
share ``p`` should be occupied. Over every cell of every scored frame in ``bins`` equal bins:
the reliability diagram, the ECE (Guo et al. 2017), the *active* ECE over the cells predicted
at least ``1 / bins`` (most cells are free and predicted free, which makes the plain ECE small
for every method) and the Brier score.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["CALIBRATION_BINS", "Calibration"]

CALIBRATION_BINS = 10


@dataclass
class Calibration:
    """Sums that make a reliability diagram, accumulated frame by frame; they add up."""

    bins: int = CALIBRATION_BINS
    count: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    probability_sum: np.ndarray = field(default_factory=lambda: np.zeros(0))
    occupied: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    squared_error: float = 0.0

    def __post_init__(self) -> None:
        if self.bins < 1:
            raise ValueError(f"bins must be >= 1, got {self.bins}")
        if not len(self.count):
            self.count = np.zeros(self.bins, np.int64)
            self.probability_sum = np.zeros(self.bins)
            self.occupied = np.zeros(self.bins, np.int64)

    def add(self, probability: np.ndarray, target: np.ndarray) -> None:
        """Add probabilities (any shape, clipped to [0, 1]) and the truth of the same shape."""
        p = np.clip(np.asarray(probability, np.float64), 0.0, 1.0).ravel()
        y = np.asarray(target).astype(bool).ravel()
        if p.shape != y.shape:
            raise ValueError(
                f"probability {np.shape(probability)} and target {np.shape(target)} differ in shape"
            )
        index = np.minimum((p * self.bins).astype(np.int64), self.bins - 1)
        self.count += np.bincount(index, minlength=self.bins)
        self.probability_sum += np.bincount(index, weights=p, minlength=self.bins)
        self.occupied += np.bincount(index[y], minlength=self.bins)
        self.squared_error += float(np.sum((p - y) ** 2))

    def __add__(self, other: Calibration) -> Calibration:
        if self.bins != other.bins:
            raise ValueError(f"cannot add calibrations of {self.bins} and {other.bins} bins")
        return Calibration(
            self.bins,
            self.count + other.count,
            self.probability_sum + other.probability_sum,
            self.occupied + other.occupied,
            self.squared_error + other.squared_error,
        )

    @property
    def cells(self) -> int:
        return int(self.count.sum())

    def mean_probability(self) -> np.ndarray:
        """Per bin, the mean predicted probability (NaN for empty bins)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count > 0, self.probability_sum / self.count, np.nan)

    def frequency(self) -> np.ndarray:
        """Per bin, the observed share of occupied cells (NaN for empty bins)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.count > 0, self.occupied / self.count, np.nan)

    def ece(self) -> float:
        """Expected calibration error; 0.0 with no cells."""
        if not self.cells:
            return 0.0
        used = self.count > 0
        gap = np.abs(self.probability_sum[used] - self.occupied[used])  # n_k |mean_p - freq|
        return float(gap.sum() / self.cells)

    def ece_active(self) -> float:
        """ECE over the cells predicted ``>= 1 / bins``; 0.0 when there are none."""
        cells = int(self.count[1:].sum())
        if not cells:
            return 0.0
        gap = np.abs(self.probability_sum[1:] - self.occupied[1:])
        return float(gap.sum() / cells)

    def brier(self) -> float:
        """Mean squared error of the probabilities; 0.0 with no cells."""
        return self.squared_error / self.cells if self.cells else 0.0

    def summary(self) -> dict[str, Any]:
        """``{"ece", "ece_active", "brier", "cells", "bins": [{"low", "high", "count",
        "mean_probability", "frequency"}]}`` (empty bins have ``null`` mean and frequency)."""
        mean, freq = self.mean_probability(), self.frequency()
        bins = [
            {
                "low": k / self.bins,
                "high": (k + 1) / self.bins,
                "count": int(self.count[k]),
                "mean_probability": None if np.isnan(mean[k]) else float(mean[k]),
                "frequency": None if np.isnan(freq[k]) else float(freq[k]),
            }
            for k in range(self.bins)
        ]
        return {
            "ece": self.ece(),
            "ece_active": self.ece_active(),
            "brier": self.brier(),
            "cells": self.cells,
            "bins": bins,
        }
