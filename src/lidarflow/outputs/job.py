"""``lidarflow predict``: a recording in, a bag out with the input and the predictions.

The ``topics`` groups (:data:`TOPIC_GROUPS`, :data:`DEFAULT_TOPICS`) and what each writes are in
docs/guide/outputs.md. Grids are :func:`lidarflow.outputs.grids.prediction_grids`'; the flow is
``32FC2`` images rounded to :data:`FLOW_QUANTUM_CELLS` beside their ``rgb8`` colour wheels.
Every prediction is logged at its scan's log time (in the input bag; the scan's stamp for a
recording file), so that a reader meets it right after its scan. Where the bag's header clock
went back (:mod:`lidarflow.data.sessions`), headers get the bag's own stamps back.
"""

from __future__ import annotations

import contextlib
import dataclasses
import heapq
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data.recording import Recording
from lidarflow.data.sessions import recorded_stamps
from lidarflow.errors import PredictError
from lidarflow.outputs.grids import (
    FLOW_RGB_FULL_CELLS,
    TOPIC_PREFIX,
    OutGrid,
    grid_topics,
    prediction_grids,
)
from lidarflow.outputs.rosout import BagOutput
from lidarflow.predict.predictor import Prediction, Predictor

__all__ = [
    "DEFAULT_TOPICS",
    "FLOW_QUANTUM_CELLS",
    "TOPIC_GROUPS",
    "TOPIC_PREFIX",
    "check_poses",
    "predict_to_bag",
]

#: What ``topics`` may name (see the module).
TOPIC_GROUPS = ("input", "occupancy", "predicted", "decided", "moving", "flow", "planner_grid")
#: Every group but the flow (two float images per scan: most of an output, docs/guide/outputs.md)
#: and the planner grid, which is for robots that ask.
DEFAULT_TOPICS = frozenset(TOPIC_GROUPS) - {"flow", "planner_grid"}
#: The flow images' values are rounded to this (cells), far below what the flow is good for,
#: so that they compress (their float noise bits do not).
FLOW_QUANTUM_CELLS = 1 / 1024


def check_poses(recording: Recording, predictor: Predictor) -> None:
    """Refuse (:class:`PredictError`) to run an ego-motion model over a recording without
    sensor poses, unless the model may run without (``poses_optional``: the Predictor then
    matches the motion from the scans)."""
    if predictor.uses_motion and not recording.has_poses and not predictor.poses_optional:
        source = recording.meta.get("source") or "the recording"
        raise PredictError(
            f"{source}: no sensor poses, but the model compensates ego motion; convert the bag "
            "with --odom-topic, or use a model trained without --ego-motion"
        )


def predict_to_bag(
    recording: Recording,
    predictor: Predictor,
    output: str | Path,
    progress: Callable[[int], None] | None = None,
    force: bool = False,
    topics: Iterable[str] = DEFAULT_TOPICS,
    source: str | Path | None = None,
) -> dict[str, int]:
    """Run ``predictor`` over ``recording`` and write the ``topics`` groups to ``output``;
    returns the number of messages per topic. ``source``: the bag ``recording`` was read from,
    whose messages the ``input`` group copies (``None``: a recording file, whose scans are
    written instead). Raises :class:`PredictError` as :func:`check_poses` does, and where
    ``output`` exists unless ``force``."""
    groups = frozenset(topics)
    if unknown := sorted(groups - set(TOPIC_GROUPS)):
        raise PredictError(f"unknown topic group {unknown[0]!r}; choose from {TOPIC_GROUPS}")
    check_poses(recording, predictor)
    # headers: the bag's own stamps (see the module); log times: the scans' in the input
    stamps = recorded_stamps(recording.stamps_ns, recording.meta.get("clock_jumps") or [])
    counts: Counter[str] = Counter()
    with contextlib.ExitStack() as stack:
        reader = None
        if source is not None:
            from lidarflow.data.bagfile import open_bag

            reader = stack.enter_context(open_bag(source))
        out = stack.enter_context(BagOutput(output, force))
        log_times = np.asarray(recording.stamps_ns, dtype=np.int64)
        copies: Iterator[tuple[int, Any, Any]] = iter(())
        if reader is not None:
            from lidarflow.outputs.inputcopy import copied_messages, scan_log_times

            topic = recording.meta.get("topic") or ""
            by_header = str(recording.meta.get("stamps", "header")) == "header"
            if by_header:  # else the recording's stamps are the log times already
                log_times = scan_log_times(reader, topic, stamps, log_times)
            if "input" in groups:
                copies = copied_messages(
                    reader, out, lambda t: not t.startswith(f"{TOPIC_PREFIX}/")
                )
        write_scans = "input" in groups and reader is None
        frames = _frames(
            recording, predictor, out, groups, stamps, log_times, write_scans, progress
        )
        items = heapq.merge(_copy_writes(out, copies), frames, key=lambda item: item[0])
        for _, write in items:
            counts.update(write())
    return dict(counts)


Write = Callable[[], list[str]]  # writes a message or a frame's; returns the topics written


def _copy_writes(out: BagOutput, copies: Iterator[tuple[int, Any, Any]]) -> Iterator[Any]:
    for log_time, connection, data in copies:

        def write(c: Any = connection, t: int = log_time, d: Any = data) -> list[str]:
            out.write_raw(c, t, d)
            return [c.topic]

        yield log_time, write


def _frames(
    recording: Recording,
    predictor: Predictor,
    out: BagOutput,
    groups: frozenset[str],
    stamps: np.ndarray,
    log_times: np.ndarray,
    write_scans: bool,
    progress: Callable[[int], None] | None,
) -> Iterator[tuple[int, Write]]:
    """``(log time, write)`` per scan: its prediction, made when asked for, in scan order;
    with the scan itself where ``write_scans`` (a recording file's, not copied from a bag)."""
    from lidarflow.outputs.inputcopy import output_topic

    poses = recording.poses
    scan_topic = output_topic(recording.meta.get("topic") or "/scan", out.ros1)
    frame_id = recording.meta.get("frame_id") or "laser"
    predictor.reset()
    for i, scan in enumerate(recording):
        p = predictor.update(scan, None if poses is None else poses[i])
        stamp, at = int(stamps[i]), int(log_times[i])

        def write(p: Prediction = p, i: int = i, stamp: int = stamp, at: int = at) -> list[str]:
            written = []
            if write_scans:
                scan = dataclasses.replace(recording.scan(i), stamp_ns=stamp)
                out.write_scan(scan_topic, scan, frame_id, at, seq=i)
                written.append(scan_topic)
            written += _write_prediction(out, p, groups, predictor, stamp, at, frame_id)
            if progress is not None:
                progress(1)
            return written

        yield at, write


def _group(topic: str) -> str:
    """The group of a grid's topic: ``/lidarflow/predicted_k2`` is ``predicted``."""
    return topic.removeprefix(f"{TOPIC_PREFIX}/").split("_k")[0]


def _write_prediction(
    out: BagOutput,
    p: Prediction,
    groups: frozenset[str],
    predictor: Predictor,
    stamp: int,
    at: int,
    frame_id: str,
) -> list[str]:
    """Write one scan's prediction ``p`` (the scan stamped ``stamp`` in the bag, logged at
    ``at``); returns the topics written."""
    ahead = stamp - p.stamp_ns  # the bag's stamp minus the re-stamped one the predictor saw
    wanted = {t for t in grid_topics(len(p.horizon), planner=True) if _group(t) in groups}
    grids = prediction_grids(p, wanted)
    for g in grids:  # on the bag's clock
        g = OutGrid(g.topic, g.data, g.stamp_ns + ahead, g.scan_stamp_ns + ahead)
        out.write_grid_data(g, predictor.grid, frame_id, log_time_ns=at)
    written = [g.topic for g in grids]
    if "flow" in groups and p.backward_flow is not None and p.forward_flow is not None:
        from lidarflow.flowcolor import flow_to_rgb

        for name, flow in (("backward", p.backward_flow), ("forward", p.forward_flow)):
            topic = f"{TOPIC_PREFIX}/flow_{name}"
            rounded = np.round(flow / FLOW_QUANTUM_CELLS) * FLOW_QUANTUM_CELLS
            out.write_flow(topic, rounded, stamp, frame_id, at)
            picture = flow_to_rgb(rounded, FLOW_RGB_FULL_CELLS)  # the picture of the image
            out.write_rgb(f"{topic}_rgb", picture, stamp, frame_id, at)
            written += [topic, f"{topic}_rgb"]
    return written
