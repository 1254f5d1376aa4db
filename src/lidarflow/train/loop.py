"""The training loop: ``train(config, run_dir)`` runs the whole recipe and returns a
:class:`TrainResult`; ``resume=True`` continues the run from its newest checkpoint exactly as if
it had never stopped (weights, optimizer moments, learning rate, Gaussian size, RNG state, data
order). A diverging step stops the run with :class:`TrainError`; nothing of its epoch is written.

In a run folder :func:`train` locks (and removes again where a new run stops before its first
epoch), a run loads its data and starts (:mod:`lidarflow.train.start`), scores the untrained
model as epoch 0, trains and closes each epoch (:func:`_fit_epoch`, :func:`_close_epoch`) until
the epochs or ``runtime.max_minutes`` are spent, and writes the final model (:func:`_finish`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import torch
from torch import Tensor

from lidarflow.errors import TrainError
from lidarflow.models import uses_ego_motion
from lidarflow.train import checkpoint as ckpt
from lidarflow.train.config import TrainConfig
from lidarflow.train.distributed import Dist, all_reduce_sum, any_flag, barrier, setup, teardown
from lidarflow.train.health import divergence_message, healthy, step_health
from lidarflow.train.objective import gaussian_size, make_loss
from lidarflow.train.rundir import abandon_run_dir, prepare_run_dir, release_run_dir, write_final
from lidarflow.train.start import Run, load_data, start_run
from lidarflow.train.supervised import flow_term, supervised, take_flow
from lidarflow.train.warm import split_batch, start_state

__all__ = ["TrainResult", "train"]

EpochHook = Callable[[int, dict[str, Any]], None]


@dataclass
class TrainResult:
    """What a finished run leaves: its folder, per-epoch rows, and the trained (unwrapped) model."""

    run_dir: Path
    rows: list[dict[str, Any]]
    model: torch.nn.Module
    extra: dict[str, Any] = field(default_factory=dict)


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


class _Fit(NamedTuple):
    """One epoch's training: its learning rate and Gaussian size, the mean loss per window over
    all ranks, the seconds it took and the frame steps it made (all ranks together)."""

    lr: float
    kernel: int
    loss: float
    seconds: float
    frames: float


def _train(
    config: TrainConfig,
    run_dir: Path,
    resume: bool,
    ctx: Dist,
    echo: Callable[[str], None] | None,
    on_epoch_end: EpochHook | None,
) -> TrainResult:
    """The steps of the module docstring, in order, in a run folder :func:`train` holds."""

    def say(message: str) -> None:
        if ctx.is_main and echo is not None:
            echo(message)

    began = time.perf_counter()
    data = load_data(config, say)
    run = start_run(config, run_dir, resume, ctx, data, say, began)
    if run.start == 0 and config.runtime.eval_before_training and run.val_loader is not None:
        _score_untrained(run)
    for epoch in range(run.start, config.optim.epochs):
        row = _close_epoch(run, epoch, _fit_epoch(run, epoch))
        if on_epoch_end is not None:
            on_epoch_end(epoch + 1, row)
        if _out_of_time(run, epoch):
            break
    return _finish(run)


def _score_untrained(run: Run) -> None:
    """Validate the untrained model as epoch 0 (logged unless the logbook holds rows)."""
    row = {"epoch": 0, **run.val_metrics(gaussian_size(run.config, 0))}
    run.rows.append(row)
    if run.book is not None and not run.book.rows:
        run.book.log(row)
    run.say("untrained: " + _describe(row))


def _fit_epoch(run: Run, epoch: int) -> _Fit:
    """Train the 0-based ``epoch``: one clipped optimizer step per batch, then one step of the
    learning-rate schedule. An unhealthy step (:mod:`lidarflow.train.health`) on any rank raises
    :class:`TrainError` on every rank before the optimizer takes it."""
    from tqdm import tqdm

    config, ctx, model, optimizer = run.config, run.ctx, run.model, run.optimizer
    run.sampler.set_epoch(epoch)
    kernel = gaussian_size(config, epoch)
    loss_fn = make_loss(config, kernel, model)
    lr = optimizer.param_groups[0]["lr"]
    params = [p for p in model.parameters() if p.requires_grad]
    clip = config.optim.grad_clip if config.optim.grad_clip > 0 else math.inf
    limit = config.runtime.divergence_limit
    B = config.optim.batch_size
    run.net.train()
    total = frames = 0.0
    t0 = time.perf_counter()
    bar = tqdm(
        run.loader,
        desc=f"epoch {epoch + 1}/{config.optim.epochs}",
        unit="batch",
        leave=False,
        disable=None if ctx.is_main else True,
    )
    for step, batch in enumerate(bar, 1):
        seq, out, loss = _batch_loss(run, batch, loss_fn)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(params, clip)
        health = step_health(loss, grad_norm, out, clip, limit)
        loss_value = health[0]
        if any_flag(ctx, not all(healthy(v, limit) for v in health)):
            raise TrainError(
                divergence_message(
                    health, limit, epoch, step, len(run.loader), lr, kernel, run.run_dir
                )
            )
        optimizer.step()
        total += loss_value * len(seq)
        frames += seq.shape[0] * seq.shape[1] * ctx.world_size
        speed = frames / (time.perf_counter() - t0)
        bar.set_postfix(loss=f"{total / (step * B):.4g}", k=kernel, fps=f"{speed:.0f}")
    bar.close()
    seconds = time.perf_counter() - t0
    run.scheduler.step()
    loss_mean = _mean_over_ranks(ctx, total, len(run.loader.sampler))
    return _Fit(lr, kernel, loss_mean, seconds, frames)


def _batch_loss(
    run: Run, batch: Any, loss_fn: Callable[[Tensor, Tensor], Tensor]
) -> tuple[Tensor, Tensor, Tensor]:
    """A training batch through the model under autocast: its maps ``(B, T, C, H, W)`` as float
    on the device, the model's output and the loss (with the supervised flow term, if any)."""
    config, ctx, model = run.config, run.ctx, run.model
    truth = None
    if supervised(config):
        batch, truth = take_flow(batch)
    maps_u8, motions, first = split_batch(
        batch, uses_ego_motion(model), config.data.memories_from_stream
    )
    seq = maps_u8.to(ctx.device, non_blocking=True).float()
    state = start_state(model, seq, first)
    with run.autocast():
        out, _ = run.net(seq, state, *(m.to(ctx.device) for m in motions))
    loss = loss_fn(seq, out.float())
    if truth is not None:
        loss = loss + flow_term(config, seq, out.float(), truth, motions)
    return seq, out, loss


def _close_epoch(run: Run, epoch: int, fit: _Fit) -> dict[str, Any]:
    """Validate the 0-based ``epoch`` just trained, keep its row and the best score so far; on
    rank 0 log the row and save the last (and best) weights, then the checkpoint: until it is
    complete, a resume starts from the epoch before. Returns the row once every rank has it."""
    metrics = run.val_metrics(fit.kernel)
    row = {
        "epoch": epoch + 1,
        "train_loss": fit.loss,
        **metrics,
        "lr": fit.lr,
        "gaussian_size": fit.kernel,
        "train_seconds": fit.seconds,
        "frame_steps_per_s": fit.frames / fit.seconds if fit.seconds > 0 else 0.0,
    }
    extra = run.extra
    score = metrics.get("val_f1", -fit.loss)
    improved = extra.get("best") is None or score > extra["best"]["score"]
    if improved:
        extra["best"] = {
            "epoch": epoch + 1,
            "score": score,
            "metric": "val_f1" if "val_f1" in metrics else "-train_loss",
        }
    extra["epochs_done"] = epoch + 1
    if run.book is not None:
        run.book.log(row)
        ckpt.save_weights(run.model, run.run_dir / "last.safetensors", {"epoch": epoch + 1})
        if improved:
            ckpt.save_weights(run.model, run.run_dir / "best.safetensors", {"epoch": epoch + 1})
        ckpt.save_checkpoint(run.run_dir, epoch + 1, run.model, run.optimizer, run.scheduler, extra)
    run.rows.append(row)
    barrier(run.ctx)
    run.say(f"epoch {epoch + 1}/{run.config.optim.epochs}: " + _describe(row))
    return row


def _out_of_time(run: Run, epoch: int) -> bool:
    """Whether the run ends after the 0-based ``epoch``, before its last, because
    ``runtime.max_minutes`` is spent on any rank (all ranks agree)."""
    rt, epochs = run.config.runtime, run.config.optim.epochs
    spent = rt.max_minutes > 0 and time.perf_counter() - run.began > 60 * rt.max_minutes
    if any_flag(run.ctx, spent) and epoch + 1 < epochs:
        run.say(
            f"time budget of {rt.max_minutes:g} min spent: the run ends after epoch "
            f"{epoch + 1} of {epochs} (--resume continues it)"
        )
        return True
    return False


def _finish(run: Run) -> TrainResult:
    """On rank 0, write the final model (``runtime.final_weights``); on every rank, the result
    (rank 0's rows include those before a resume)."""
    if run.book is not None:
        write_final(run.run_dir, run.config, run.model, run.data, run.extra)
        run.book.close()
    barrier(run.ctx)
    rows = run.book.rows if run.book else run.rows
    return TrainResult(run.run_dir, rows, run.model, run.extra)


def _mean_over_ranks(ctx: Dist, total: float, count: int) -> float:
    s, n = all_reduce_sum(ctx, [total, float(count)])
    return s / n if n else float("nan")


def _describe(row: dict[str, Any]) -> str:
    """The row's training loss and validation metrics, in the row's order."""
    shown = [k for k in row if k == "train_loss" or k.startswith("val_")]
    return ", ".join(f"{k} {row[k]:.4g}" for k in shown)
