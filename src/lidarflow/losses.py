"""The self-supervised losses: LiDAR-FlowNet's warp loss (paper eq. 3, design notes section 4),
DeepTracking's cross-entropy and SOGMP's cross-entropy plus KL.

Indexing (every loss): ``seq`` is ``(B, T, 2, H, W)`` with channels ``(O, V)``; the output at
index ``t`` has seen frames ``0..t`` and speaks about the pair ``(t, t+1)``. Pairs
``t = warmup .. T-2`` are counted, and every counted cell of every pair weighs the same (a pooled,
possibly weighted, mean). The paper's loss is ``LossConfig.paper()``, the default:

    L = MSE(O^t, W(G(O^{t+1}, k), F^t)) + MSE(O^{t+1}, W(G(O^t, k), B^t))
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from lidarflow.ops.gaussian import gaussian_blur
from lidarflow.ops.warp import warp

_EPS = 1e-6


@dataclass(frozen=True)
class LossConfig:
    """What the flow loss blurs, masks, weights and adds. Defaults = the paper's loss.

    Attributes:
        blur_source: filter the map being warped, ``W(G(O^t, k), B)`` (the paper).
        blur_target: filter the map compared against, ``G(O^{t+1}, k)`` (not in the paper).
        smoothness: weight of a first-order L1 flow smoothness term,
            ``mean |d flow / d col| + mean |d flow / d row|`` over all four flow channels.
        visible_only: count only the cells visible in the target frame (``V^{t+1}`` for the
            backward term, ``V^t`` for the forward term).
        occupied_weight: weight of cells occupied in the (unblurred) target relative to free
            ones; the data term is the weighted mean ``sum(w e) / sum(w)``, so 1 is plain MSE.
        bce: binary cross-entropy of the warped map (clamped to [eps, 1 - eps]) against the
            target instead of the squared error.
        forward_term: include ``MSE(O^t, W(G(O^{t+1}, k), F^t))`` (the paper does).
        occupancy_bce: weight of the cross-entropy of the predicted next map against
            ``O^{t+1}`` (models with an occupancy head, :func:`next_map_bce`); 0 = off.
        occupancy_visible_only: count only cells visible in ``O^{t+1}`` in that term. Off by
            default: the metric scores every cell, an occluded one as free.
        occupancy_changed_weight: in that term, the weight of cells that change between
            ``O^t`` and ``O^{t+1}`` relative to the others (1 = plain mean).
        kl_weight: SOGMP only (:func:`sogmp_loss`): the weight ``beta`` of its latent's KL
            divergence from the prior (the peer's 0.01).
        warp: weight of the self-supervised warp loss above (1 = the paper; 0 = off, e.g.
            when only the exact flow teaches, ``flow_epe``).
        flow_epe: weight of the supervised end-point error against exact (simulated) flow,
            :func:`lidarflow.flow_supervision.window_flow_loss`; 0 = off. Needs recordings
            with ground-truth flow.
        flow_epe_moving_weight: in that term, the weight of a moving cell (its exact flow
            differs from the platform's by more than ``flow_epe_moving_threshold`` cells)
            relative to a static one.
        flow_epe_moving_threshold: that threshold, in cells per frame.
    """

    blur_source: bool = True
    blur_target: bool = False
    smoothness: float = 0.0
    visible_only: bool = False
    occupied_weight: float = 1.0
    bce: bool = False
    forward_term: bool = True
    occupancy_bce: float = 0.0
    occupancy_visible_only: bool = False
    occupancy_changed_weight: float = 1.0
    kl_weight: float = 0.01
    warp: float = 1.0
    flow_epe: float = 0.0
    flow_epe_moving_weight: float = 10.0
    flow_epe_moving_threshold: float = 0.15

    def __post_init__(self) -> None:
        non_negative = ("smoothness", "occupancy_bce", "kl_weight", "warp", "flow_epe")
        for name in (*non_negative, "flow_epe_moving_weight", "flow_epe_moving_threshold"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("occupied_weight", "occupancy_changed_weight"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")

    @classmethod
    def paper(cls) -> LossConfig:
        """The literal paper loss: filter on the warped (source) side only, MSE, both terms."""
        return cls()

    @classmethod
    def blurred_both(cls) -> LossConfig:
        """Source and target both filtered: ``MSE(G(O^{t+1}), W(G(O^t), B))`` and the forward
        term alike: zero flow is the minimum where nothing moves, so no collapse."""
        return cls(blur_target=True)

    def replace(self, **changes: object) -> LossConfig:
        """A copy with ``changes`` applied (validated)."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]


def flow_loss(
    seq: Tensor, flows: Tensor, kernel_size: int, config: LossConfig | None = None, warmup: int = 10
) -> Tensor:
    """Self-supervised warp loss of LiDAR-FlowNet, a scalar: the backward term, plus the
    forward term (if enabled), plus ``smoothness`` x the smoothness term.

    Args:
        seq: ``(B, T, 2, H, W)`` maps, channels ``(O, V)``.
        flows: ``(B, T, 4, H, W)`` model outputs, channels ``B_col, B_row, F_col, F_row`` (cells);
            ``flows[:, t]`` relates frames ``t`` and ``t + 1``.
        kernel_size: Gaussian filter size ``k`` (odd; 1 = no filter).
        config: loss variant; ``None`` = :meth:`LossConfig.paper`.
        warmup: pairs ``t < warmup`` are not counted.
    """
    config = LossConfig.paper() if config is None else config
    _check(seq, flows, 4, warmup)
    # The loss is always computed in the maps' precision (fp32), also under bf16 autocast: the
    # blur and the warp would otherwise round occupancy differences the loss is made of.
    with torch.autocast(seq.device.type, enabled=False):
        return _flow_loss(seq, flows.to(seq.dtype), kernel_size, config, warmup)


def _flow_loss(
    seq: Tensor, flows: Tensor, kernel_size: int, config: LossConfig, warmup: int
) -> Tensor:
    b, t, _, h, w = seq.shape
    n = t - 1 - warmup
    # All pairs at once: (B, n, ...) -> (B * n, ...), one blur and one warp per direction.
    cur = seq[:, warmup : t - 1, :2].reshape(b * n, 2, h, w)
    nxt = seq[:, warmup + 1 :, :2].reshape(b * n, 2, h, w)
    flow = flows[:, warmup : t - 1].reshape(b * n, 4, h, w)

    loss = _warp_term(cur, nxt, flow[:, 0:2], kernel_size, config)
    if config.forward_term:
        loss = loss + _warp_term(nxt, cur, flow[:, 2:4], kernel_size, config)
    if config.smoothness > 0.0:
        dcol = (flow[..., :, 1:] - flow[..., :, :-1]).abs().mean()
        drow = (flow[..., 1:, :] - flow[..., :-1, :]).abs().mean()
        loss = loss + config.smoothness * (dcol + drow)
    return loss


def _warp_term(
    source: Tensor, target: Tensor, flow: Tensor, kernel_size: int, config: LossConfig
) -> Tensor:
    """Data term of one direction: compare ``target``'s occupancy with ``W(G(source O), flow)``."""
    src_occ = source[:, 0:1]
    tgt_occ = target[:, 0:1]
    if config.blur_source:
        src_occ = gaussian_blur(src_occ, kernel_size)
    predicted = warp(src_occ, flow)
    reference = gaussian_blur(tgt_occ, kernel_size) if config.blur_target else tgt_occ
    if config.bce:
        err = F.binary_cross_entropy(
            predicted.clamp(_EPS, 1.0 - _EPS), reference.clamp(0.0, 1.0), reduction="none"
        )
    else:
        err = (predicted - reference).square()
    weight = None
    if config.occupied_weight != 1.0:
        weight = 1.0 + (config.occupied_weight - 1.0) * (tgt_occ > 0.5).to(err.dtype)
    if config.visible_only:
        vis = target[:, 1:2].to(err.dtype)
        weight = vis if weight is None else weight * vis
    if weight is None:
        return err.mean()
    return (err * weight).sum() / weight.sum().clamp_min(1.0)


def deeptracking_loss(
    seq: Tensor,
    logits: Tensor,
    warmup: int = 10,
    visible_only: bool = True,
    changed_weight: float = 1.0,
) -> Tensor:
    """DeepTracking's published loss, also LiDAR-FlowNet's occupancy-head term: binary
    cross-entropy of the logits ``(B, T, 1, H, W)``, ``logits[:, t]`` predicting ``O^{t+1}``.

    With ``visible_only`` (Ondruska & Posner 2016) only cells visible in the target frame count:
    an occluded cell's state is not observed, so it must not be taught as free.
    ``changed_weight`` weighs the cells that differ between ``O^t`` and ``O^{t+1}`` that many
    times the others (a weighted mean).
    """
    _check(seq, logits, 1, warmup)
    t = seq.shape[1]
    target = seq[:, warmup + 1 :, 0:1]
    pred = logits[:, warmup : t - 1].to(seq.dtype)
    with torch.autocast(seq.device.type, enabled=False):
        err = F.binary_cross_entropy_with_logits(pred, target, reduction="none")
    weight = seq[:, warmup + 1 :, 1:2] if visible_only else torch.ones_like(err)
    if changed_weight != 1.0:
        changed = (target != seq[:, warmup : t - 1, 0:1]).to(err.dtype)
        weight = weight * (1.0 + (changed_weight - 1.0) * changed)
    return (err * weight).sum() / weight.sum().clamp_min(1.0)


next_map_bce = deeptracking_loss


def sogmp_loss(seq: Tensor, out: Tensor, warmup: int = 9, kl_weight: float = 0.01) -> Tensor:
    """SOGMP's loss (Xie & Dames 2023, as its public training code computes it): per map, the
    binary cross-entropy against ``O^{t+1}`` summed over every cell, plus ``kl_weight`` x the
    step's KL divergence from ``N(0, I)``; averaged over windows and pairs.

    ``out`` ``(B, T, 2, H, W)`` is :class:`~lidarflow.models.sogmp.SOGMP`'s output: channel 0
    the next-occupancy logit, channel 1 the KL spread over the cells. Sums per map (not means)
    keep the peer's balance between the two terms.
    """
    _check(seq, out, 2, warmup)
    t = seq.shape[1]
    target = seq[:, warmup + 1 :, 0:1]
    pred = out[:, warmup : t - 1].to(seq.dtype)
    with torch.autocast(seq.device.type, enabled=False):
        bce = F.binary_cross_entropy_with_logits(pred[:, :, :1], target, reduction="none")
    per_map = bce.sum(dim=(2, 3, 4)) + kl_weight * pred[:, :, 1].sum(dim=(2, 3))
    return per_map.mean()


def gaussian_schedule(epoch: int, start: int = 9, step_epochs: int = 25, minimum: int = 1) -> int:
    """The paper's filter size at 0-based ``epoch``: ``start``, minus 2 every ``step_epochs``
    epochs, never below ``minimum``.

    >>> [gaussian_schedule(e) for e in (0, 24, 25, 50, 75, 99, 100, 199)]
    [9, 9, 7, 5, 3, 3, 1, 1]
    """
    if epoch < 0:
        raise ValueError(f"epoch must be >= 0, got {epoch}")
    if start % 2 == 0 or minimum % 2 == 0 or minimum < 1 or start < minimum:
        raise ValueError(
            f"start and minimum must be odd with 1 <= minimum <= start, got {start}, {minimum}"
        )
    if step_epochs < 1:
        raise ValueError(f"step_epochs must be >= 1, got {step_epochs}")
    return max(minimum, start - 2 * (epoch // step_epochs))


def _check(seq: Tensor, out: Tensor, channels: int, warmup: int) -> None:
    # Channels past (O, V) are model inputs only (e.g. subcell_input's); the losses use O and V.
    if seq.dim() != 5 or seq.shape[2] < 2:
        raise ValueError(f"seq must be (B, T, C >= 2, H, W), got {tuple(seq.shape)}")
    b, t, _, h, w = seq.shape
    if out.shape != (b, t, channels, h, w):
        raise ValueError(
            f"model output must be (B, T, {channels}, H, W) = {(b, t, channels, h, w)} to match "
            f"seq {tuple(seq.shape)}, got {tuple(out.shape)}"
        )
    if not 0 <= warmup <= t - 2:
        raise ValueError(
            f"warmup must be in [0, T - 2] so at least one pair is counted; got warmup={warmup} "
            f"with T={t}: use longer sequences or a shorter warm-up"
        )
