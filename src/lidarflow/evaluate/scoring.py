"""Accumulate predictions against truth: one :class:`Scorer` per method and recording; scorers
add up (micro-averaging) for "overall".

Probabilities are binned into :data:`BINS` equal bins for the precision-recall curve, exact for
binary predictors and within 1/BINS in threshold otherwise. The peers' WMSE and SSIM are
averaged over the frames scored (as SOGMP averages over its test frames).
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lidarflow.evaluate.calibration import Calibration
from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion, summed
from lidarflow.evaluate.movers import MoverScore
from lidarflow.evaluate.peer_metrics import SSIM_WINDOW, ssim, wmse

__all__ = ["BINS", "Scorer"]

BINS = 200


@dataclass
class Scorer:
    """One method's scores on one recording: counts at 0.4, changed cells, PR bins,
    calibration, end-point errors, moving segmentation, the peers' metrics and the movers."""

    counts: Counts = field(default_factory=Counts)
    changed: Counts = field(default_factory=Counts)
    frames: int = 0
    epe_sum: float = 0.0
    epe_cells: int = 0
    epe_per_frame: list[float] = field(default_factory=list)
    # end-point error split by the truth: cells that move on their own / with the platform
    epe_moving_sum: float = 0.0
    epe_moving_cells: int = 0
    epe_static_sum: float = 0.0
    epe_static_cells: int = 0
    positives: np.ndarray = field(default_factory=lambda: np.zeros(BINS + 1, np.int64))
    negatives: np.ndarray = field(default_factory=lambda: np.zeros(BINS + 1, np.int64))
    calibration: Calibration = field(default_factory=Calibration)
    moving: Counts = field(default_factory=Counts)
    moving_frames: int = 0
    wmse_sum: float = 0.0
    ssim_sum: float = 0.0
    ssim_frames: int = 0
    movers: MoverScore = field(default_factory=MoverScore)
    # each frame's counts in order, for the margins' intervals (.resampling): (tp, fp, fn) a
    # frame, and the movers' TolerantCounts.row(); int32, 40 bytes a frame
    counts_rows: array = field(default_factory=lambda: array("i"))
    changed_rows: array = field(default_factory=lambda: array("i"))
    mover_rows: array = field(default_factory=lambda: array("i"))

    def add(self, probability: np.ndarray, current: np.ndarray, target: np.ndarray) -> None:
        """Score one predicted map against the true next map ``target``; ``current`` is the
        map the prediction was made from (for the changed-cell mask)."""
        target = target.astype(bool)
        predicted = probability >= THRESHOLD
        counts = confusion(predicted, target)
        changed = confusion(predicted, target, current.astype(bool) != target)
        self.counts, self.changed = self.counts + counts, self.changed + changed
        self.counts_rows.extend(counts.row())
        self.changed_rows.extend(changed.row())
        # Bin index = floor(p * BINS), so "p >= k / BINS" is exactly "bin >= k".
        bins = np.clip(np.floor(np.asarray(probability, np.float64) * BINS), 0, BINS).astype(int)
        self.positives += np.bincount(bins[target], minlength=BINS + 1)
        self.negatives += np.bincount(bins[~target], minlength=BINS + 1)
        self.calibration.add(probability, target)
        self.wmse_sum += float(wmse(np.atleast_2d(probability), np.atleast_2d(target)))
        if target.ndim == 2 and min(target.shape) >= SSIM_WINDOW:
            self.ssim_sum += float(ssim(probability, target))
            self.ssim_frames += 1
        self.frames += 1

    def add_movers(self, probability: np.ndarray, target: np.ndarray, region: np.ndarray) -> None:
        """Score one predicted map inside the target frame's dynamic ``region``."""
        self.mover_rows.extend(self.movers.add(probability, target, region).row())

    def add_moving(self, predicted: np.ndarray, truth: np.ndarray) -> None:
        """Score one frame's moving-cell mask ``(H, W)`` against the true moving cells."""
        self.moving = self.moving + confusion(predicted, truth)
        self.moving_frames += 1

    def add_epe(self, error_sum: float, cells: int) -> None:
        self.epe_sum += error_sum
        self.epe_cells += cells
        self.epe_per_frame.append(error_sum / cells if cells else float("nan"))

    def add_epe_split(self, error: np.ndarray, cells: np.ndarray, moving: np.ndarray) -> None:
        """Add one frame's end-point errors ``(H, W)`` on ``cells``, the truly ``moving`` ones
        and the rest (static) apart."""
        moving = cells & moving
        static = cells & ~moving
        self.epe_moving_sum += float(error[moving].sum())
        self.epe_moving_cells += int(moving.sum())
        self.epe_static_sum += float(error[static].sum())
        self.epe_static_cells += int(static.sum())

    def __add__(self, other: Scorer) -> Scorer:
        return summed(self, other)

    def pr_curve(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(thresholds, precision, recall)`` for thresholds ``k / BINS``, high to low."""
        tp = np.cumsum(self.positives[::-1])
        fp = np.cumsum(self.negatives[::-1])
        total = max(int(self.positives.sum()), 1)
        precision = np.where(tp + fp > 0, tp / np.maximum(tp + fp, 1), 1.0)
        recall = tp / total
        thresholds = np.arange(BINS, -1, -1) / BINS
        return thresholds, precision, recall

    def average_precision(self) -> float:
        """Sum over thresholds of precision times the recall gained (as scikit-learn)."""
        _, precision, recall = self.pr_curve()
        gained = np.diff(np.concatenate([[0.0], recall]))
        return float(np.sum(gained * precision))

    def summary(self) -> dict[str, Any]:
        """The metrics as JSON: flat numbers (``f1`` ... ``epe``, ``wmse``, ``ssim``),
        ``calibration`` and, where scored, ``segmentation`` of the moving class and ``movers``
        (with the flat ``mover_f1`` and ``mover_f1_tolerant``)."""
        out: dict[str, Any] = {
            "f1": self.counts.f1,
            "precision": self.counts.precision,
            "recall": self.counts.recall,
            "ap": self.average_precision(),
            "changed_f1": self.changed.f1,
            "frames": self.frames,
        }
        if self.epe_cells:
            out["epe"] = self.epe_sum / self.epe_cells
        if self.epe_moving_cells:
            out["epe_moving"] = self.epe_moving_sum / self.epe_moving_cells
        if self.epe_static_cells:
            out["epe_static"] = self.epe_static_sum / self.epe_static_cells
        if self.frames:
            out["wmse"] = self.wmse_sum / self.frames
        if self.ssim_frames:
            out["ssim"] = self.ssim_sum / self.ssim_frames
        out["calibration"] = self.calibration.summary()
        if self.movers.frames:
            out["movers"] = self.movers.summary()
            out["mover_f1"] = out["movers"]["f1"]
            out["mover_f1_tolerant"] = out["movers"]["f1_tolerant"]
        if self.moving_frames:
            out["segmentation"] = {
                "iou": self.moving.iou,
                **self.moving.to_dict(),
                "frames": self.moving_frames,
            }
        return out
