"""The training loop: model and loss per model type, schedules, metrics, checkpoints, DDP.

``train(config, run_dir)`` runs the whole recipe and returns a :class:`TrainResult`;
``train(..., resume=True)`` continues the run in ``run_dir`` from its newest checkpoint, exactly
as if it had never stopped (same weights, optimizer moments, learning rate, Gaussian size, RNG
state and data order). Non-finite losses or gradients stop the run with :class:`TrainError`
naming the epoch and step; nothing of the failing epoch is written.

A run, in a run folder that :func:`train` locks, and removes again where a new run stops before
its first epoch, goes through these steps in order (what they share is a :class:`_Run`):

1. **Data** (:func:`_load_data`): threads and seeds, then the training and validation windows.
2. **Start** (:func:`_start`): the model (from ``model.init`` on a new run), its optimizer and
   learning-rate schedule, all restored from the newest checkpoint on a resume; the DDP
   wrapper, autocast, the loaders and the logbook. A new run scores the untrained model as
   epoch 0 where it has validation data (``runtime.eval_before_training``).
3. **Epochs**, each (:func:`_fit_epoch`, :func:`_close_epoch`): the batches, one optimizer step
   each; then validation, the row logged, the weights and the checkpoint saved, the checkpoint
   last. The run ends early, resumable, once ``runtime.max_minutes`` is spent.
4. **Finish** (:func:`_finish`): the final weights as ``model.safetensors`` and ``model.json``.

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
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import DataLoader

from lidarflow.errors import ModelError, TrainError
from lidarflow.models import build, uses_ego_motion
from lidarflow.models.speed import accelerate, native_bf16
from lidarflow.train import checkpoint as ckpt
from lidarflow.train.config import TrainConfig
from lidarflow.train.data import TrainData, load_train_data
from lidarflow.train.distributed import Dist, any_flag, barrier, setup
from lidarflow.train.loaders import MixSampler, make_loader, make_val_loader
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
Say = Callable[[str], None]  # a progress line for the user (rank 0's echo; a no-op elsewhere)


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


@dataclass
class _Run:
    """A run under way: what its steps share, and the state it carries from epoch to epoch.

    ``extra`` (the best score so far and the epochs done) goes into every checkpoint and comes
    back on a resume; ``rows`` are this process's rows (every rank computes the same ones);
    ``book`` writes them on rank 0 and is ``None`` elsewhere. ``start`` is the epochs done before
    this process began: 0, or those of the checkpoint resumed from.
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
    data = _load_data(config, say)
    run = _start(config, run_dir, resume, ctx, data, say, began)
    if run.start == 0 and config.runtime.eval_before_training and run.val_loader is not None:
        _score_untrained(run)
    for epoch in range(run.start, config.optim.epochs):
        row = _close_epoch(run, epoch, _fit_epoch(run, epoch))
        if on_epoch_end is not None:
            on_epoch_end(epoch + 1, row)
        if _out_of_time(run, epoch):
            break
    return _finish(run)


def _load_data(config: TrainConfig, say: Say) -> TrainData:
    """Set the threads (``runtime.threads``) and seed every generator with ``runtime.seed``,
    then load the training and validation windows in the form the model takes (motions for an
    ego-motion model, sub-cell input for a head that reads it, flow for a supervised recipe,
    which must find it: :class:`TrainError` otherwise). Says the data's summary and notes."""
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
    """The model of ``config.model`` on ``ctx.device``, accelerated as ``runtime`` asks: from the
    weights of ``model.init`` on a new run (a resume's come from its checkpoint), and with
    every window's start memories streamed into ``data`` where ``data.memories_from_stream``.
    A model that cannot be built or streamed is a :class:`TrainError`."""
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


def _start(
    config: TrainConfig,
    run_dir: Path,
    resume: bool,
    ctx: Dist,
    data: TrainData,
    say: Say,
    began: float,
) -> _Run:
    """Everything the epochs need, on every rank: the model (:func:`_make_model`), its
    optimizer and learning-rate schedule, all three restored from the newest checkpoint on a resume
    (with the RNG states, so that the run goes on as if it had never stopped); the DDP wrapper,
    bf16 autocast (``runtime.amp``), the loaders and, on rank 0, the logbook (a resume's keeps
    the rows up to its checkpoint)."""
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
    return _Run(
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
        autocast=_autocast(bf16, ctx.device),
        book=book,
        start=start,
        extra=extra,
    )


def _score_untrained(run: _Run) -> None:
    """Validate the untrained model as epoch 0 (a new run's first row, in the logbook unless
    it already holds rows)."""
    row = {"epoch": 0, **run.val_metrics(gaussian_size(run.config, 0))}
    run.rows.append(row)
    if run.book is not None and not run.book.rows:
        run.book.log(row)
    run.say("untrained: " + _describe(row))


def _fit_epoch(run: _Run, epoch: int) -> _Fit:
    """Train the 0-based ``epoch``: one optimizer step per batch of the epoch's draw (which
    depends only on the seed and the epoch), gradients clipped to ``optim.grad_clip``, then one
    step of the learning-rate schedule. A step whose loss, gradient norm or output is non-finite
    or beyond ``runtime.divergence_limit`` on any rank raises :class:`TrainError` on every rank
    before the optimizer takes it."""
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
        health = _health(loss, grad_norm, out, clip, limit)
        loss_value = health[0]
        if any_flag(ctx, not all(_healthy(v, limit) for v in health)):
            raise TrainError(
                _diverged(health, limit, epoch, step, len(run.loader), lr, kernel, run.run_dir)
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
    run: _Run, batch: Any, loss_fn: Callable[[Tensor, Tensor], Tensor]
) -> tuple[Tensor, Tensor, Tensor]:
    """A training batch through the model (under autocast, each window from its start state):
    its maps ``(B, T, 2, H, W)`` as float on the device, the model's output ``(B, T, C, H, W)``
    and the loss, plus the supervised flow term where the recipe has one."""
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


def _close_epoch(run: _Run, epoch: int, fit: _Fit) -> dict[str, Any]:
    """Validate the 0-based ``epoch`` just trained, keep its row and the best score so far,
    and on rank 0 log the row and save the last (and best) weights and the checkpoint, the
    checkpoint last: until it is complete, a resume starts from the epoch before, dropping this
    row and overwriting these weights. Returns the row, once every rank has got here."""
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


def _out_of_time(run: _Run, epoch: int) -> bool:
    """Whether the run ends after the 0-based ``epoch``, before its last, because the time
    budget ``runtime.max_minutes`` is spent on any rank (all ranks agree; a resume goes on)."""
    rt, epochs = run.config.runtime, run.config.optim.epochs
    spent = rt.max_minutes > 0 and time.perf_counter() - run.began > 60 * rt.max_minutes
    if any_flag(run.ctx, spent) and epoch + 1 < epochs:
        run.say(
            f"time budget of {rt.max_minutes:g} min spent: the run ends after epoch "
            f"{epoch + 1} of {epochs} (--resume continues it)"
        )
        return True
    return False


def _finish(run: _Run) -> TrainResult:
    """On rank 0, write the final weights (``runtime.final_weights``: the last epoch's or the
    best's) as ``model.safetensors`` with ``model.json``; then, on every rank, the result: the
    logbook's rows on rank 0 (a resume's include those before it), this process's elsewhere."""
    if run.book is not None:
        write_final(run.run_dir, run.config, run.model, run.data, run.extra)
        run.book.close()
    barrier(run.ctx)
    rows = run.book.rows if run.book else run.rows
    return TrainResult(run.run_dir, rows, run.model, run.extra)


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
