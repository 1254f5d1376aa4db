"""The metrics the peers (SOGMP, SCOPE) report beside F1: the class-weighted MSE and SSIM of a
predicted map, pure NumPy on maps ``(..., H, W)``, one value per map. Their definitions, and
why numbers differ across grids and papers: ``docs/guide/conventions.md``. SSIM equals
scikit-image's ``structural_similarity(x, y, gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=1)``.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["SSIM_C1", "SSIM_C2", "SSIM_SIGMA", "SSIM_WINDOW", "gaussian_window", "ssim", "wmse"]

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2  # (K1 L)^2 with L = 1
SSIM_C2 = 0.03**2  # (K2 L)^2


def _pair(
    predicted: np.ndarray, target: np.ndarray, dtype: type = np.float64
) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(predicted, dtype)
    t = np.asarray(target, dtype)
    if p.shape != t.shape or p.ndim < 2:
        raise ValueError(
            f"predicted and target must be maps (..., H, W) of one shape, got {p.shape} and "
            f"{t.shape}"
        )
    return p, t


def wmse(
    predicted: np.ndarray,
    target: np.ndarray,
    weights: tuple[float, float] | None = None,
) -> np.ndarray:
    """Class-weighted mean squared error of ``predicted`` probabilities against the 0/1
    ``target`` (cells ``>= 0.5`` occupied), ``(..., H, W) -> (...)``, in [0, 1], lower is
    better. ``weights=None`` balances the classes per map; ``(w_free, w_occupied)`` fixes them.

    >>> target = np.array([[1.0, 0.0, 0.0, 0.0]])
    >>> float(wmse(np.zeros((1, 4)), target))  # misses the one occupied cell: half the weight
    0.5
    >>> float(wmse(np.zeros((1, 4)), target, weights=(1.0, 1.0)))  # the plain MSE
    0.25
    """
    p, t = _pair(predicted, target)
    occupied = t >= 0.5
    error = (p - t) ** 2
    axes = (-2, -1)
    if weights is not None:
        w_free, w_occupied = (float(w) for w in weights)
        if w_free < 0 or w_occupied < 0 or w_free + w_occupied == 0:
            raise ValueError(f"weights must be >= 0 and not both 0, got {weights}")
        w = np.where(occupied, w_occupied, w_free)
        return np.sum(w * error, axis=axes) / np.maximum(np.sum(w, axis=axes), 1e-300)
    n_occupied = np.count_nonzero(occupied, axis=axes)
    n_free = occupied.shape[-2] * occupied.shape[-1] - n_occupied
    sse_occupied = np.sum(np.where(occupied, error, 0.0), axis=axes)
    sse_free = np.sum(np.where(occupied, 0.0, error), axis=axes)
    # the mean of the per-class MSEs over the classes present
    mse_occupied = sse_occupied / np.maximum(n_occupied, 1)
    mse_free = sse_free / np.maximum(n_free, 1)
    present = (n_occupied > 0).astype(np.float64) + (n_free > 0)
    return (mse_occupied + mse_free) / present


def gaussian_window(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> np.ndarray:
    """The normalised 1-D Gaussian ``(size,)`` whose outer product is SSIM's window."""
    x = np.arange(size, dtype=np.float64) - (size - 1) / 2
    g = np.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


@functools.lru_cache(maxsize=8)
def _band(size: int, n: int = SSIM_WINDOW) -> np.ndarray:
    """``(size, size - n + 1)`` float32: column ``j`` holds the window over cells
    ``j .. j + n - 1``, so that a product with it filters one axis (a BLAS product)."""
    g = gaussian_window(n)
    band = np.zeros((size, size - n + 1), np.float32)
    for j in range(size - n + 1):
        band[j : j + n, j] = g
    band.setflags(write=False)
    return band


def _filter(maps: np.ndarray) -> np.ndarray:
    """``maps (..., H, W)`` filtered at the valid positions: ``(..., H - 10, W - 10)``."""
    return _band(maps.shape[-2]).T @ (maps @ _band(maps.shape[-1]))


def ssim(predicted: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Mean structural similarity of two maps with values in [0, 1], ``(..., H, W) -> (...)``,
    in [-1, 1], 1 for identical maps. Maps must be at least 11 x 11 cells.

    >>> x = np.zeros((12, 12)); x[3:8, 4:6] = 1.0
    >>> float(ssim(x, x))
    1.0
    >>> round(float(ssim(x, np.zeros((12, 12)))), 4)  # a blank prediction
    0.0
    """
    x, y = _pair(predicted, target, np.float32)
    if min(x.shape[-2:]) < SSIM_WINDOW:
        raise ValueError(
            f"SSIM needs maps of at least {SSIM_WINDOW} x {SSIM_WINDOW} cells, got "
            f"{x.shape[-2]} x {x.shape[-1]}"
        )
    mu_x, mu_y, xx, yy, xy = _filter(np.stack([x, y, x * x, y * y, x * y]))
    var_x = xx - mu_x * mu_x
    var_y = yy - mu_y * mu_y
    cov = xy - mu_x * mu_y
    local = ((2 * mu_x * mu_y + SSIM_C1) * (2 * cov + SSIM_C2)) / (
        (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (var_x + var_y + SSIM_C2)
    )
    return local.mean(axis=(-2, -1), dtype=np.float64)
