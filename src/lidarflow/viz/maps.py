"""Pictures of occupancy and visibility maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidarflow.scan import GridSpec
from lidarflow.viz.figures import pyplot, save_figure

__all__ = ["draw_maps"]


def _extent(grid: GridSpec) -> tuple[float, float, float, float]:
    # imshow extent in (y_left, y_right, x_bottom, x_top) so the picture reads like the robot
    # sees it: forward is up, left is left, the sensor at the bottom middle.
    half = grid.width / 2 * grid.res
    return (half, -half, 0.0, grid.height * grid.res)


def draw_maps(
    occupancy: np.ndarray,
    visibility: np.ndarray,
    path: str | Path,
    grid: GridSpec | None = None,
    title: str = "",
    flow: np.ndarray | None = None,
    moving: np.ndarray | None = None,
    flow_scale: float = 1.0,
) -> Path:
    """Draw occupancy and visibility side by side and save a PNG.

    ``flow`` (optional) is a ``(2, H, W)`` flow in cells (channel 0 column, channel 1 row) that
    lives on ``occupancy``'s cells, i.e. the forward flow ``F^t`` of this frame: each occupied cell
    gets an arrow to where its content is in the next frame, drawn ``flow_scale`` times longer.
    ``moving`` (optional, ``(H, W)`` bool) marks occupied cells on moving objects in red."""
    plt = pyplot()

    grid = grid or GridSpec(*occupancy.shape)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.4), constrained_layout=True)
    extent = _extent(grid)
    panels = zip(axes, (occupancy, visibility), ("occupancy", "visibility"), strict=True)
    for ax, image, name in panels:
        ax.imshow(image, cmap="gray_r", vmin=0, vmax=1, extent=extent, interpolation="nearest")
        ax.plot([0], [0], marker="^", color="tab:red", markersize=10, clip_on=False)
        ax.set_title(name)
        ax.set_xlabel("y (m, left positive)")
        ax.set_ylabel("x (m, forward)")
    if moving is not None and (moving & occupancy).any():
        overlay = np.zeros((*occupancy.shape, 4))
        overlay[moving & occupancy] = (0.85, 0.1, 0.1, 1.0)
        axes[0].imshow(overlay, extent=extent, interpolation="nearest")
    if flow is not None:
        rows, cols = np.nonzero(occupancy & (np.hypot(flow[0], flow[1]) > 1e-3))
        x = (grid.height - rows - 0.5) * grid.res
        y = (grid.width / 2 - cols - 0.5) * grid.res
        # A flow of +1 column moves towards smaller y; +1 row towards smaller x.
        axes[0].quiver(
            y,
            x,
            -flow[0, rows, cols] * grid.res * flow_scale,
            -flow[1, rows, cols] * grid.res * flow_scale,
            color="tab:blue",
            angles="xy",
            scale_units="xy",
            scale=1,
            width=0.004,
        )
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)
