"""Running under ``torchrun``: process group, device per rank, and the few collectives used.

Under ``torchrun --nproc_per_node N -m lidarflow.cli train ...`` (``RANK``, ``WORLD_SIZE``,
``LOCAL_RANK`` set), :func:`setup` joins the group (``nccl`` on CUDA, ``gloo`` on CPU); otherwise
everything is one process and the collectives are no-ops. Only rank 0 writes files.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.distributed as dist

from lidarflow.errors import TrainError

__all__ = ["Dist", "all_reduce_sum", "any_flag", "barrier", "pick_device", "setup", "teardown"]


CPU = torch.device("cpu")


@dataclass(frozen=True)
class Dist:
    """Where this process stands: ``rank`` of ``world_size``, on ``device``."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    device: torch.device = CPU

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def enabled(self) -> bool:
        return self.world_size > 1


def pick_device(name: str, local_rank: int = 0) -> torch.device:
    """``auto`` means CUDA when available; a bare ``cuda`` means this rank's GPU."""
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise TrainError("--device cuda asked for, but torch sees no CUDA device")
        return torch.device(f"cuda:{local_rank}" if name == "cuda" else name)
    return torch.device(name)


def setup(device: str = "auto") -> Dist:
    """Join the process group when launched by torchrun; otherwise a single process."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    dev = pick_device(device, local_rank)
    if world_size > 1 and not dist.is_initialized():
        backend = "nccl" if dev.type == "cuda" else "gloo"
        if dev.type == "cuda":
            torch.cuda.set_device(dev)
        try:
            dist.init_process_group(backend=backend, rank=rank, world_size=world_size)
        except (RuntimeError, ValueError) as err:
            raise TrainError(f"cannot join the {backend} process group: {err}") from err
    return Dist(rank, world_size, local_rank, dev)


def teardown() -> None:
    if dist.is_initialized():
        dist.destroy_process_group()


def barrier(ctx: Dist) -> None:
    if ctx.enabled:
        dist.barrier()


def all_reduce_sum(ctx: Dist, values: list[float]) -> list[float]:
    """Element-wise sum of ``values`` over ranks (float64 on the rank's device)."""
    if not ctx.enabled:
        return list(values)
    device = ctx.device if ctx.device.type == "cuda" else torch.device("cpu")
    t = torch.tensor(values, dtype=torch.float64, device=device)
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return t.tolist()


def any_flag(ctx: Dist, flag: bool) -> bool:
    """True on every rank when ``flag`` is true on any (so all ranks stop together)."""
    if not ctx.enabled:
        return flag
    return all_reduce_sum(ctx, [float(flag)])[0] > 0
