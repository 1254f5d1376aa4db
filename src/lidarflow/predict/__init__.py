"""The runtime a robot imports: the streaming Predictor and the per-frame engine behind it
(files it writes are :mod:`lidarflow.outputs`'s)."""

from lidarflow.predict.predictor import Prediction, Predictor

__all__ = ["Prediction", "Predictor"]
