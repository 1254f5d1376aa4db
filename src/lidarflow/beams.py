"""Beam validity: what each reading of a scan says, a return, no return, or unknown.

A finite ``rho`` with ``range_min <= rho < range_max`` is a *return*; ``+inf`` or
``rho >= range_max`` is *no return* (free space out to ``range_max``); ``NaN``, ``-inf``, ``0``
or ``rho < range_min`` are *unknown*. In a scan that writes no return as ``range_max``, readings
just under it are no return too (``docs/guide/conventions.md#beams``).

NumPy, with :func:`return_masks` in one compiled pass where :mod:`lidarflow.compiled` is
available; every function takes ranges ``(..., beams)``, one row a scan.
"""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import available, kernel, ready

__all__ = [
    "NO_RETURN",
    "RETURN",
    "RING_MIN_BEAMS",
    "RING_SHARE",
    "UNKNOWN",
    "at_range_max",
    "beam_status",
    "mask_thresholds",
    "return_masks",
    "ring_band",
    "ring_scans",
    "scan_masks",
]

UNKNOWN, RETURN, NO_RETURN = 0, 1, 2


def beam_status(ranges: np.ndarray, range_min: float, range_max: float) -> np.ndarray:
    """Each beam's status: ``UNKNOWN`` (0), ``RETURN`` (1) or ``NO_RETURN`` (2).

    >>> beam_status(np.array([1.0, np.inf, np.nan, 0.0, 20.0, 10.0]), 0.1, 10.0).tolist()
    [1, 2, 0, 0, 2, 2]
    >>> beam_status(np.array([0.0, 0.5]), 0.0, 10.0).tolist()  # 0 is unknown whatever range_min
    [0, 1]
    """
    r = np.atleast_1d(np.asarray(ranges))
    if not np.issubdtype(r.dtype, np.floating):
        r = r.astype(np.float64)
    is_return, beyond = return_masks(r, range_min, range_max)
    status = np.zeros(r.shape, dtype=np.uint8)
    status[is_return] = RETURN
    status[beyond] = NO_RETURN
    return status


#: A scan with at least this share of its beams (and :data:`RING_MIN_BEAMS`) reading exactly
#: ``range_max`` writes "no return" that way.
RING_SHARE = 0.01
RING_MIN_BEAMS = 3


def ring_band(range_max: float) -> float:
    """How far under ``range_max`` (m) a scan that writes no return as ``range_max`` also reads
    as no return: 1 % of it, at least 3 cm (3 sigma of the 1 cm noise simulators add)."""
    return max(0.03, 0.01 * float(range_max))


def at_range_max(ranges: np.ndarray, range_max: float) -> np.ndarray:
    """How many readings of each scan are exactly ``range_max`` in the ranges' (float) dtype
    (none where ``range_max`` is beyond it)."""
    r = np.asarray(ranges)
    with np.errstate(over="ignore"):  # a range_max beyond float32 (pointcloud_to_laserscan's)
        top = r.dtype.type(range_max)
    return np.count_nonzero(r == top, axis=-1) if np.isfinite(top) else np.zeros(r.shape[:-1])


def ring_scans(ranges: np.ndarray, range_max: float) -> np.ndarray:
    """Whether each scan writes no return as ``range_max``: :data:`RING_SHARE` of its beams,
    and :data:`RING_MIN_BEAMS`, read exactly that, which a continuous measurement does not."""
    counts = at_range_max(ranges, range_max)
    return counts >= max(RING_MIN_BEAMS, RING_SHARE * np.shape(ranges)[-1])


def return_masks(
    r: np.ndarray, range_min: float, range_max: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(is_return, no_return)`` masks of float ranges ``r`` by the module's rule.
    ``range_max`` is compared in ``r``'s dtype, so a reading stored as the message's float32
    ``range_max`` is no return whatever that value's float64 neighbours; ``range_min`` as NumPy
    compares it (a Python float in ``r``'s dtype). Compiled where available (float32 and
    float64 ranges), the same masks."""
    if available() and r.ndim and r.size and r.dtype in (np.float32, np.float64):
        masks = _return_masks_compiled(r, range_min, range_max)
        if masks is not None:
            return masks
    return _return_masks_numpy(r, range_min, range_max)


def _return_masks_numpy(
    r: np.ndarray, range_min: float, range_max: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`return_masks` in NumPy (the reference)."""
    # a range_max beyond float32 (pointcloud_to_laserscan's default, 1.8e308) casts to inf
    with np.errstate(invalid="ignore", over="ignore"):
        top = r.dtype.type(range_max)
        beyond = r >= top  # +inf included; NaN compares False
        ring = ring_scans(r, range_max)[..., None]
        beyond |= ring & (r >= r.dtype.type(range_max - ring_band(range_max)))
        # 0 is unknown even where range_min is 0 (drivers write invalid beams as 0)
        return (r >= range_min) & (r > 0) & ~beyond, beyond


@kernel
def scan_masks(
    r: np.ndarray,
    thresholds: np.ndarray,
    is_return: np.ndarray,
    beyond: np.ndarray,
) -> None:
    """:func:`_return_masks_numpy` of one scan ``r`` ``(beams,)`` into ``is_return``,
    ``beyond``, compiled. ``thresholds`` (:func:`mask_thresholds`) are the values NumPy
    compares with, rounded to the comparison's dtype, so that comparing in float64 is exact."""
    low, top, ring_low, ring_count = thresholds[0], thresholds[1], thresholds[2], thresholds[3]
    at_top = 0
    for i in range(len(r)):
        if r[i] == top:
            at_top += 1
    ring = at_top >= ring_count
    for i in range(len(r)):
        x = r[i]
        out = x >= top or (ring and x >= ring_low)
        beyond[i] = out
        is_return[i] = x >= low and x > 0 and not out


@kernel
def _masks_loop(
    r: np.ndarray, thresholds: np.ndarray, is_return: np.ndarray, beyond: np.ndarray
) -> None:
    """:func:`scan_masks` of every scan of ``r`` ``(scans, beams)``."""
    for s in range(r.shape[0]):
        scan_masks(r[s], thresholds, is_return[s], beyond[s])


def mask_thresholds(dtype: np.dtype, range_min: float, range_max: float, beams: int) -> np.ndarray:
    """``(low, top, ring_low, ring_count)`` float64 for :func:`scan_masks` of ``beams`` readings
    of float ``dtype``: ``range_min`` as NumPy compares it with ``dtype`` (a Python float in
    ``dtype``, a NumPy float64 in float64), ``range_max`` and the ring band's edge in
    ``dtype``, and the readings at ``top`` that make a ring scan (``inf`` where ``top`` is not
    finite)."""
    with np.errstate(invalid="ignore", over="ignore"):
        top = dtype.type(range_max)
        ring_low = dtype.type(range_max - ring_band(range_max))
        low = np.result_type(dtype, range_min).type(range_min)
    ring_count = max(RING_MIN_BEAMS, RING_SHARE * beams) if np.isfinite(top) else np.inf
    return np.array([low, top, ring_low, ring_count], np.float64)


def _return_masks_compiled(
    r: np.ndarray, range_min: float, range_max: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`return_masks` by :func:`_masks_loop` (``r`` float32 or float64, 1-D or more, not
    empty); ``None`` while the loop is not compiled yet (:func:`lidarflow.compiled.ready`)."""
    thresholds = mask_thresholds(r.dtype, range_min, range_max, r.shape[-1])
    flat = np.ascontiguousarray(r).reshape(-1, r.shape[-1])
    is_return = np.empty(flat.shape, bool)
    beyond = np.empty(flat.shape, bool)
    if not ready(_masks_loop, flat, thresholds, is_return, beyond):
        return None
    _masks_loop(flat, thresholds, is_return, beyond)
    return is_return.reshape(r.shape), beyond.reshape(r.shape)
