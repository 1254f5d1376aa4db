"""Compiled loops for the per-scan hot spots, where numba is installed (``lidarflow[fast]``).

Each kernel is a plain Python loop that :func:`kernel` hands to numba; every caller keeps a
NumPy reference beside it and takes the kernel only where :func:`available` says so, so an
install without numba gives the same outputs at NumPy's speed. The kernels do the reference's
arithmetic in its order (no fast-math, no fused multiply-add), so outputs are bit-identical;
the tests compare each against its reference.

Compiled code is cached on disk (numba's ``cache=True``: beside the module, or in the user's
cache when that is read-only; ``NUMBA_CACHE_DIR`` moves it), so only the first run on a machine
compiles. ``LIDARFLOW_COMPILED=0`` turns the kernels off (the NumPy references run).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["available", "kernel"]

F = TypeVar("F", bound=Callable[..., Any])

try:
    if os.environ.get("LIDARFLOW_COMPILED", "1") == "0":
        raise ImportError("turned off by LIDARFLOW_COMPILED=0")
    import numba
except ImportError:
    numba = None


def available() -> bool:
    """Whether the kernels run compiled (numba importable and not turned off)."""
    return numba is not None


def kernel(function: F) -> F:
    """``function`` compiled by numba (no Python objects, the GIL released, cached on disk), or
    ``function`` itself where numba is not available: the callers then take their NumPy
    reference, never this loop, which in pure Python would be slow."""
    if numba is None:
        return function
    return numba.njit(cache=True, nogil=True)(function)  # type: ignore[no-any-return]
