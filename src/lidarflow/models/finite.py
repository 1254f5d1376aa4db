"""Weights checked finite when a model loads: a NaN or infinite weight loads and runs, then
breaks far from its cause (an IndexError in the decision, a NaN ONNX file exported with exit 0),
so loading refuses it in one line naming the tensor."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lidarflow.errors import ModelError

__all__ = ["check_finite", "check_finite_onnx"]


def check_finite(tensors: Mapping[str, Any], source: str | Path) -> None:
    """Raise :class:`ModelError` where a floating-point tensor (torch or NumPy) of ``tensors``
    holds NaN or infinity: such a model loads and runs, and breaks far from the cause."""
    import numpy as np
    import torch

    bad = []
    for name, value in tensors.items():
        array = value.detach().float().cpu().numpy() if isinstance(value, torch.Tensor) else value
        array = np.asarray(array)
        if np.issubdtype(array.dtype, np.floating) and not np.isfinite(array).all():
            bad.append(name)
    if bad:
        more = f" and {len(bad) - 3} more" if len(bad) > 3 else ""
        raise ModelError(
            f"{source}: weights are not finite (NaN or inf in {', '.join(bad[:3])}{more}); "
            "the file is damaged or its training diverged: use an earlier checkpoint or retrain"
        )


def check_finite_onnx(path: str | Path) -> None:
    """:func:`check_finite` on the initializers (weights) of the ONNX file ``path``."""
    import onnx
    from onnx import numpy_helper

    try:
        graph = onnx.load(str(path), load_external_data=False).graph
    except Exception as err:  # onnx raises its own (protobuf) errors
        raise ModelError(f"{path}: not a loadable ONNX model ({err})") from err
    check_finite({i.name: numpy_helper.to_array(i) for i in graph.initializer}, path)
