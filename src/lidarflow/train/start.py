"""Starting a run: its data (:func:`load_data`), its model, optimizer, schedule, loaders and
logbook (:func:`start_run`), shared with the steps of :mod:`lidarflow.train.loop` as a
:class:`Run`.
"""

from __future__ import annotations

import random
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import DataLoader

from lidarflow.errors import ModelError, TrainError
from lidarflow.models import build
from lidarflow.models.speed import accelerate
from lidarflow.train import checkpoint as ckpt
from lidarflow.train.config import TrainConfig
from lidarflow.train.data import TrainData, load_train_data
from lidarflow.train.distributed import Dist, barrier
from lidarflow.train.loaders import MixSampler, make_loader, make_val_loader
from lidarflow.train.logbook import Logbook
from lidarflow.train.model_setup import load_init, make_optimizer
from lidarflow.train.objective import make_loss
from lidarflow.train.precision import autocast, resolve_amp
from lidarflow.train.supervised import require_flow, supervised
from lidarflow.train.validate import validate
from lidarflow.train.warm import stream_start_states

__all__ = ["Run", "Say", "load_data", "start_run"]

Say = Callable[[str], None]  # a progress line for the user (rank 0's echo; a no-op elsewhere)


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


@dataclass
class Run:
    """A run under way: what its steps share, and the state it carries from epoch to epoch.

    ``extra`` (best score, epochs done) goes into every checkpoint; ``rows`` are this process's
    rows; ``book`` writes them on rank 0 (``None`` elsewhere); ``start``: the epochs done before
    this process began.
    """

    config: TrainConfig
    run_dir: Path
    ctx: Dist
    say: Say
    began: float  # time.perf_counter() before the data loaded: the budget counts loading too
    data: TrainData
    model: torch.nn.Module  # unwrapped: what is saved, validated and returned
    net: torch.nn.Module  # what the training batches go through: the model or its DDP wrapper
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.StepLR
    loader: DataLoader
    sampler: MixSampler
    val_loader: DataLoader | None
    autocast: Callable[[], Any]
    book: Logbook | None
    start: int
    extra: dict[str, Any]
    rows: list[dict[str, Any]] = field(default_factory=list)

    def val_metrics(self, kernel: int) -> dict[str, float]:
        """The validation metrics with the Gaussian size ``kernel``; none without validation."""
        if self.val_loader is None:
            return {}
        config = self.config
        return validate(
            self.model,
            self.val_loader,
            make_loss(config, kernel, self.model),
            config.data.warmup,
            self.ctx,
            self.autocast,
            config.model.name == "flownet",
            config.data.memories_from_stream,
        )


def load_data(config: TrainConfig, say: Say) -> TrainData:
    """Set the threads and seed every generator, then load the windows in the form the model
    takes (motions, sub-cell input, exact flow for a supervised recipe: :class:`TrainError`
    where it is missing). Says the data's summary and notes."""
    rt = config.runtime
    if rt.threads > 0:
        torch.set_num_threads(rt.threads)
    _seed_everything(rt.seed)
    spec = config.model.spec()
    data = load_train_data(
        config.data,
        with_motion=spec.ego_motion,
        with_subcell=spec.head is not None and spec.head.subcell_input,
        train_flow=supervised(config),
    )
    if supervised(config):
        require_flow(config, data)
    say(data.summary())
    for note in data.notes:
        say(f"note: {note}")
    return data


def _make_model(
    config: TrainConfig, resume: bool, data: TrainData, ctx: Dist, say: Say
) -> torch.nn.Module:
    """The model of ``config.model`` on ``ctx.device``, accelerated, from ``model.init`` on a
    new run; streams the windows' start memories into ``data`` (``data.memories_from_stream``).
    :class:`TrainError` where the model cannot be built or streamed."""
    try:
        model = build(config.model.spec())
    except (ModelError, ValueError) as err:
        raise TrainError(f"cannot build model {config.model.name!r}: {err}") from err
    if config.model.init and not resume:
        new_head = load_init(model, config.model.init)
        say(
            f"starting from the weights of {config.model.init}"
            + (" (occupancy head new)" if new_head else "")
        )
    if config.data.memories_from_stream:
        try:
            for windows in (*data.sources, *([data.val] if data.val is not None else [])):
                stream_start_states(model, windows)
        except ValueError as err:
            raise TrainError(f"data.memories_from_stream: {err}") from err
        say("windows start from the head's memories as streaming leaves them")
    rt = config.runtime
    return accelerate(model.to(ctx.device), rt.channels_last, rt.compile)  # type: ignore[arg-type]


def start_run(
    config: TrainConfig,
    run_dir: Path,
    resume: bool,
    ctx: Dist,
    data: TrainData,
    say: Say,
    began: float,
) -> Run:
    """Everything the epochs need, on every rank: model, optimizer and schedule (restored with
    the RNG states on a resume), the DDP wrapper, autocast, the loaders and, on rank 0, the
    logbook."""
    model = _make_model(config, resume, data, ctx, say)
    optimizer = make_optimizer(config, model)
    scheduler = torch.optim.lr_scheduler.StepLR(
        optimizer, config.schedule.lr_step_epochs, config.schedule.lr_gamma
    )
    start, extra = 0, {"best": None}
    if resume:
        start, extra = ckpt.load_checkpoint(run_dir, model, optimizer, scheduler)
        say(f"resuming {run_dir} after epoch {start}")
        if start >= config.optim.epochs:
            say(f"{run_dir}: already trained {start} of {config.optim.epochs} epochs")
    barrier(ctx)

    net: torch.nn.Module = model
    if ctx.enabled:
        ids = [ctx.device.index] if ctx.device.type == "cuda" else None
        net = torch.nn.parallel.DistributedDataParallel(model, device_ids=ids)
    rt = config.runtime
    bf16, amp_note = resolve_amp(rt.amp, ctx.device)
    if amp_note:
        say(amp_note)
    B = config.optim.batch_size
    loader, sampler = make_loader(
        data, config.data, B, rt.seed, ctx.rank, ctx.world_size, ctx.device.type == "cuda"
    )
    val_loader = (
        make_val_loader(data.val, B, ctx.rank, ctx.world_size) if data.val is not None else None
    )
    book = Logbook(run_dir, rt.tensorboard, start if resume else None) if ctx.is_main else None
    return Run(
        config=config,
        run_dir=run_dir,
        ctx=ctx,
        say=say,
        began=began,
        data=data,
        model=model,
        net=net,
        optimizer=optimizer,
        scheduler=scheduler,
        loader=loader,
        sampler=sampler,
        val_loader=val_loader,
        autocast=autocast(bf16, ctx.device),
        book=book,
        start=start,
        extra=extra,
    )
