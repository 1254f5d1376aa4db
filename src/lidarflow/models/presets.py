"""Pretrained weights described in code (as torchvision does): the bundled default model.

The record names the files shipped in ``lidarflow/assets/model/``, their SHA-256, and where
the numbers about them live (the model card, ``MODEL_CARD.md`` beside the weights).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from lidarflow.errors import ModelError
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.models.weights import load_trained, sha256

__all__ = ["BUNDLED", "WeightsRecord", "bundled_model_dir", "resolve_model"]


@dataclass(frozen=True)
class WeightsRecord:
    """A shipped model: its folder inside the package and the checksum of its weights."""

    folder: str
    weights_sha256: str
    description: str

    def path(self) -> Path:
        return Path(str(resources.files("lidarflow") / self.folder))


BUNDLED = WeightsRecord(
    folder="assets/model",
    weights_sha256="2cdec0acd8fecfdecdfbcf6755848eefd52b10e2d847d4d46b9a9dfcd2aeddca",
    description="LiDAR-FlowNet trained by lidarflow's default recipe (see MODEL_CARD.md)",
)


def bundled_model_dir() -> Path:
    return BUNDLED.path()


def resolve_model(source: str | Path | None) -> tuple[RecurrentMapModel, dict[str, Any]]:
    """Load ``source`` (run folder / weights file), or the bundled model when ``None`` or the
    word ``bundled`` (unless a file of that name exists); the bundled weights are checked
    against their recorded checksum."""
    if source is not None and not (str(source) == "bundled" and not Path(source).exists()):
        return load_trained(source)
    folder = bundled_model_dir()
    weights = folder / "model.safetensors"
    if not weights.exists():
        raise ModelError(
            f"no bundled model in this installation ({weights} is missing); "
            "pass --model RUN_DIR or reinstall lidarflow"
        )
    if BUNDLED.weights_sha256 and sha256(weights) != BUNDLED.weights_sha256:
        raise ModelError(f"{weights}: checksum differs from the record; the file is damaged")
    return load_trained(folder)
