"""Separable Gaussian filter ``G(maps, k)`` of the paper's loss (section IV-C).

- ``kernel_size`` is the paper's filter size: odd, ``1`` means no filter (the identity).
- ``sigma`` defaults to OpenCV's rule for the size (``cv2.getGaussianKernel`` with
  ``sigma <= 0``): the paper names only the size.
- Zero padding: cells beyond the map are empty space, as for the warp (reflect padding would
  invent mirrored obstacles), so mass leaks out at the edge only.
- The kernel sums to 1 and is applied per channel (depthwise), rows then columns.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

_KERNELS: dict[tuple[int, float, str, torch.dtype], Tensor] = {}


def opencv_sigma(kernel_size: int) -> float:
    """OpenCV's default sigma for an odd ``kernel_size``: ``0.3 * ((k - 1) * 0.5 - 1) + 0.8``."""
    return 0.3 * ((kernel_size - 1) * 0.5 - 1) + 0.8


def gaussian_kernel1d(
    kernel_size: int,
    sigma: float | None = None,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Normalised 1-D Gaussian weights ``(kernel_size,)``, centred, summing to 1.

    >>> gaussian_kernel1d(3, 1.0)
    tensor([0.2741, 0.4519, 0.2741])
    """
    _check_size(kernel_size, sigma)
    s = opencv_sigma(kernel_size) if sigma is None else float(sigma)
    half = (kernel_size - 1) / 2
    x = torch.arange(kernel_size, device=device, dtype=torch.float64) - half
    k = torch.exp(-(x**2) / (2 * s * s))
    return (k / k.sum()).to(dtype)


def gaussian_blur(maps: Tensor, kernel_size: int, sigma: float | None = None) -> Tensor:
    """Blur every channel of ``maps`` ``(B, C, H, W)`` with a ``kernel_size`` Gaussian, zero
    'same' padding; ``kernel_size == 1`` returns ``maps`` itself. Differentiable in ``maps``.

    >>> m = torch.zeros(1, 1, 5, 5); m[0, 0, 2, 2] = 1.0
    >>> out = gaussian_blur(m, 3)
    >>> round(out.sum().item(), 6), out[0, 0, 2, 2] > out[0, 0, 2, 1] > out[0, 0, 1, 1]
    (1.0, tensor(True))
    """
    if maps.dim() != 4:
        raise ValueError(f"maps must be (B, C, H, W), got {tuple(maps.shape)}")
    if not maps.is_floating_point():
        raise ValueError(f"maps must be floating point, got {maps.dtype}")
    _check_size(kernel_size, sigma)
    if kernel_size == 1:
        return maps
    channels = maps.shape[1]
    k = _kernel(kernel_size, sigma, maps.device, maps.dtype)
    pad = kernel_size // 2
    # Depthwise, separable: 2k multiply-adds per cell instead of k^2.
    rows = k.view(1, 1, kernel_size, 1).expand(channels, 1, kernel_size, 1)
    cols = k.view(1, 1, 1, kernel_size).expand(channels, 1, 1, kernel_size)
    out = F.conv2d(maps, rows, padding=(pad, 0), groups=channels)
    return F.conv2d(out, cols, padding=(0, pad), groups=channels)


def _kernel(
    kernel_size: int, sigma: float | None, device: torch.device, dtype: torch.dtype
) -> Tensor:
    key = (kernel_size, -1.0 if sigma is None else float(sigma), str(device), dtype)
    k = _KERNELS.get(key)
    if k is None:
        k = gaussian_kernel1d(kernel_size, sigma, device=device, dtype=dtype)
        if len(_KERNELS) > 64:
            _KERNELS.clear()
        _KERNELS[key] = k
    return k


def _check_size(kernel_size: int, sigma: float | None) -> None:
    if isinstance(kernel_size, bool) or not isinstance(kernel_size, int):
        raise ValueError(f"kernel_size must be an odd int, got {kernel_size!r}")
    if kernel_size < 1 or kernel_size % 2 == 0:
        raise ValueError(f"kernel_size must be odd and >= 1, got {kernel_size}")
    if sigma is not None and not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a positive finite number or None, got {sigma!r}")
