"""lidarflow: 2-D LiDAR map prediction by estimating motion flow (LiDAR-FlowNet)."""

from lidarflow.errors import LidarflowError
from lidarflow.scan import BeamGeometry, GridSpec, Scan, rasterize, rasterize_batch

__version__ = "0.1.0"

__all__ = ["BeamGeometry", "GridSpec", "LidarflowError", "Scan", "rasterize", "rasterize_batch"]
