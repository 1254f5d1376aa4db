"""Loading trained models: a run directory, or a ``.safetensors`` file with its JSON beside it.

A trained model is two files written by ``lidarflow train``: ``model.safetensors`` (weights)
and ``model.json`` (``{"model": name, "model_kwargs": {...}, "grid": {...}, ...}``: enough to
rebuild the net, and where it came from). A weights file ``X.safetensors`` looks for ``X.json``
first, then ``model.json`` in its folder.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from lidarflow.errors import ModelError
from lidarflow.models.recurrent import RecurrentMapModel

__all__ = ["describe_source", "load_trained", "sha256"]


def sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _locate(path: Path) -> tuple[Path, Path]:
    if path.is_dir():
        weights, card = path / "model.safetensors", path / "model.json"
    elif path.suffix == ".safetensors":
        weights = path
        card = path.with_suffix(".json")
        if not card.exists():
            card = path.parent / "model.json"
    elif path.suffix == ".json":
        card = path
        weights = path.parent / "model.safetensors"
    elif path.suffix.lower() == ".onnx":  # exported, so its PyTorch source exists somewhere
        raise ModelError(
            f"{path}: an ONNX model runs only in `lidarflow predict` (and Predictor); pass the "
            "run folder or .safetensors file it was exported from"
        )
    else:
        raise ModelError(f"{path}: expected a run folder, a .safetensors file or a model.json")
    for needed in (weights, card):
        if not needed.exists():
            raise ModelError(
                f"{path}: {needed.name} not found; pass the folder `lidarflow train -o` wrote, "
                "or a weights file with its JSON beside it"
            )
    return weights, card


def load_trained(path: str | Path) -> tuple[RecurrentMapModel, dict[str, Any]]:
    """Rebuild and load a trained model; returns ``(model in eval mode, its model.json)``."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    from lidarflow.models import build_model

    path = Path(path)
    if not path.exists():
        raise ModelError(f"{path}: no such model file or folder")
    weights, card_path = _locate(path)
    try:
        card = json.loads(card_path.read_text())
        name = card["model"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as err:
        raise ModelError(f"{card_path}: not a lidarflow model description ({err})") from err
    model = build_model(name, **dict(card.get("model_kwargs") or {}))
    try:
        state = load_file(str(weights))
    except (SafetensorError, OSError) as err:
        raise ModelError(f"{weights}: unreadable weights ({err})") from err
    try:
        model.load_state_dict(state)
    except RuntimeError as err:
        first = str(err).strip().splitlines()[0]
        raise ModelError(f"{weights}: weights do not fit a {name} model ({first})") from err
    from lidarflow.models.finite import check_finite

    check_finite(model.state_dict(), weights)  # NaN weights load, run, break far from the cause
    model.eval()
    card = {**card, "weights_path": str(weights), "weights_sha256": sha256(weights)}
    return model, card


def describe_source(path: str | Path) -> str:
    """A short method name for reports: the run folder's name, or the weights file's stem."""
    path = Path(path)
    if path.is_dir():
        return path.resolve().name
    if path.stem == "model":
        return path.resolve().parent.name
    return path.stem
