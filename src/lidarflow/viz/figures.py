"""Matplotlib set-up shared by every picture: headless backend, saving and closing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["check_picture_path", "pyplot", "save_figure"]


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def check_picture_path(path: str | Path) -> None:
    """Refuse, in one line, a picture path whose suffix names no format matplotlib writes
    (it picks the format by the suffix)."""
    from matplotlib.backend_bases import FigureCanvasBase

    from lidarflow.errors import OutputError

    formats = FigureCanvasBase.get_supported_filetypes()
    if Path(path).suffix.lower().lstrip(".") not in formats:
        known = ", ".join(f".{f}" for f in ("png", "pdf", "svg", "jpg"))
        raise OutputError(f"{path}: not a picture format lidarflow writes; end it in {known}...")


def save_figure(fig: Any, path: str | Path, dpi: int = 100) -> Path:
    """Save ``fig`` as ``path`` (parents created; whole or not at all) and release it."""
    from lidarflow.atomic import atomic_path

    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi)
    finally:
        pyplot().close(fig)
    return path
