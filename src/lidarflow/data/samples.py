"""The sample recording bundled with the package (licence notice beside it in ``assets/``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["SAMPLE_TOPIC", "sample_bag_path"]

SAMPLE_TOPIC = "right_scan"


def sample_bag_path() -> Path:
    """Path of the bundled ROS 1 bag (``positive_2`` of the leg_tracker benchmarks)."""
    return Path(str(resources.files("lidarflow") / "assets" / "sample_positive_2.bag"))
