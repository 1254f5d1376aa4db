"""Training: config dataclasses (the paper's recipe by default), data mixing and splits, the
loop, checkpoints and torchrun support. Entry point: :func:`lidarflow.train.loop.train`."""

from lidarflow.train.config import TrainConfig
from lidarflow.train.config_io import build_config
from lidarflow.train.loop import TrainResult, train
from lidarflow.train.recipes import RECIPES, recipe

__all__ = ["RECIPES", "TrainConfig", "TrainResult", "build_config", "recipe", "train"]
