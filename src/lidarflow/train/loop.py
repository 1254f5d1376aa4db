"""The training loop: model and loss per model type, schedules, metrics, checkpoints, DDP.

``train(config, run_dir)`` runs the whole recipe and returns a :class:`TrainResult`;
``train(..., resume=True)`` continues the run in ``run_dir`` from its newest checkpoint, exactly
as if it had never stopped (same weights, optimizer moments, learning rate, Gaussian size, RNG
state and data order). Non-finite losses or gradients stop the run with :class:`TrainError`
naming the epoch and step; nothing of the failing epoch is written.

Loss per model: ``flownet`` -> :func:`lidarflow.losses.flow_loss` with the epoch's Gaussian size
(``config.loss`` says which variant), plus ``loss.occupancy_bce`` x the cross-entropy of the
occupancy head's next map when the model has one; ``deeptracking`` -> :func:`deeptracking_loss`;
``sogmp`` -> :func:`sogmp_loss` with ``loss.kl_weight``.
All count only steps after ``data.warmup`` frames.
"""

from __future__ import annotations

import contextlib
import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from lidarflow.errors import ModelError, TrainError
from lidarflow.models import build, uses_ego_motion
from lidarflow.models.speed import accelerate, native_bf16
from lidarflow.train import checkpoint as ckpt
from lidarflow.train.config import TrainConfig
from lidarflow.train.data import load_train_data
from lidarflow.train.distributed import Dist, any_flag, barrier, setup
from lidarflow.train.loaders import make_loader, make_val_loader
from lidarflow.train.logbook import Logbook
from lidarflow.train.model_setup import load_init, make_optimizer
from lidarflow.train.objective import gaussian_size, make_loss
from lidarflow.train.rundir import (
    abandon_run_dir,
    prepare_run_dir,
    release_run_dir,
    write_final,
)
from lidarflow.train.supervised import flow_term, require_flow, supervised, take_flow
from lidarflow.train.validate import validate
from lidarflow.train.warm import split_batch, start_state, stream_start_states

__all__ = ["TrainResult", "gaussian_size", "make_loss", "train"]

EpochHook = Callable[[int, dict[str, Any]], None]


@dataclass
class TrainResult:
    """What a finished run leaves: its folder, per-epoch rows, and the trained (unwrapped) model."""

    run_dir: Path
    rows: list[dict[str, Any]]
    model: torch.nn.Module
    extra: dict[str, Any] = field(default_factory=dict)


def _seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def resolve_amp(amp: str, device: torch.device) -> tuple[bool, str | None]:
    """Whether to train under bf16 autocast for ``runtime.amp`` on ``device``, and a line for
    the log where the choice is not what the setting alone says (``auto``), or costs time
    (``bf16`` where the device has no native bf16: a ``note:``)."""
    if amp == "none":
        return False, None
    native = native_bf16(device)
    if amp == "auto":
        if native:
            return True, f"amp auto: bf16 autocast ({device.type} computes bf16 natively)"
        return False, f"amp auto: fp32 (this {device.type} has no native bf16, emulated is slower)"
    if native:
        return True, None
    return True, (
        f"note: this {device.type} has no native bf16: bf16 autocast is emulated and slower "
        "than fp32 here (--amp auto or none trains faster)"
    )


def _autocast(bf16: bool, device: torch.device) -> Callable[[], Any]:
    if bf16:
        return lambda: torch.autocast(device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext


def train(
    config: TrainConfig,
    run_dir: str | Path,
    resume: bool = False,
    echo: Callable[[str], None] | None = None,
    on_epoch_end: EpochHook | None = None,
    start_over: bool = False,
) -> TrainResult:
    """Train ``config`` into ``run_dir`` (see the module docstring). ``echo`` receives one-line
    progress messages (rank 0 only); ``on_epoch_end(epoch, row)`` runs after each checkpoint;
    ``start_over``: replace a run already in ``run_dir`` (``--force``), once it is locked."""
    from lidarflow.train.distributed import teardown

    config.validate()
    run_dir = Path(run_dir)
    ctx = setup(config.runtime.device)
    try:
        created = prepare_run_dir(run_dir, config, resume, ctx, start_over)
        try:
            return _train(config, run_dir, resume, ctx, echo, on_epoch_end)
        except BaseException:
            if ctx.is_main and not resume:  # stopped before its first epoch: leave no trace
                abandon_run_dir(run_dir, created)
            raise
    finally:
        if ctx.is_main:
            release_run_dir(run_dir)
        teardown()


def _train(
    config: TrainConfig,
    run_dir: Path,
    resume: bool,
    ctx: Dist,
    echo: Callable[[str], None] | None,
    on_epoch_end: EpochHook | None,
) -> TrainResult:
    from tqdm import tqdm

    def say(message: str) -> None:
        if ctx.is_main and echo is not None:
            echo(message)

    rt = config.runtime
    began = time.perf_counter()  # the budget (runtime.max_minutes) counts data loading too
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

    try:
        model = build(spec)
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
    model = accelerate(model.to(ctx.device), rt.channels_last, rt.compile)  # type: ignore[arg-type]
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
    bf16, amp_note = resolve_amp(rt.amp, ctx.device)
    if amp_note:
        say(amp_note)
    autocast = _autocast(bf16, ctx.device)
    B = config.optim.batch_size
    loader, sampler = make_loader(
        data, config.data, B, rt.seed, ctx.rank, ctx.world_size, ctx.device.type == "cuda"
    )
    val_loader = (
        make_val_loader(data.val, B, ctx.rank, ctx.world_size) if data.val is not None else None
    )
    is_flow = config.model.name == "flownet"
    book = Logbook(run_dir, rt.tensorboard, start if resume else None) if ctx.is_main else None
    rows: list[dict[str, Any]] = []  # this process's rows (every rank computes the same ones)

    def evaluate(kernel: int) -> dict[str, float]:
        if val_loader is None:
            return {}
        return validate(
            model,
            val_loader,
            make_loss(config, kernel, model),
            config.data.warmup,
            ctx,
            autocast,
            is_flow,
            config.data.memories_from_stream,
        )

    if start == 0 and rt.eval_before_training and val_loader is not None:
        row = {"epoch": 0, **evaluate(gaussian_size(config, 0))}
        rows.append(row)
        if book is not None and not book.rows:
            book.log(row)
        say("untrained: " + _describe(row))

    warm = config.data.memories_from_stream
    params = [p for p in model.parameters() if p.requires_grad]
    clip = config.optim.grad_clip if config.optim.grad_clip > 0 else math.inf
    limit = rt.divergence_limit
    for epoch in range(start, config.optim.epochs):
        sampler.set_epoch(epoch)
        kernel = gaussian_size(config, epoch)
        loss_fn = make_loss(config, kernel, model)
        lr = optimizer.param_groups[0]["lr"]
        net.train()
        total = frames = 0.0
        t0 = time.perf_counter()
        bar = tqdm(
            loader,
            desc=f"epoch {epoch + 1}/{config.optim.epochs}",
            unit="batch",
            leave=False,
            disable=None if ctx.is_main else True,
        )
        for step, batch in enumerate(bar, 1):
            truth = None
            if supervised(config):
                batch, truth = take_flow(batch)
            maps_u8, motions, first = split_batch(batch, uses_ego_motion(model), warm)
            seq = maps_u8.to(ctx.device, non_blocking=True).float()
            state = start_state(model, seq, first)
            with autocast():
                out, _ = net(seq, state, *(m.to(ctx.device) for m in motions))
            loss = loss_fn(seq, out.float())
            if truth is not None:
                loss = loss + flow_term(config, seq, out.float(), truth, motions)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(params, clip)
            health = _health(loss, grad_norm, out, clip, limit)
            loss_value = health[0]
            if any_flag(ctx, not all(_healthy(v, limit) for v in health)):
                raise TrainError(
                    _diverged(health, limit, epoch, step, len(loader), lr, kernel, run_dir)
                )
            optimizer.step()
            total += loss_value * len(seq)
            frames += seq.shape[0] * seq.shape[1] * ctx.world_size
            speed = frames / (time.perf_counter() - t0)
            bar.set_postfix(loss=f"{total / (step * B):.4g}", k=kernel, fps=f"{speed:.0f}")
        bar.close()
        train_seconds = time.perf_counter() - t0
        scheduler.step()
        train_loss = _mean_over_ranks(ctx, total, len(loader.sampler))
        metrics = evaluate(kernel)
        row = {
            "epoch": epoch + 1,
            "train_loss": train_loss,
            **metrics,
            "lr": lr,
            "gaussian_size": kernel,
            "train_seconds": train_seconds,
            "frame_steps_per_s": frames / train_seconds if train_seconds > 0 else 0.0,
        }
        score = metrics.get("val_f1", -train_loss)
        improved = extra.get("best") is None or score > extra["best"]["score"]
        if improved:
            extra["best"] = {
                "epoch": epoch + 1,
                "score": score,
                "metric": "val_f1" if "val_f1" in metrics else "-train_loss",
            }
        extra["epochs_done"] = epoch + 1
        if ctx.is_main:
            # The checkpoint goes last: until it is complete, a resume starts from the epoch
            # before, and drops this row and overwrites these weights.
            book.log(row)
            ckpt.save_weights(model, run_dir / "last.safetensors", {"epoch": epoch + 1})
            if improved:
                ckpt.save_weights(model, run_dir / "best.safetensors", {"epoch": epoch + 1})
            ckpt.save_checkpoint(run_dir, epoch + 1, model, optimizer, scheduler, extra)
        rows.append(row)
        barrier(ctx)
        say(f"epoch {epoch + 1}/{config.optim.epochs}: " + _describe(row))
        if on_epoch_end is not None:
            on_epoch_end(epoch + 1, row)
        spent = rt.max_minutes > 0 and time.perf_counter() - began > 60 * rt.max_minutes
        if any_flag(ctx, spent) and epoch + 1 < config.optim.epochs:
            say(
                f"time budget of {rt.max_minutes:g} min spent: the run ends after epoch "
                f"{epoch + 1} of {config.optim.epochs} (--resume continues it)"
            )
            break

    if ctx.is_main:
        write_final(run_dir, config, model, data, extra)
        book.close()
    barrier(ctx)
    return TrainResult(run_dir, book.rows if book else rows, model, extra)


def _health(loss: Tensor, grad_norm: Tensor, out: Tensor, clip: float, limit: float) -> list[float]:
    """The step's loss, gradient norm and largest output, in one sync. The output is checked
    too: a flow blown up to 1e30 cells still gives a finite loss (the warp samples zeros far
    outside the map), so a magnitude beyond runtime.divergence_limit counts as divergence."""
    health = torch.stack(
        [loss.detach().float(), grad_norm.float(), out.detach().float().abs().amax()]
    ).tolist()
    if math.isfinite(clip) and math.isfinite(health[1]):
        health[1] = min(health[1], limit)  # with clipping on, only NaN/inf is fatal
    return health


def _healthy(value: float, limit: float) -> bool:
    return math.isfinite(value) and abs(value) <= limit


def _diverged(
    health: list[float],
    limit: float,
    epoch: int,
    step: int,
    steps: int,
    lr: float,
    kernel: int,
    run_dir: Path,
) -> str:
    """The one-line story of a divergence: what went non-finite, where, and what to do."""
    names = ("loss", "gradient norm", "largest model output")
    bad = ", ".join(
        f"{n} {v:.4g}" for n, v in zip(names, health, strict=True) if not _healthy(v, limit)
    )
    last = ckpt.latest_epoch(run_dir)
    where = f"the last good checkpoint is epoch {last} in {run_dir}" if last else "none finished"
    return (
        f"training diverged at epoch {epoch + 1}, step {step} of {steps} (lr {lr:.3g}, Gaussian "
        f"size {kernel}): non-finite or absurd (> {limit:.0g}) {bad}; nothing of this epoch "
        f"was saved ({where}); lower --lr, set --grad-clip, or drop --amp"
    )


def _mean_over_ranks(ctx: Dist, total: float, count: int) -> float:
    from lidarflow.train.distributed import all_reduce_sum

    s, n = all_reduce_sum(ctx, [total, float(count)])
    return s / n if n else float("nan")


def _describe(row: dict[str, Any]) -> str:
    keys = (
        "train_loss",
        "val_loss",
        "val_f1",
        "val_copy_last_f1",
        "val_changed_f1",
        "val_epe",
        "val_epe_zero",
        "val_epe_moving",
        "val_epe_moving_zero",
    )
    return ", ".join(f"{k} {row[k]:.4g}" for k in keys if k in row)
