"""Deployment: the streaming Predictor, bag/MCAP output, ONNX export."""

from lidarflow.predict.predictor import Prediction, Predictor

__all__ = ["Prediction", "Predictor"]
