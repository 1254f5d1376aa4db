"""Loading trained models: a run directory, or a ``.safetensors`` file with its JSON beside it.

A trained model is ``model.safetensors`` (weights) and ``model.json`` (``{"model": name,
"model_kwargs": {...}, "decision": {...}, "grid": {...}, ...}``), as ``lidarflow train`` writes
them. A weights file ``X.safetensors`` looks for ``X.json`` first, then ``model.json`` beside it.
Older files keep loading: parameter names from before the blocks are moved to theirs
(:func:`upgrade_state`), decision keys among the ``model_kwargs`` become the ``decision`` record.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lidarflow.errors import ModelError
from lidarflow.models.config import ModelSpec

if TYPE_CHECKING:  # reading records and checksums needs no PyTorch; loading weights does
    from lidarflow.models.recurrent import RecurrentMapModel

__all__ = [
    "MAX_DECISION_OFFSET",
    "check_decision_offset",
    "decision_record",
    "describe_source",
    "load_trained",
    "read_safetensors",
    "sha256",
    "upgrade_state",
]

#: LiDAR-FlowNet's parameter names before its blocks, and the blocks' names for them.
_BLOCK_NAMES = (
    ("conv0.", "flow.conv0."),
    ("grus.", "flow.grus."),
    ("conv_flow.", "flow.conv_flow."),
    ("conv_occupancy.", "head.out."),
    ("occupancy_hidden.", "head.hidden."),
    ("warp_gain", "head.gain"),
)
_WRAPPER = "inner."  # the ego-motion wrapper's prefix


def sha256(path: str | Path) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


#: safetensors' dtype names, as NumPy's (the ones lidarflow writes and a few more).
_SAFETENSORS_DTYPES = {"F64": "<f8", "F32": "<f4", "F16": "<f2", "I64": "<i8", "I32": "<i4"}


def read_safetensors(path: str | Path) -> dict[str, np.ndarray]:
    """A ``.safetensors`` file's tensors as NumPy arrays, read without PyTorch or the
    safetensors package (its format: an 8-byte little-endian header size, a JSON header of
    each tensor's dtype, shape and byte range, then the bytes). ``ValueError`` for a file that
    is not one, or a dtype NumPy has no name for here."""
    data = Path(path).read_bytes()
    try:
        size = int.from_bytes(data[:8], "little")
        header = json.loads(data[8 : 8 + size])
        out = {}
        for name, entry in header.items():
            if name == "__metadata__":
                continue
            begin, end = (8 + size + offset for offset in entry["data_offsets"])
            dtype = np.dtype(_SAFETENSORS_DTYPES[entry["dtype"]])
            array = np.frombuffer(data[begin:end], dtype).reshape(entry["shape"])
            out[name] = array.astype(dtype.newbyteorder("="))
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path}: not a safetensors file ({err!r})") from err
    return out


def upgrade_state(state: dict[str, Any]) -> dict[str, Any]:
    """A LiDAR-FlowNet state dict with its parameters under the blocks' names (``flow.``,
    ``head.``); names already there are kept."""
    out = {}
    for key, value in state.items():
        prefix = _WRAPPER if key.startswith(_WRAPPER) else ""
        name = key[len(prefix) :]
        for old, new in _BLOCK_NAMES:
            if name.startswith(old):
                name = new + name[len(old) :]
                break
        out[prefix + name] = value
    return out


#: The largest decision offset (added to the occupancy head's logit): beyond it the decided
#: probability is within 2e-9 of 0 or 1 whatever the model says.
MAX_DECISION_OFFSET = 20.0


def check_decision_offset(offset: Any, where: str) -> float:
    """``offset`` as a float within :data:`MAX_DECISION_OFFSET` of 0; else a :class:`ModelError`
    naming ``where`` (the file and key it came from)."""
    try:
        value = float(offset)
    except (TypeError, ValueError, OverflowError):  # not a number, or an int beyond a float
        value = math.nan
    if not (math.isfinite(value) and abs(value) <= MAX_DECISION_OFFSET):
        raise ModelError(
            f"{where}: the decision offset must be a number in [-{MAX_DECISION_OFFSET:g}, "
            f"{MAX_DECISION_OFFSET:g}], got {offset!r}"
        )
    return value


def decision_record(card: dict[str, Any], source: str | Path = "model.json") -> dict[str, Any]:
    """The decision a model was shipped with, ``{"offset": float, "online": bool, "movers":
    bool}``, from its ``decision`` record or older files' ``model_kwargs``; a bad offset is a
    :class:`ModelError` naming ``source`` (the file ``card`` came from) and the key."""
    if isinstance(card.get("decision"), dict):
        record, key = card["decision"], "decision.offset"
    else:
        kwargs = card.get("model_kwargs") or {}
        record = {"offset": kwargs.get("decision_offset", 0.0)}
        record["online"] = kwargs.get("online_decision", False)
        key = "model_kwargs.decision_offset"
    return {
        "offset": check_decision_offset(record.get("offset", 0.0), f"{source}: {key}"),
        "online": bool(record.get("online")),
        "movers": bool(record.get("movers")),
    }


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
            f"{path}: an ONNX model only runs (`lidarflow predict`, `evaluate`, `live`, `ros1`, "
            "Predictor); pass the run folder or .safetensors file it was exported from"
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
    """Rebuild and load a trained model; returns ``(model in eval mode, its model.json)``, the
    card's ``decision`` filled in (:func:`decision_record`)."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    from lidarflow.models import build

    path = Path(path)
    if not path.exists():
        raise ModelError(f"{path}: no such model file or folder")
    weights, card_path = _locate(path)
    try:
        card = json.loads(card_path.read_text())
        name = card["model"]
        kwargs = dict(card.get("model_kwargs") or {})
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise ModelError(f"{card_path}: not a lidarflow model description ({err})") from err
    try:
        spec, _ = ModelSpec.from_kwargs(name, kwargs, stored=True)
    except (TypeError, ValueError) as err:
        raise ModelError(f"{card_path}: {err}") from err
    decision = decision_record(card, card_path)  # before any weights are read
    model = build(spec)
    try:
        state = load_file(str(weights))
    except (SafetensorError, OSError) as err:
        raise ModelError(f"{weights}: unreadable weights ({err})") from err
    if spec.name == "flownet":
        state = upgrade_state(state)
    try:
        model.load_state_dict(state)
    except RuntimeError as err:
        first = str(err).strip().splitlines()[0]
        raise ModelError(f"{weights}: weights do not fit a {name} model ({first})") from err
    from lidarflow.models.finite import check_finite

    check_finite(model.state_dict(), weights)  # NaN weights load, run, break far from the cause
    model.eval()
    card = {
        **card,
        "decision": decision,
        "weights_path": str(weights),
        "weights_sha256": sha256(weights),
    }
    return model, card


def describe_source(path: str | Path) -> str:
    """A short method name for reports: the run folder's name, or the weights file's stem."""
    path = Path(path)
    if path.is_dir():
        return path.resolve().name
    if path.stem == "model":
        return path.resolve().parent.name
    return path.stem
