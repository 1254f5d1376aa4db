"""Pretrained weights described in code (as torchvision does), and the presets that load them.

A :class:`WeightsRecord` names the files shipped in ``lidarflow/assets/``, their SHA-256, and
their meta: training data and command, size, and held-out results beside the best baseline
(``MODEL_CARD.md`` beside the weights is the short card; the history is in ``docs/model/``).

>>> from lidarflow.models.presets import BUNDLED, lidar_flownet   # doctest: +SKIP
>>> model = lidar_flownet(weights=BUNDLED)       # the bundled model, ready to stream
>>> untrained = lidar_flownet()                   # Table I's network, freshly initialised
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lidarflow.errors import ModelError
from lidarflow.models.config import FlowConfig, HeadConfig, ModelSpec
from lidarflow.models.weights import load_trained, sha256

if TYPE_CHECKING:  # the records and the ONNX file need no PyTorch; loading the weights does
    from lidarflow.models.recurrent import RecurrentMapModel

__all__ = [
    "BUNDLED",
    "WeightsRecord",
    "bundled_model_dir",
    "bundled_onnx",
    "is_bundled",
    "lidar_flownet",
    "resolve_model",
    "sha256",
]


@dataclass(frozen=True)
class WeightsRecord:
    """A shipped model: its folder inside the package, the checksum of its weights, and meta
    (``training_data``, ``command``, ``parameters``, ``heldout``: per development recording
    held out, ``(F1, changed-cell F1, margin over the best baseline)``)."""

    folder: str
    weights_sha256: str
    description: str
    meta: dict[str, Any] = field(default_factory=dict)
    #: The same model exported to ONNX (``model.onnx`` beside the weights), the core install's.
    onnx_sha256: str = ""

    def path(self) -> Path:
        return Path(str(resources.files("lidarflow") / self.folder))


BUNDLED = WeightsRecord(
    folder="assets/model",
    weights_sha256="62182f7c75731acd8b53bf0c3d9415a5eb3271584b6f6ebf0eb3f39caf7b45a6",
    # `lidarflow export -o src/lidarflow/assets/model/model.onnx` (the bundled model, its
    # decision policy marked in the file); tests/models/test_presets.py holds it to the weights
    onnx_sha256="1dcc4f5d5f63ebe1a9b5a6b25d7ef1d64c3d0facd9f4560ab6e4fec3d87a0b29",
    description=(
        "LiDAR-FlowNet's occupancy head without the flow network, v10: v9's head, trained by "
        "lidarflow's default recipe head_only, with a tracker's moved objects laid over its "
        "decided map (see MODEL_CARD.md)"
    ),
    meta={
        "version": "v10",
        "recipe": "head_only",
        "parameters": 194,
        "grid": {"height": 100, "width": 100, "res": 0.1},
        "training_data": [
            "positive_1.bag",
            "positive_2.bag",
            "positive_3.bag",
            "positive_4.bag",
            "demo_stationary_simple_environment.bag",
            "datmo_overtakes.bag",
            "general_tracking_moving_1.bag.zip",
        ],
        "command": (
            "lidarflow train ../shared/data/{positive_1,positive_2,positive_3,positive_4,"
            "demo_stationary_simple_environment,datmo_overtakes}.bag "
            "../shared/data/general_tracking_moving_1.bag.zip --recipe head_only --threads 1 "
            "-o runs/bundled_v9"
        ),
        "init": "v8",
        # Leave one recording out, one step ahead, online decision, against the three
        # baselines (docs/model/README.md, docs/research/peer_comparison).
        "heldout": {
            "positive_1": (0.9427, 0.2973, 0.0098),
            "positive_2": (0.9533, 0.3598, 0.0047),
            "positive_3": (0.9241, 0.2702, 0.0084),
            "positive_4": (0.9193, 0.1738, -0.0027),
            "demo_stationary_simple_environment": (0.8269, 0.2268, 0.0142),
            "datmo_overtakes": (0.6668, 0.6653, 0.2161),
            "general_tracking_moving_1": (0.7571, 0.7014, 0.0489),
        },
    },
)


def bundled_model_dir() -> Path:
    return BUNDLED.path()


def bundled_onnx() -> tuple[Path, dict[str, Any]]:
    """The bundled model's ONNX file (checked against its recorded checksum) and its
    ``model.json``: what runs the bundled model where PyTorch is not installed."""
    folder = bundled_model_dir()
    path = folder / "model.onnx"
    if not path.exists():
        raise ModelError(f"no bundled ONNX model in this installation ({path} is missing)")
    if BUNDLED.onnx_sha256 and sha256(path) != BUNDLED.onnx_sha256:
        raise ModelError(f"{path}: checksum differs from the record; the file is damaged")
    card = json.loads((folder / "model.json").read_text())
    return path, {**card, "weights_path": str(path)}


def lidar_flownet(
    weights: WeightsRecord | None = None, head: HeadConfig | None = None
) -> RecurrentMapModel:
    """LiDAR-FlowNet: with ``weights`` the shipped model they describe (checked against their
    checksum), else Table I's network freshly initialised, with ``head`` if given."""
    if weights is not None:
        return _load_folder(weights.path(), weights.weights_sha256)[0]
    from lidarflow.models import build

    return build(ModelSpec("flownet", FlowConfig(), head))


def _load_folder(folder: Path, checksum: str) -> tuple[RecurrentMapModel, dict[str, Any]]:
    weights = folder / "model.safetensors"
    if not weights.exists():
        raise ModelError(
            f"no bundled model in this installation ({weights} is missing); "
            "pass --model RUN_DIR or reinstall lidarflow"
        )
    if checksum and sha256(weights) != checksum:
        raise ModelError(f"{weights}: checksum differs from the record; the file is damaged")
    return load_trained(folder)


def is_bundled(source: str | Path | None) -> bool:
    """Whether ``source`` names the bundled model: ``None``, or the word ``bundled`` (unless a
    file of that name exists)."""
    return source is None or (str(source) == "bundled" and not Path(source).exists())


def resolve_model(source: str | Path | None) -> tuple[RecurrentMapModel, dict[str, Any]]:
    """Load ``source`` (run folder / weights file), or the bundled model (:func:`is_bundled`);
    the bundled weights are checked against their recorded checksum."""
    if not is_bundled(source):
        return load_trained(source)
    return _load_folder(bundled_model_dir(), BUNDLED.weights_sha256)
