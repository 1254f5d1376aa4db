"""Validation metrics of one epoch (design notes §5), summed over DDP ranks.

For every counted pair, the predicted next map thresholded at 0.4 against ``O^{t+1}``
(micro-averaged, :func:`confusion`), beside copy-last ``O^t``; ``changed_f1`` only where
``O^t != O^{t+1}``. With ground-truth flow, the end-point error of ``B^t`` over the occupied
cells of ``O^{t+1}`` (``epe``) and over those that truly move (``epe_moving``); ``*_zero``: the
same for zero flow.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import numpy as np
import torch
from torch import Tensor

from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion
from lidarflow.train.distributed import Dist, all_reduce_sum
from lidarflow.train.warm import start_state

__all__ = ["validate"]


def _counts(pred: Tensor, target: Tensor, mask: Tensor | None = None) -> Counts:
    return confusion(
        pred.cpu().numpy(), target.cpu().numpy(), None if mask is None else mask.cpu().numpy()
    )


@torch.no_grad()
def validate(
    model: torch.nn.Module,
    loader: torch.utils.data.DataLoader,
    loss_fn: Callable[[Tensor, Tensor], Tensor],
    warmup: int,
    ctx: Dist,
    autocast: Callable[[], AbstractContextManager[Any]],
    is_flow: bool,
    warm: bool = False,
) -> dict[str, float]:
    """Loss and prediction metrics of ``model`` (the unwrapped module) over ``loader``
    (``warm``: its windows carry the head's streamed start state, :mod:`lidarflow.train.warm`)."""
    model.eval()
    loss_sum = windows = 0.0
    net, copy, net_changed = Counts(), Counts(), Counts()
    epe = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]  # err, err_zero, n, err_moving, err_moving_zero, n_moving
    for maps_u8, flow_gt, has_flow, *motions in loader:  # motions: ego-motion models only
        first = motions.pop() if warm else None  # the head's state streamed to the window
        seq = maps_u8.to(ctx.device).float()
        with autocast():
            state = start_state(model, seq, first)
            out, _ = model(seq, state, *(m.to(ctx.device) for m in motions))
        out = out.float()
        loss_sum += float(loss_fn(seq, out)) * len(seq)
        windows += len(seq)
        now = seq[:, warmup:-1]  # (B, n, C, H, W)
        b, n, _, h, w = now.shape
        step_out = out[:, warmup:-1].reshape(b * n, -1, h, w)
        prob = model.predict_next(now.reshape(b * n, -1, h, w), step_out).reshape(b, n, h, w)
        occ_now = now[:, :, 0] > 0.5
        occ_next = seq[:, warmup + 1 :, 0] > 0.5
        changed = occ_now != occ_next
        predicted = prob >= THRESHOLD
        net += _counts(predicted, occ_next)
        copy += _counts(occ_now, occ_next)
        net_changed += _counts(predicted, occ_next, changed)
        if is_flow and bool(has_flow.any()):
            keep = has_flow.to(ctx.device)
            gt = flow_gt.to(ctx.device)[keep][:, warmup:-1]  # B^t of the counted pairs
            zero = gt.norm(dim=2)
            err = (out[keep][:, warmup:-1, 0:2] - gt).norm(dim=2)
            for i, cells in ((0, occ_next[keep]), (3, zero > 0)):  # occupied, moving
                epe[i] += float(err[cells].sum())
                epe[i + 1] += float(zero[cells].sum())
                epe[i + 2] += float(cells.sum())
    model.train()
    counts = [float(getattr(c, k)) for c in (net, copy, net_changed) for k in ("tp", "fp", "fn")]
    loss_sum, windows, *sums = all_reduce_sum(ctx, [loss_sum, windows, *counts, *epe])
    net, copy, net_changed = (Counts(*map(int, sums[3 * i : 3 * i + 3])) for i in range(3))
    e = sums[9:]
    metrics = {
        "val_loss": loss_sum / windows if windows else float("nan"),
        "val_f1": net.f1,
        "val_copy_last_f1": copy.f1,
        "val_changed_f1": net_changed.f1,
    }
    if e[2] > 0:
        metrics["val_epe"] = e[0] / e[2]
        metrics["val_epe_zero"] = e[1] / e[2]
    if e[5] > 0:
        metrics["val_epe_moving"] = e[3] / e[5]
        metrics["val_epe_moving_zero"] = e[4] / e[5]
    return {k: float(np.float64(v)) for k, v in metrics.items()}
