"""Training data: windows of recordings from several sources, with a validation split.

A *source* is one ``data.sources`` entry: a recording ``.npz``, a bag / ROS 2 bag folder / MCAP
(converted on the fly), a folder of ``.npz`` recordings, or a glob pattern. How the windows are
drawn into batches, by each source's ``data.mix`` weight, is :mod:`lidarflow.train.loaders`.

Validation split (``data.val_split``):

- ``tail`` (default): the last ``val_fraction`` of every recording's frames (at least one
  window) as one contiguous block, so validation windows never share frames with training
  windows. A recording too short to give both is used for training only.
- ``recordings``: the last ``ceil(val_fraction * n)`` recordings (in the order given), whole.
- ``data.val_sources``: explicit validation recordings; then no training data is held out.

Items are described by :class:`Windows`.
"""

from __future__ import annotations

import glob
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from lidarflow.data import Recording, SequenceSet, load_any
from lidarflow.data.sources import topic_notes
from lidarflow.errors import LidarflowError, TrainError
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.scan import GridSpec
from lidarflow.train.config import DataConfig

__all__ = ["TrainData", "Windows", "expand_source", "load_train_data"]

FLOW_KEY = "flow_backward"
FORWARD_KEY = "flow_forward"
# a recording's ground-truth flow: dense (N, 2, H, W), sparse (cells, values) or none
Flow = np.ndarray | tuple[np.ndarray, np.ndarray] | None


def expand_source(spec: str) -> list[Path]:
    """The files of one source: a file or bag folder as is, a folder of ``.npz`` files, or a
    glob pattern."""
    path = Path(spec)
    if any(ch in spec for ch in "*?["):
        found = sorted(Path(p) for p in glob.glob(spec))
        if not found:
            raise TrainError(f"data source {spec!r}: the pattern matches no file")
        return found
    if path.is_dir():
        npz = sorted(path.glob("*.npz"))
        return npz or [path]  # no .npz inside: a ROS 2 bag folder
    if not path.exists():
        raise TrainError(f"data source {spec}: no such file or folder")
    return [path]


class Windows(Dataset):
    """Windows ``(rec, start)`` over boolean maps. An item is, in order:

    - uint8 ``(T, C, H, W)`` maps: occupancy, visibility (and the sub-cell channels);
    - with ``with_flow``: float32 ``(T, 2, H, W)`` ground-truth ``B^t`` (``(T, 4, H, W)``,
      ``B^t`` then ``F^t``, with ``flows_forward``), zeros where the recording has none, and a
      bool saying whether it is real;
    - with ``motions`` (float32 ``(N, 3)`` per recording): the window's ``(T, 3)`` motions
      ``(dx, dy, dyaw)`` in cells, frame ``t`` in frame ``t - 1``, identity where a pose is
      unknown or ``pose_dropout`` serves the window without poses;
    - with ``start_states`` (:func:`lidarflow.train.warm.stream_start_states`): the head's
      state where streaming reaches the window's first frame.
    """

    def __init__(
        self,
        maps: Sequence[np.ndarray],
        index: Sequence[tuple[int, int]],
        length: int,
        flows: Sequence[Flow] = (),
        with_flow: bool = False,
        motions: Sequence[np.ndarray] | None = None,
        pose_dropout: float = 0.0,
        flows_forward: Sequence[Flow] | None = None,
    ) -> None:
        self.maps = list(maps)
        self.index = list(index)
        self.length = length
        self.flows = list(flows) or [None] * len(self.maps)
        self.with_flow = with_flow
        self.flows_forward = None if flows_forward is None else list(flows_forward)
        self.motions = None if motions is None else list(motions)
        self.pose_dropout = pose_dropout
        # (recording, start, posed) -> the head's state before the window's first frame.
        self.start_states: dict[tuple[int, int, bool], np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> torch.Tensor | tuple[torch.Tensor | bool, ...]:
        item = self._item(i)
        parts = list(item) if isinstance(item, tuple) else [item]
        rec, start = self.index[i]
        posed = self.motions is not None and not self.dropped(i)
        if self.motions is not None:
            motion = torch.from_numpy(self.motions[rec][start : start + self.length])
            parts.append(motion if posed else torch.zeros_like(motion))
        if self.start_states is not None:
            parts.append(torch.from_numpy(self.start_states[(rec, start, posed)]))
        return parts[0] if len(parts) == 1 else tuple(parts)

    def dropped(self, i: int) -> bool:
        """Whether window ``i`` is served without its poses (fixed per window)."""
        rec, start = self.index[i]
        return bool(self.pose_dropout) and (
            np.random.default_rng((rec, start)).random() < self.pose_dropout
        )

    def _item(self, i: int) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor, bool]:
        rec, start = self.index[i]
        window = self.maps[rec][start : start + self.length]
        maps = torch.from_numpy(np.ascontiguousarray(window).view(np.uint8))
        if not self.with_flow:
            return maps
        shape = window.shape[-2:]
        flows = [self.flows[rec]]
        if self.flows_forward is not None:
            flows.append(self.flows_forward[rec])
        if any(f is None for f in flows):
            return maps, torch.zeros((self.length, 2 * len(flows), *shape)), False
        dense = [self._dense(f, start, shape) for f in flows]  # type: ignore[arg-type]
        return maps, torch.from_numpy(np.concatenate(dense, axis=1)), True

    def _dense(
        self, flow: np.ndarray | tuple[np.ndarray, np.ndarray], start: int, shape: tuple[int, ...]
    ) -> np.ndarray:
        """float32 ``(T, 2, H, W)`` of the window at ``start`` from a dense or sparse flow."""
        if isinstance(flow, tuple):  # sparse: (cells (N, K), values (N, K, 2))
            cells, values = (a[start : start + self.length] for a in flow)
            dense = np.zeros((len(cells), 2, shape[0] * shape[1]), dtype=np.float32)
            frame, slot = np.nonzero(cells >= 0)
            dense[frame, :, cells[frame, slot]] = values[frame, slot]
            return dense.reshape(len(cells), 2, *shape)
        return flow[start : start + self.length].astype(np.float32)

    @property
    def has_flow(self) -> bool:
        return any(f is not None for f in self.flows)


@dataclass
class TrainData:
    """Training windows (one :class:`Windows` per source), their weights, and validation."""

    sources: list[Windows]
    weights: list[float]
    val: Windows | None
    grid: GridSpec
    notes: list[str] = field(default_factory=list)

    @property
    def train_windows(self) -> int:
        return sum(len(s) for s in self.sources)

    def summary(self) -> str:
        total = max(self.train_windows, 1)
        weights = self.weights or [len(s) / total for s in self.sources]
        parts = [
            f"{len(s)} windows (weight {w:.2f})" for s, w in zip(self.sources, weights, strict=True)
        ]
        val = f"{len(self.val)} validation windows" if self.val is not None else "no validation"
        return f"training: {'; '.join(parts)}; {val}"


def _ground_truth(rec: Recording, grid: GridSpec, key: str = FLOW_KEY) -> tuple[Flow, str | None]:
    """The recording's ground-truth flow ``key`` (:mod:`lidarflow.sim.storage`) if it is on
    ``grid``; else ``None`` and why."""
    extras, stored = rec.extras, rec.meta.get("grid") or {}
    flow: Flow
    if key in extras:
        flow = extras[key]
        shape = tuple(flow.shape[-2:])
    elif f"{key}_cells" in extras and f"{key}_values" in extras:
        flow = (extras[f"{key}_cells"], extras[f"{key}_values"])
        shape = (stored.get("height"), stored.get("width"))
    else:
        return None, None
    res = stored.get("res", grid.res)
    if shape != grid.shape or not np.isclose(res, grid.res):
        return (
            None,
            f"ground-truth flow is on a {shape} grid of {res} m, not {grid.shape} of "
            f"{grid.res} m: no EPE for it",
        )
    return flow, None


def _windows(
    recordings: list[Recording],
    cfg: DataConfig,
    grid: GridSpec,
    with_flow: bool,
    with_motion: bool = False,
    pose_dropout: float = 0.0,
    with_subcell: bool = False,
    forward: bool = False,
) -> tuple[Windows, list[str]]:
    seqs = SequenceSet(
        recordings, cfg.seq_len, cfg.stride or cfg.seq_len, grid, cfg.max_gap_periods,
        with_subcell,
    )  # fmt: skip
    flows: list[Flow] = []
    notes = list(seqs.report.notes)
    for rec in recordings:
        flow, note = _ground_truth(rec, grid)
        flows.append(flow)
        if note:
            notes.append(f"{rec.meta.get('source', 'a recording')}: {note}")
    motions = None
    if with_motion:
        motions = []
        for rec in recordings:
            m, known = relative_motions(rec.poses, len(rec))
            motions.append(metres_to_cells(m, grid.res))
            if len(rec) > 1 and not known[1:].all():
                notes.append(
                    f"{rec.meta.get('source', 'a recording')}: no pose for "
                    f"{int((~known[1:]).sum())} of {len(rec) - 1} frame steps; those steps are "
                    "not ego-motion compensated"
                )
    forwards = [_ground_truth(rec, grid, FORWARD_KEY)[0] for rec in recordings] if forward else None
    windows = Windows(
        seqs.maps, seqs.index, cfg.seq_len, flows, with_flow, motions, pose_dropout, forwards
    )
    return windows, notes


def _load(paths: list[Path], topic: str | None) -> list[Recording]:
    from tqdm import tqdm

    recordings = []
    for path in paths:
        try:
            with tqdm(desc=f"reading {path.name}", unit="scan", leave=False, disable=None) as bar:
                rec = load_any(
                    path, topic=None if path.suffix == ".npz" else topic, progress=bar.update
                )
        except LidarflowError as err:
            raise TrainError(f"cannot load training data: {err}") from err
        rec.meta.setdefault("source", str(path))
        for note in topic_notes(path, rec):  # as every command says
            tqdm.write(note, file=sys.stderr)
        recordings.append(rec)
    return recordings


def _split_tail(
    rec: Recording, fraction: float, length: int
) -> tuple[Recording | None, Recording | None]:
    n = len(rec)
    n_val = max(math.ceil(fraction * n), length) if fraction > 0 else 0
    if n_val == 0 or n - n_val < length:
        return rec, None
    return rec.slice(0, n - n_val), rec.slice(n - n_val, n)


def load_train_data(
    cfg: DataConfig, with_motion: bool = False, with_subcell: bool = False, train_flow: bool = False
) -> TrainData:
    """Load every source, split off validation, and cut windows; ``with_motion``: items carry
    the per-frame ego motion; ``with_subcell``: maps carry
    :meth:`~lidarflow.data.Recording.subcell_maps` as channels 2 and 3; ``train_flow``: training
    windows carry the exact ``B^t, F^t``. Validation windows carry ``B^t`` and every pose."""
    if not cfg.sources:
        raise TrainError("no training data: give at least one recording or bag")
    if cfg.mix and len(cfg.mix) not in (len(cfg.sources), len(cfg.sources) - 1):
        raise TrainError(
            f"--mix gives {len(cfg.mix)} weight(s) for {len(cfg.sources)} sources: give one per "
            "source (or, for two sources, one fraction for the first)"
        )
    grid = GridSpec(cfg.grid, cfg.grid, cfg.res)
    per_source = [_load(expand_source(s), cfg.topic) for s in cfg.sources]
    notes: list[str] = []
    val_recs: list[Recording] = []
    train_recs: list[list[Recording]] = [[] for _ in per_source]
    if cfg.val_sources:
        val_recs = [r for s in cfg.val_sources for r in _load(expand_source(s), cfg.topic)]
        train_recs = per_source
    elif cfg.val_split == "recordings" and cfg.val_fraction > 0:
        flat = [(i, r) for i, recs in enumerate(per_source) for r in recs]
        k = max(1, math.ceil(cfg.val_fraction * len(flat)))
        if k >= len(flat):
            raise TrainError(
                f"val_split=recordings needs at least 2 recordings, got {len(flat)}; "
                "give more or use --val-split tail"
            )
        for i, rec in flat[: len(flat) - k]:
            train_recs[i].append(rec)
        val_recs = [rec for _, rec in flat[len(flat) - k :]]
    else:
        for i, recs in enumerate(per_source):
            for rec in recs:
                train, val = _split_tail(rec, cfg.val_fraction, cfg.seq_len)
                if val is None and cfg.val_fraction > 0:
                    notes.append(f"{rec.meta['source']}: too short to hold out validation frames")
                if train is not None:
                    train_recs[i].append(train)
                if val is not None:
                    val_recs.append(val)
    sources = []
    for spec, recs in zip(cfg.sources, train_recs, strict=True):
        if not recs:
            raise TrainError(f"data source {spec}: nothing left for training after the split")
        try:
            # Validation keeps every pose: it measures the model where odometry is there.
            windows, more = _windows(
                recs, cfg, grid, train_flow, with_motion, cfg.pose_dropout, with_subcell,
                forward=train_flow,
            )  # fmt: skip
        except LidarflowError as err:
            raise TrainError(f"data source {spec}: {err}") from err
        if not any(m[:, 0].any() for m in windows.maps):  # channel 0: occupancy
            frames = sum(len(m) for m in windows.maps)
            raise TrainError(
                f"data source {spec}: no occupied cell in any of its {frames} training frames "
                "(its beams NaN, inf or out of range, or its returns off the grid): nothing to "
                "learn from (`lidarflow info` counts its beams)"
            )
        sources.append(windows)
        notes += more
    val = None
    if val_recs:
        try:
            val, more = _windows(val_recs, cfg, grid, True, with_motion, with_subcell=with_subcell)
            notes += more
        except LidarflowError as err:
            notes.append(f"no validation windows ({err})")
    return TrainData(sources, _weights(cfg.mix, len(sources)), val, grid, notes)


def _weights(mix: list[float], n: int) -> list[float]:
    """Normalised per-source weights; empty means natural proportions."""
    if not mix:
        return []
    if len(mix) == n - 1:  # one fraction per source but the last, which takes the rest
        if sum(mix) > 1:
            raise TrainError(f"--mix fractions {mix} add up to more than 1")
        mix = [*mix, 1 - sum(mix)]
    total = sum(mix)
    return [w / total for w in mix]
