"""Batches of training windows: the mixed, resumable, sharded draw of an epoch.

An epoch draws ``data.epoch_windows`` windows (0: every training window once), ``round(w_s n)``
of them from source ``s`` by its ``data.mix`` weight, in whole reshuffled passes, then shuffles
them together. The order depends only on ``(seed, epoch)``, so ``--resume`` reproduces it, and is
sharded over DDP ranks as :class:`torch.utils.data.DistributedSampler` shards.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from lidarflow.train.config import DataConfig
from lidarflow.train.data import TrainData, Windows

__all__ = ["MixSampler", "make_loader", "make_val_loader"]


class MixSampler(Sampler[int]):
    """Indices into the concatenation of sources, drawn by weight, sharded over ranks.

    The draw for an epoch depends only on ``(seed, epoch)``; call :meth:`set_epoch` first.
    """

    def __init__(
        self,
        sizes: Sequence[int],
        weights: Sequence[float] = (),
        num_samples: int = 0,
        seed: int = 0,
        rank: int = 0,
        world_size: int = 1,
    ) -> None:
        self.sizes = list(sizes)
        self.weights = list(weights)
        self.num_samples = num_samples or sum(self.sizes)
        self.seed = seed
        self.rank = rank
        self.world_size = world_size
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = epoch

    def _global_order(self) -> list[int]:
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + self.epoch)
        offsets = np.concatenate([[0], np.cumsum(self.sizes)])
        if not self.weights:
            return _draw(int(offsets[-1]), self.num_samples, g).tolist()
        counts = [round(w * self.num_samples) for w in self.weights]
        counts[int(np.argmax(self.weights))] += self.num_samples - sum(counts)
        chosen = [
            _draw(size, count, g) + int(offset)
            for size, count, offset in zip(self.sizes, counts, offsets, strict=False)
            if count > 0
        ]
        everything = torch.cat(chosen)
        return everything[torch.randperm(len(everything), generator=g)].tolist()

    def __iter__(self) -> Iterator[int]:
        order = self._global_order()
        padded = len(self) * self.world_size
        order += order[: padded - len(order)]
        return iter(order[self.rank : padded : self.world_size])

    def __len__(self) -> int:
        return math.ceil(self.num_samples / self.world_size)


def _draw(size: int, count: int, g: torch.Generator) -> torch.Tensor:
    """``count`` indices below ``size``: whole reshuffled passes, the last one cut."""
    passes = [torch.randperm(size, generator=g) for _ in range(math.ceil(count / size))]
    return torch.cat(passes)[:count]


class _Concat(Dataset):
    def __init__(self, parts: Sequence[Windows]) -> None:
        self.parts = list(parts)
        self.offsets = np.cumsum([0, *(len(p) for p in parts)])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def __getitem__(self, i: int) -> torch.Tensor:
        part = int(np.searchsorted(self.offsets, i, side="right") - 1)
        return self.parts[part][i - int(self.offsets[part])]


def make_loader(
    data: TrainData,
    cfg: DataConfig,
    batch_size: int,
    seed: int,
    rank: int = 0,
    world_size: int = 1,
    pin_memory: bool = False,
) -> tuple[DataLoader, MixSampler]:
    """The training DataLoader and its sampler (call ``sampler.set_epoch(e)`` every epoch)."""
    sampler = MixSampler(
        [len(s) for s in data.sources], data.weights, cfg.epoch_windows, seed, rank, world_size
    )
    loader = DataLoader(
        _Concat(data.sources),
        batch_size=batch_size,
        sampler=sampler,
        num_workers=cfg.num_workers,
        pin_memory=pin_memory,
        drop_last=False,
    )
    return loader, sampler


def make_val_loader(
    windows: Windows, batch_size: int, rank: int = 0, world_size: int = 1
) -> DataLoader:
    """Validation in a fixed order; rank ``r`` takes every ``world``-th window, no padding
    (counts are summed over ranks, so nothing is counted twice)."""
    subset = torch.utils.data.Subset(windows, list(range(rank, len(windows), world_size)))
    return DataLoader(subset, batch_size=batch_size, shuffle=False)
