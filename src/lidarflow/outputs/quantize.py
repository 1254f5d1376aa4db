"""Int8 quantization of an exported step graph, for the CPU latency budget.

Static QDQ quantization (onnxruntime) turns the convolutions, most of a step, into int8 ones,
while the GRU gates, the warp and the occupancy head stay float32. Activation ranges are
calibrated by streaming real maps through the float graph, so that the recurrent state seen at
calibration is the one deployed. Speed and accuracy: docs/research/speed/.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.atomic import atomic_path
from lidarflow.errors import PredictError
from lidarflow.outputs.export import copy_marks
from lidarflow.predict.backends import split_step_inputs

__all__ = ["CALIBRATION_FEEDS", "data_dependent_convs", "head_convs", "quantize_onnx"]

#: Steps whose inputs calibrate the activation ranges (taken spread over the recording).
CALIBRATION_FEEDS = 120
#: Steps streamed before the first calibration feed, so that the state is built up.
WARMUP = 10


def calibration_feeds(
    session: object, maps: Sequence[np.ndarray], count: int = CALIBRATION_FEEDS
) -> list[dict[str, np.ndarray]]:
    """Stream ``maps`` (each ``(C, H, W)``, the graph's input channels) through the float
    ``session`` and keep the inputs of ``count`` steps spread evenly after the warm-up
    (ego-motion graphs get zero motion)."""
    inputs = session.get_inputs()  # type: ignore[attr-defined]
    motion_inputs, state_inputs = split_step_inputs(inputs)
    channels = int(inputs[0].shape[1])
    if len(maps) and np.shape(maps[0])[0] != channels:
        raise PredictError(
            f"calibration maps have {np.shape(maps[0])[0]} channels, the model takes {channels} "
            "(a subcell_input model also takes Recording.subcell_maps)"
        )
    state = [np.zeros(i.shape, np.float32) for i in state_inputs]
    usable = len(maps) - WARMUP
    if usable < 1:
        raise PredictError(
            f"calibration needs more than {WARMUP} frames, the recording has {len(maps)}"
        )
    keep = set(np.linspace(WARMUP, len(maps) - 1, min(count, usable)).round().astype(int))
    feeds: list[dict[str, np.ndarray]] = []
    for t, frame in enumerate(maps):
        feed = {"maps": np.asarray(frame, np.float32)[None]}
        feed.update({name: np.zeros((1, 3), np.float32) for name in motion_inputs})
        feed.update({i.name: s for i, s in zip(state_inputs, state, strict=True)})
        if t in keep:
            feeds.append(feed)
        state = session.run(None, feed)[2:]  # type: ignore[attr-defined]
    return feeds


def _graph(path: str | Path) -> Any:
    import onnx

    return onnx.load(str(path)).graph


def data_dependent_convs(path: str | Path) -> list[str]:
    """Names of the Conv nodes whose kernel is computed, not stored: the constant-velocity
    input's correlation and shift (:mod:`lidarflow.ops.shift`). They count cells and pick one
    shift; in int8 the counts would round and the wrong shift win, so they stay float."""
    graph = _graph(path)
    stored = {t.name for t in graph.initializer}
    stored |= {out for node in graph.node if node.op_type == "Constant" for out in node.output}
    return [
        node.name for node in graph.node if node.op_type == "Conv" and node.input[1] not in stored
    ]


#: The occupancy head block (``LidarFlowNet.head``: its ``hidden`` and ``out`` convolutions),
#: as its name appears in the exported graph's node names.
HEAD_MODULES = ("/head/hidden/", "/head/out/")


def head_convs(path: str | Path) -> list[str]:
    """Names of the occupancy head's Conv nodes. They stay float: the head is a per-cell 1 x 1
    layer, a tiny share of a step, whose output is the logit the decision thresholds, from
    inputs int8 would round (docs/research/speed/)."""
    return [
        node.name
        for node in _graph(path).node
        if node.op_type == "Conv" and any(m in node.name for m in HEAD_MODULES)
    ]


def quantize_onnx(float_path: str | Path, out_path: str | Path, maps: Sequence[np.ndarray]) -> Path:
    """Write an int8 (QDQ, per-channel weights) copy of the step graph at ``float_path`` to
    ``out_path`` (every Conv but :func:`data_dependent_convs` and :func:`head_convs`), its
    activation ranges calibrated on ``maps``, a recording's ``(C, H, W)`` input maps in order."""
    import onnxruntime as ort
    from onnxruntime.quantization import (
        CalibrationDataReader,
        QuantFormat,
        QuantType,
        quantize_static,
    )
    from onnxruntime.quantization.shape_inference import quant_pre_process

    out_path = Path(out_path)
    if not out_path.parent.exists():
        raise PredictError(f"{out_path.parent}: no such folder for the ONNX file")
    session = ort.InferenceSession(str(float_path), providers=["CPUExecutionProvider"])
    feeds = calibration_feeds(session, maps)

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.feeds: Iterator[dict[str, np.ndarray]] = iter(feeds)

        def get_next(self) -> dict[str, np.ndarray] | None:
            return next(self.feeds, None)

    with tempfile.TemporaryDirectory() as tmp, atomic_path(out_path) as written:
        prepared = Path(tmp) / "prepared.onnx"
        try:
            quant_pre_process(str(float_path), str(prepared))
            quantize_static(
                str(prepared),
                str(written),
                Reader(),
                quant_format=QuantFormat.QDQ,
                per_channel=True,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
                op_types_to_quantize=["Conv"],
                nodes_to_exclude=data_dependent_convs(prepared) + head_convs(prepared),
            )
        except Exception as err:  # onnxruntime's tools raise many types
            raise PredictError(f"int8 quantization failed: {type(err).__name__}: {err}") from err
        copy_marks(float_path, written)
    return out_path
