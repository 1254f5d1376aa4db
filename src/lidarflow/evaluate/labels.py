"""Labelled movers: positions people labelled in a recording's scans, and how much of them a
prediction covers. Label files are bags: leg_tracker's extracted bags, each labelled scan given
to the frame with exactly its ranges, or bags of ``/ground_truth_people_tracks``, each
annotation given to the frame nearest its log time less one scan period
(``docs/research/movers``). Definitions: ``docs/guide/conventions.md``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.baselines import Method
from lidarflow.data.bagfile import open_bag
from lidarflow.data.blocks import Frames
from lidarflow.data.recording import Recording
from lidarflow.errors import BagError, EvaluateError
from lidarflow.evaluate.metrics import THRESHOLD, summed
from lidarflow.evaluate.resampling import paired_interval
from lidarflow.evaluate.runner import Hooks
from lidarflow.scan import GridSpec, cell_centres

__all__ = [
    "CEILING",
    "LEGS_TOPIC",
    "PEOPLE_TOPIC",
    "RADIUS",
    "SCANS_TOPIC",
    "LabelCounts",
    "LabelScore",
    "Labels",
    "frames_by_ranges",
    "frames_by_stamps",
    "label_counts",
    "labels_entry",
    "read_labels",
    "with_labels",
]

#: How near (metres) an occupied cell's centre and a label must lie to count for each other:
#: about a leg's (a person's) radius plus half a cell.
RADIUS = 0.3
LEGS_TOPIC = "/leg_cluster_positions"
SCANS_TOPIC = "/training_scan"
PEOPLE_TOPIC = "/ground_truth_people_tracks"
#: The row of the scan itself (``O^{t+k}`` taken as the prediction): recall's ceiling.
CEILING = "scan"


@dataclass(frozen=True)
class Labels:
    """A label file read against a recording: ``positions``, frame index -> ``(N, 2)`` metres
    (a frame labelled empty holds ``(0, 2)``); ``kind``, ``"legs"`` or ``"people"``;
    ``unmatched``, the labelled scans (annotations) given to no frame of the recording."""

    positions: dict[int, np.ndarray]
    kind: str
    unmatched: int = 0


def read_labels(path: str | Path, recording: Recording) -> Labels:
    """The labels of the bag at ``path`` given to the frames of ``recording``. Raises
    :class:`~lidarflow.errors.EvaluateError` for a file holding neither kind of label or
    fitting no frame, :class:`~lidarflow.errors.BagError` for one that is no readable bag."""
    path = Path(path)
    with open_bag(path) as reader:
        topics = {c.topic for c in reader.connections}
        try:
            if {LEGS_TOPIC, SCANS_TOPIC} <= topics:
                labels = _read_legs(reader, path, recording)
            elif PEOPLE_TOPIC in topics:
                labels = _read_people(reader, recording)
            else:
                raise EvaluateError(
                    f"{path}: no labels: expected {SCANS_TOPIC} and {LEGS_TOPIC} (leg_tracker's "
                    f"extracted bags) or {PEOPLE_TOPIC}; it has {', '.join(sorted(topics))}"
                )
        except (EvaluateError, BagError):
            raise
        except Exception as err:  # rosbags raises many types for damaged messages
            raise BagError(f"{path}: cannot read its labels ({type(err).__name__}: {err})") from err
    if not labels.positions:
        raise EvaluateError(
            f"{path}: none of its {labels.unmatched} labelled scans is a scan of the recording "
            "evaluated: give the label file of this recording"
        )
    return labels


def _read_legs(reader: Any, path: Path, recording: Recording) -> Labels:
    wanted = [c for c in reader.connections if c.topic in (LEGS_TOPIC, SCANS_TOPIC)]
    scans: list[tuple[int, np.ndarray]] = []
    legs: list[tuple[int, np.ndarray]] = []
    for conn, log_time, raw in reader.messages(connections=wanted):
        msg = reader.deserialize(raw, conn.msgtype)
        if conn.topic == SCANS_TOPIC:
            scans.append((int(log_time), np.asarray(msg.ranges, np.float32)))
        else:
            xy = [(p.position.x, p.position.y) for p in msg.poses]
            legs.append((int(log_time), np.array(xy, np.float64).reshape(-1, 2)))
    _check_pairs(path, [t for t, _ in scans], [t for t, _ in legs])
    frames = frames_by_ranges([r for _, r in sorted(scans, key=itemgetter(0))], recording)
    ordered = [xy for _, xy in sorted(legs, key=itemgetter(0))]
    positions = {f: xy for f, xy in zip(frames, ordered, strict=True) if f is not None}
    return Labels(positions, "legs", sum(f is None for f in frames))


def _check_pairs(path: Path, scan_times: list[int], leg_times: list[int]) -> None:
    """Refuse scans and leg arrays that are not logged in pairs: as many of each, the
    ``i``-th of each before the ``i + 1``-th of either."""
    if len(scan_times) != len(leg_times):
        raise EvaluateError(
            f"{path}: {len(scan_times)} messages on {SCANS_TOPIC} but {len(leg_times)} on "
            f"{LEGS_TOPIC}: the labels cannot be paired with their scans"
        )
    scans, legs = np.sort(scan_times), np.sort(leg_times)
    if len(scans) > 1 and np.any(np.maximum(scans, legs)[:-1] >= np.minimum(scans, legs)[1:]):
        raise EvaluateError(
            f"{path}: {SCANS_TOPIC} and {LEGS_TOPIC} are not logged in pairs: the labels "
            "cannot be paired with their scans"
        )


def frames_by_ranges(scans: list[np.ndarray], recording: Recording) -> list[int | None]:
    """The frame of ``recording`` whose ranges equal each of ``scans`` bit for bit (float32),
    ``None`` where none does; of several, the first after the previous scan's, else the
    first."""
    frames: dict[bytes, list[int]] = {}
    ranges, offsets = recording.ranges.astype(np.float32, copy=False), recording.offsets
    for i in range(len(recording)):
        frames.setdefault(ranges[offsets[i] : offsets[i + 1]].tobytes(), []).append(i)
    out: list[int | None] = []
    last = -1
    for scan in scans:
        found = frames.get(np.asarray(scan, np.float32).tobytes())
        if found is None:
            out.append(None)
            continue
        later = [f for f in found if f > last]
        out.append(later[0] if later else found[0])
        last = out[-1] if out[-1] is not None else last
    return out


def _read_people(reader: Any, recording: Recording) -> Labels:
    connections = [c for c in reader.connections if c.topic == PEOPLE_TOPIC]
    stamps: list[int] = []
    xy: list[tuple[float, float]] = []
    for conn, log_time, raw in reader.messages(connections=connections):
        position = reader.deserialize(raw, conn.msgtype).pose.position
        stamps.append(int(log_time))
        xy.append((position.x, position.y))
    period = int(np.median(np.diff(recording.stamps_ns))) if len(recording) > 1 else 0
    frames = frames_by_stamps(np.array(stamps, np.int64), recording.stamps_ns, period)
    points = np.array(xy, np.float64).reshape(-1, 2)
    positions = {int(f): points[frames == f] for f in np.unique(frames[frames >= 0])}
    return Labels(positions, "people", int((frames < 0).sum()))


def frames_by_stamps(stamps_ns: np.ndarray, scan_stamps_ns: np.ndarray, lag_ns: int) -> np.ndarray:
    """The frame of each annotation: the scan (``scan_stamps_ns`` ascending) whose stamp is
    nearest the annotation's less ``lag_ns``; -1 where that scan is further than ``lag_ns``.

    >>> frames_by_stamps(np.array([100, 210, 260, 900]), np.array([0, 100, 200]), 100).tolist()
    [0, 1, 2, -1]
    """
    scans = np.asarray(scan_stamps_ns, np.int64)
    wanted = np.asarray(stamps_ns, np.int64) - int(lag_ns)
    if not len(scans):
        return np.full(len(wanted), -1, np.int64)
    after = np.clip(np.searchsorted(scans, wanted), 0, len(scans) - 1)
    before = np.clip(after - 1, 0, len(scans) - 1)
    nearer = np.where(np.abs(scans[after] - wanted) < np.abs(scans[before] - wanted), after, before)
    far = np.abs(scans[nearer] - wanted) > max(int(lag_ns), 0)
    return np.where(far, -1, nearer).astype(np.int64)


@dataclass
class LabelCounts:
    """Labels ``found`` of those ``labelled`` (recall), occupied cells of the region ``near`` a
    label of those ``predicted`` there (precision), over ``frames`` frames."""

    found: int = 0
    labelled: int = 0
    near: int = 0
    predicted: int = 0
    frames: int = 0

    def __add__(self, other: LabelCounts) -> LabelCounts:
        return summed(self, other)

    @property
    def recall(self) -> float | None:
        return self.found / self.labelled if self.labelled else None

    @property
    def precision(self) -> float | None:
        return self.near / self.predicted if self.predicted else None

    def row(self) -> tuple[int, int, int, int]:
        """``(found, labelled, near, predicted)``: a frame's counts as the intervals take them."""
        return self.found, self.labelled, self.near, self.predicted


def label_counts(
    decided: np.ndarray,
    labels_xy: np.ndarray,
    region: np.ndarray,
    grid: GridSpec,
    radius: float = RADIUS,
) -> LabelCounts:
    """One labelled frame: of the labels ``labels_xy`` (``(N, 2)`` metres, sensor frame) inside
    ``grid``, those within ``radius`` of a cell of ``decided`` ``(H, W)`` bool; of
    ``decided``'s cells inside ``region``, those within ``radius`` of any label.

    >>> grid = GridSpec(4, 4, 1.0)
    >>> decided = np.zeros((4, 4), bool); decided[0, 0] = decided[3, 3] = True
    >>> label_counts(decided, np.array([[3.6, 1.4], [0.5, 0.5]]), np.ones((4, 4), bool), grid)
    LabelCounts(found=1, labelled=2, near=1, predicted=2, frames=1)
    """
    decided, region = np.asarray(decided, bool), np.asarray(region, bool)
    if decided.shape != grid.shape or region.shape != grid.shape:
        raise ValueError(
            f"decided and region must be {grid.shape} (the grid), got {decided.shape} and "
            f"{region.shape}"
        )
    xy = np.asarray(labels_xy, np.float64).reshape(-1, 2)
    x, y = _centres(grid)
    cells = np.stack([x[decided], y[decided]], axis=1)  # (C, 2)
    inside_region = region[decided]
    near = np.hypot(*(cells[None, :, :] - xy[:, None, :]).transpose(2, 0, 1)) <= radius  # (N, C)
    inside = _inside(xy, grid)
    return LabelCounts(
        found=int(near[inside].any(axis=1).sum()),
        labelled=int(inside.sum()),
        near=int((near.any(axis=0) & inside_region).sum()),
        predicted=int(inside_region.sum()),
        frames=1,
    )


@functools.lru_cache(maxsize=8)
def _centres(grid: GridSpec) -> tuple[np.ndarray, np.ndarray]:
    return cell_centres(grid)


def _inside(xy: np.ndarray, grid: GridSpec) -> np.ndarray:
    half = grid.width / 2 * grid.res
    return (
        (xy[:, 0] >= 0)
        & (xy[:, 0] < grid.height * grid.res)
        & (-half <= xy[:, 1])
        & (xy[:, 1] < half)
    )


@dataclass
class LabelScore:
    """Every method's :class:`LabelCounts` per step ``k`` (1..``horizon``) on the labelled
    frames ``positions``, precision inside ``region`` (``t ->`` frame ``t``'s region)."""

    positions: Mapping[int, np.ndarray]
    grid: GridSpec
    horizon: int
    region: Callable[[int], np.ndarray]
    # each labelled frame's counts, per method and step: {t: counts}
    frames: dict[str, list[dict[int, LabelCounts]]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.region = functools.lru_cache(maxsize=self.horizon + 1)(self.region)

    def add(self, method: str, t: int, predicted: np.ndarray) -> None:
        """Score ``method``'s outputs ``(K, H, W)`` (or one ``(H, W)``) made after frame ``t``
        against frame ``t + k``'s labels, where it has some."""
        predicted = np.asarray(predicted).reshape(-1, *self.grid.shape)
        frames = self.frames.setdefault(method, [{} for _ in range(self.horizon)])
        for k, output in enumerate(predicted[: self.horizon]):
            labels = self.positions.get(t + 1 + k)
            if labels is not None:
                region = self.region(t + 1 + k)
                frames[k][t] = label_counts(output >= THRESHOLD, labels, region, self.grid)

    @property
    def counts(self) -> dict[str, list[LabelCounts]]:
        """Every method's counts per step, summed over its labelled frames."""
        return {
            method: [sum(per_frame.values(), LabelCounts()) for per_frame in frames]
            for method, frames in self.frames.items()
        }

    def intervals(self, baseline: str = "copy_last") -> dict[str, dict[str, list[Any]]]:
        """Each other method's recall over ``baseline``'s (a ratio) and precision less its,
        their :func:`~lidarflow.evaluate.resampling.paired_interval` over the labelled frames
        both scored, per step: ``{method: {"recall_ratio": [[low, high] | None, ...],
        "precision_margin": [...]}}``; ``{}`` without the baseline."""
        if baseline not in self.frames:
            return {}
        out = {}
        for method, frames in self.frames.items():
            if method not in (baseline, CEILING):
                pairs = [
                    _paired_rows(a, b) for a, b in zip(frames, self.frames[baseline], strict=True)
                ]
                out[method] = {
                    name: [None if (i := paired_interval(*pair, compare)) is None else list(i)
                           for pair in pairs]
                    for name, compare in _COMPARED.items()
                }  # fmt: skip
        return out

    def summary(self) -> dict[str, dict[str, list[Any]]]:
        """``{method: {"recall": [k = 1..K], "precision", "labelled", "frames"}}``."""
        return {
            method: {
                "recall": [c.recall for c in counts],
                "precision": [c.precision for c in counts],
                "labelled": [c.labelled for c in counts],
                "frames": [c.frames for c in counts],
            }
            for method, counts in self.counts.items()
        }


def _paired_rows(
    mine: Mapping[int, LabelCounts], theirs: Mapping[int, LabelCounts]
) -> tuple[np.ndarray, np.ndarray]:
    """Both methods' :meth:`LabelCounts.row` ``(F, 4)`` on the frames both scored, in time
    order."""
    common = sorted(mine.keys() & theirs.keys())
    rows = [np.array([one[t].row() for t in common]).reshape(-1, 4) for one in (mine, theirs)]
    return rows[0], rows[1]


def _recall_ratio(mine: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    """Per draw: recall (found / labelled) over the baseline's; NaN where it found none."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (mine[:, 0] / mine[:, 1]) / (theirs[:, 0] / theirs[:, 1])
    return np.where(np.isfinite(ratio), ratio, np.nan)


def _precision_margin(mine: np.ndarray, theirs: np.ndarray) -> np.ndarray:
    """Per draw: precision (near / predicted) less the baseline's; NaN where either predicted
    nothing in the region."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return mine[:, 2] / mine[:, 3] - theirs[:, 2] / theirs[:, 3]


_COMPARED = {"recall_ratio": _recall_ratio, "precision_margin": _precision_margin}


def with_labels(
    hooks: Hooks, score: LabelScore, methods: Sequence[Method], occupancy: Frames
) -> Hooks:
    """``hooks`` that also hand ``score`` every prediction scored ahead (the main table's for
    ``score.horizon`` 1), oracles left out, and with copy-last's the scan itself as
    :data:`CEILING`."""
    oracles = {m.name for m in methods if getattr(m, "oracle", False)}
    horizon = score.horizon

    def add(method: str, t: int, predicted: np.ndarray) -> None:
        if method in oracles:
            return
        score.add(method, t, predicted)
        if method == "copy_last":
            score.add(CEILING, t, np.stack([occupancy[t + 1 + k] for k in range(horizon)]))

    if horizon > 1:
        return dataclasses.replace(hooks, on_ahead=_then(hooks.on_ahead, add))

    def one(method: str, t: int, probability: np.ndarray, flow: np.ndarray | None) -> None:
        add(method, t, probability)

    return dataclasses.replace(hooks, on_prediction=_then(hooks.on_prediction, one))


def _then(first: Callable[..., None] | None, second: Callable[..., None]) -> Callable[..., None]:
    if first is None:
        return second

    def both(*args: Any) -> None:
        first(*args)
        second(*args)

    return both


def labels_entry(labels: Labels, score: LabelScore) -> dict[str, Any]:
    """A recording's report keys: ``legs``, ``legs_intervals``, ``legs_kind`` and any
    ``legs_unmatched``."""
    entry = {"legs": score.summary(), "legs_intervals": score.intervals(), "legs_kind": labels.kind}
    if labels.unmatched:
        entry["legs_unmatched"] = labels.unmatched
    return entry
