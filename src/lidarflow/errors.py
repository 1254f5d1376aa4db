"""One exception type per layer, all under :class:`LidarflowError`, raised ``from`` the cause;
the CLI prints one line: what failed, which file or topic, and what to do."""

from __future__ import annotations


class LidarflowError(Exception):
    """Base class of every error lidarflow raises on purpose."""


class ScanError(LidarflowError):
    """A scan or grid specification is malformed (wrong shape, bad geometry)."""


class BagError(LidarflowError):
    """A bag/MCAP file cannot be opened or read, or the requested topic is not there."""


class RecordingError(LidarflowError):
    """A recording file is missing, corrupt, or too short for what was asked."""


class SimError(LidarflowError):
    """The simulator was configured with impossible parameters."""


class ModelError(LidarflowError):
    """A model or its weights cannot be built or loaded."""


class TrainError(LidarflowError):
    """Training failed (bad configuration, NaN loss, unusable checkpoint)."""


class EvaluateError(LidarflowError):
    """Evaluation failed (no frames to evaluate, mismatched grids)."""


class PredictError(LidarflowError):
    """Prediction, export or writing of predictions failed."""


class OutputError(LidarflowError):
    """An output cannot be written: it exists already (and overwriting was not asked for)."""
