"""Pictures of occupancy and visibility maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidarflow.geometry import cell_to_metric
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
        x, y = cell_to_metric(rows, cols, grid.height, grid.width, grid.res)
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
    _legends(axes, moving is not None and bool((moving & occupancy).any()), flow is not None)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def _legends(axes: object, moving: bool, flow: bool) -> None:
    """What each colour of the two panels means (and the overlays drawn on the first)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    def cell(colour: str, label: str) -> Patch:
        return Patch(facecolor=colour, edgecolor="0.5", label=label)

    sensor = Line2D([], [], marker="^", color="tab:red", linestyle="", label="sensor")
    first = [cell("black", "occupied"), cell("white", "free or unseen"), sensor]
    if moving:
        first.append(cell((0.85, 0.1, 0.1), "moving"))
    if flow:
        first.append(Line2D([], [], color="tab:blue", label="flow to the next frame"))
    second = [cell("black", "seen"), cell("white", "unseen (behind a return, out of range)")]
    for ax, handles in zip(axes, (first, second), strict=True):
        ax.legend(handles=handles, loc="upper left", fontsize="small", framealpha=0.85)
