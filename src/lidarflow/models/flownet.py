"""LiDAR-FlowNet, exactly Table I of the paper (design notes section 4).

    input (O, V)      2 x H x W
    conv0             3x3, 16 ch, d 1, p 1       (+ ReLU, see below)
    gru0 / gru1 / gru2 ConvGRU 16 ch, 3x3, dilation 1 / 2 / 4, 'same' padding
    conv_flow         3x3, 4 ch, d 1, p 1        -> B_col, B_row, F_col, F_row (cells), linear

42,500 parameters with the bias choice documented in :mod:`lidarflow.models.convgru`.

Activations: the paper names none outside the GRUs. conv_flow is linear (flow is unbounded,
signed). After conv0 we put a ReLU (``conv0_activation="relu"``, the default; ``"none"`` gives
the purely linear conv0): the paper calls conv0 a feature extractor, and without a non-linearity
conv0 would merely compose with each gate's ``W_x*`` into one larger linear filter. It adds no
parameters, so Table I's count is unchanged.

The flow head starts at zero (``zero_init_flow=True``): the untrained net outputs zero flow, so
its prediction ``W(O^t, 0) = O^t`` is copy-last, the baseline it has to beat (issue 11 measured
this start to train better than a random head).

Occupancy head (``occupancy_head=True``, not in the paper; issue 11). Warping can only move cells
that were seen, and a thresholded warp of a binary map cannot say "this cell flickers" or "this
cell will likely be free". The head keeps, as extra recurrent state, exponential moving averages
``m`` of the occupancy (decays :data:`MEMORY_DECAYS`; what the temporal-average baseline knows),
and a 3x3 convolution over ``(GRU output, O^t, m)`` gives a per-cell residual logit ``r``,
returned as the fifth output channel. The prediction is
``P^{t+1} = sigmoid(g * W(O^t, B^t) + r)`` with a learnt gain ``g``. At initialisation ``r`` is
the constant logit of :data:`FREE_PROBABILITY_INIT` and ``g`` lifts an occupied cell to
:data:`OCCUPIED_PROBABILITY_INIT`: the untrained net is still exactly copy-last at the 0.4
threshold, and a cross-entropy does not first have to pull every free cell down (a symmetric
start at 0.05 / 0.95 did: the bias moved faster than the gain and the first epoch predicted
nothing occupied). Trained with a cross-entropy against ``O^{t+1}``
(:attr:`lidarflow.losses.LossConfig.occupancy_bce`) the output is a probability, which is what
the F1-at-0.4 metric and a planner both want. The flow part is unchanged (42,500 parameters);
the head adds ``(16 + 1 + len(decays)) * 9 + 1`` weights and the gain.

Constant-velocity input (``constant_velocity_input=True``, with the occupancy head; issue 11).
The head also sees the constant-velocity baseline's prediction (the current map moved once more
by the integer shift that best maps the previous map onto it, :mod:`lidarflow.ops.shift`),
kept with the previous map as one more memory channel. On a moving platform the flow network
trained on simulation lost to that baseline on both real recordings; with it as an input the
head can weigh it per cell against the warp and the memories. Its weights start at zero, so the
untrained model is unchanged.

Hidden layer (``head_hidden_channels=N``, with the occupancy head): the head's features go
through a 3x3 convolution to N channels and a ReLU, then the residual logit is a 1x1 convolution
of those. The linear head can only weigh each memory; a cell's next value is not linear in its
past (the per-cell history table, ``experiments/history_rule.py``, beat copy-last's F1 on both
static held-out recordings where the linear head did not). The output convolution starts at
zero, so the untrained model is still copy-last.

Memories that follow the scene (``shift_memories=True``, with the constant-velocity input).
In the sensor's frame a driving robot's world moves, so an exponential moving average of past
maps smears it: on the driving recording the head with still memories lost to the
constant-velocity baseline. With this option each memory is first moved by the frame's shift
(the one the constant-velocity input found, previous map -> current map), then updated, so it
averages the world, not the sensor's frame; and the head sees the memories moved once more (into
the next frame, as the constant-velocity map is). Where nothing moves the shift is zero and the
model is the one without the option, weight for weight (so a head trained without it is a valid
start).

Visibility and warp inputs (``visibility_input=True``, ``warp_input=True``, with the occupancy
head; issue 11). The head also sees ``V^t`` (a cell occupied in a memory but not visible now is
hidden behind something and likely still there; one seen free now has likely gone) and the
flow network's warp ``W(O^t, B^t)`` itself (with it the head can tell, per cell, where the warp
and the constant-velocity map disagree, and lean on the one its other inputs favour; without it
the warp reaches the prediction only through the global gain ``g``). Their weights in the head's
first layer start random like the others', and the output layer at zero, so the untrained model
is still copy-last. ``visibility_memories=True`` also keeps one memory of ``V`` per decay, moved
with the occupancy memories: how often a cell is seen at all. Two thirds of the cells that change
on the static development recordings appear from or vanish into a cell not visible in the other
frame (a return jittering along its beam behind a surface's edge); such cells are seldom
visible, open floor nearly always. Measured leave-one-out on two folds, it did not help the
recording it was meant for (docs/results/accuracy/positive_4/): off by default.

A head of each cell's own past (``head_kernel_size=1``, ``head_flow_features=False``, with the
occupancy head; issue 11). The head sees, per cell, only the current map, its memories and the
constant-velocity map (no neighbours, no GRU features). Why try it: a classifier of each cell's
memories did better on the 180-degree recording it had not seen without neighbour features than
with them (the others are 270-degree hokuyos). With fixed decision offsets it did not win that
recording in the model's own leave-one-out folds (docs/results/accuracy/loo/screen_cell_warm/);
with the offsets chosen online it wins it and 5 of the 6 others, which the default head with
the same online decision does not (docs/results/accuracy/loo/online/), so the ``head`` recipe
uses it. Motion still reaches the prediction through the flow's warp and the shifted memories.

Where the returns lie inside their cells (``subcell_input=True``, with the occupancy head;
issue 11). Maps then have four channels, ``(O, V, edge, near)`` (:func:`lidarflow.scan.
subcell_batch`): a cell whose returns all lie at its border, and a cell that a neighbour's return
lies against. Most cells that change on a static scene are a return crossing a cell edge along
its beam; the binary map cannot see it coming, these two channels can. Only the head sees them
(the flow network's input stays Table I's ``(O, V)``); their weights start random like the
head's other inputs', the output layer at zero, so the untrained model is still copy-last.

How often a cell changes (``transition_memories=True``, with the constant-velocity input).
Two more memories (decay :data:`TRANSITION_DECAY`): of the cell appearing (free in the previous
map, moved with the memories, occupied now) and of it vanishing. Occupancy memories say how
often a cell is occupied, not how often it flips: a cell occupied half the time may alternate
every frame or hold for seconds. Keyed into the causal history table, a cell's own rate of
leaving its state lifted the 180-degree recording by 0.013 (docs/results/accuracy/positive_4/
history_keys/). In the model, leave-one-out on all seven folds, it moved that recording by
+0.003 and the summed margin not at all (history_keys/transition_memories/): off by default.

Offsets chosen online (``online_decision=True``, with the occupancy head; issue 11). The model
is unchanged; the flag tells ``evaluate`` and the ``Predictor`` to re-decide its probabilities
with the decision offsets that have done best on the stream so far
(:mod:`lidarflow.predict.decision`).

Grid size is not fixed: every layer is a 'same' convolution. ``forward`` has no data-dependent
Python branching, so ``step`` exports to ONNX unchanged.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from lidarflow.models.convgru import ConvGRUCell
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.ops.shift import apply_shift, best_shift_kernel
from lidarflow.ops.warp import warp

ACTIVATIONS = ("relu", "none")
# Roughly what copy-last's cells do on the development recordings: a free cell stays free,
# an occupied one stays occupied nine times in ten.
FREE_PROBABILITY_INIT = 0.01
OCCUPIED_PROBABILITY_INIT = 0.9
# A fast and a slow memory: about 2 and 5 frames, the windows of short temporal averages.
MEMORY_DECAYS = (0.5, 0.8)
# About the last 50 frames: the history table's transition rates did best at this decay.
TRANSITION_DECAY = 0.98
#: Names (prefixes) of the occupancy head's parameters: everything else is Table I's network.
OCCUPANCY_HEAD_PARAMETERS = ("conv_occupancy.", "occupancy_hidden.", "warp_gain")
# The frame count of the bias-corrected memories stops here: d^n is 0 in float32 long before.
_MAX_FRAMES_COUNTED = 10_000.0


class LidarFlowNet(RecurrentMapModel):
    """LiDAR-FlowNet. ``step((O, V) (B, 2, H, W), state) -> (flow (B, 4, H, W), state)``.

    State: one ``(B, hidden, H, W)`` tensor per GRU (three). Output channels, in cells:
    ``B_col, B_row, F_col, F_row`` with ``O^{t+1}(p) = O^t(p + B(p))`` and
    ``O^t(p) = O^{t+1}(p + F(p))`` (design notes section 3).

    >>> import torch
    >>> net = LidarFlowNet()
    >>> flow, state = net.step(torch.zeros(1, 2, 12, 10), net.init_state(1, 12, 10))
    >>> tuple(flow.shape), len(state), sum(p.numel() for p in net.parameters())
    ((1, 4, 12, 10), 3, 42500)
    """

    out_channels: int = 4  # 5 with the occupancy head (channel 4: residual logit)
    memory_decays: tuple[float, ...] = ()
    memory_bias_correction: bool = False
    decision_offset: float = 0.0
    decision_offset_free: float | None = None
    constant_velocity_input: bool = False
    head_hidden_channels: int = 0
    shift_memories: bool = False
    visibility_input: bool = False
    visibility_memories: bool = False
    warp_input: bool = False
    head_kernel_size: int = 3
    head_flow_features: bool = True
    online_decision: bool = False
    subcell_input: bool = False
    transition_memories: bool = False

    def __init__(
        self,
        in_channels: int = 2,
        hidden_channels: int = 16,
        dilations: tuple[int, ...] = (1, 2, 4),
        kernel_size: int = 3,
        conv0_activation: str = "relu",
        zero_init_flow: bool = True,
        occupancy_head: bool = False,
        memory_decays: tuple[float, ...] = MEMORY_DECAYS,
        memory_bias_correction: bool = False,
        decision_offset: float = 0.0,
        decision_offset_free: float | None = None,
        constant_velocity_input: bool = False,
        head_hidden_channels: int = 0,
        shift_memories: bool = False,
        visibility_input: bool = False,
        visibility_memories: bool = False,
        warp_input: bool = False,
        head_kernel_size: int | None = None,
        head_flow_features: bool = True,
        online_decision: bool = False,
        subcell_input: bool = False,
        transition_memories: bool = False,
    ) -> None:
        super().__init__()
        if conv0_activation not in ACTIVATIONS:
            raise ValueError(
                f"conv0_activation must be one of {ACTIVATIONS}, got {conv0_activation!r}"
            )
        pad = kernel_size // 2
        self.hidden_channels = hidden_channels
        self.occupancy_head = occupancy_head
        self.out_channels = 5 if occupancy_head else 4
        if occupancy_head:
            if not all(0.0 <= d < 1.0 for d in memory_decays):
                raise ValueError(f"memory_decays must be in [0, 1), got {memory_decays}")
            self.memory_decays = tuple(float(d) for d in memory_decays)
            self.memory_bias_correction = bool(memory_bias_correction)
            self.constant_velocity_input = bool(constant_velocity_input)
            if head_hidden_channels < 0:
                raise ValueError(f"head_hidden_channels must be >= 0, got {head_hidden_channels}")
            self.head_hidden_channels = int(head_hidden_channels)
            if shift_memories and not constant_velocity_input:
                raise ValueError(
                    "shift_memories needs constant_velocity_input=True (it finds the shift)"
                )
            self.shift_memories = bool(shift_memories)
            self.visibility_input = bool(visibility_input)
            self.visibility_memories = bool(visibility_memories)
            self.warp_input = bool(warp_input)
            self.head_kernel_size = kernel_size if head_kernel_size is None else head_kernel_size
            if self.head_kernel_size < 1 or self.head_kernel_size % 2 == 0:
                raise ValueError(f"head_kernel_size must be odd and >= 1, got {head_kernel_size}")
            self.head_flow_features = bool(head_flow_features)
            self.subcell_input = bool(subcell_input)
            if transition_memories and not constant_velocity_input:
                raise ValueError(
                    "transition_memories needs constant_velocity_input=True (the previous map)"
                )
            self.transition_memories = bool(transition_memories)
        elif (
            visibility_input or visibility_memories or warp_input or subcell_input
            or transition_memories
        ):  # fmt: skip
            raise ValueError(
                "visibility_input, visibility_memories, warp_input, subcell_input and "
                "transition_memories need occupancy_head=True (they feed it)"
            )
        elif head_kernel_size is not None or not head_flow_features:
            raise ValueError(
                "head_kernel_size and head_flow_features need occupancy_head=True (the head's)"
            )
        elif shift_memories:
            raise ValueError("shift_memories needs occupancy_head=True (they are the head's)")
        elif head_hidden_channels:
            raise ValueError("head_hidden_channels needs occupancy_head=True (it is the head's)")
        elif decision_offset or decision_offset_free is not None or online_decision:
            raise ValueError("decision offsets need occupancy_head=True (they shift its logit)")
        elif constant_velocity_input:
            raise ValueError("constant_velocity_input needs occupancy_head=True (it feeds it)")
        # Added to the head's logit when predicting, never in training (the cross-entropy
        # keeps the probabilities calibrated): cross-entropy makes the head predict a change
        # only when it is likelier than the 0.4 threshold, so a model tuned for calibration
        # gives up most cells that change; a small positive offset, chosen on the training
        # recordings (experiments/decision_offset.py), buys them back at a small price in F1.
        self.decision_offset = float(decision_offset)
        # The offset of the cells free in the last map moved into the next frame (the warp), where
        # ``decision_offset`` is then the occupied cells' own. A cell's change is a different bet
        # each way: an occupied cell predicted free gains only if it empties, a free one
        # predicted occupied only if it fills, and the two are not equally likely at the same
        # logit. Fixed, chosen on the training recordings, two offsets did not win
        # demo_stationary (docs/results/accuracy/loo/screen_cell_warm/); chosen online as the
        # stream goes (online_decision below) they do.
        # ``None``: the same offset.
        self.decision_offset_free = (
            None if decision_offset_free is None else float(decision_offset_free)
        )
        # Not used by the network: it tells the streaming users (evaluate, the Predictor) to
        # choose the offsets online, on the stream's own past frames, starting from these
        # (lidarflow.predict.decision).
        self.online_decision = bool(online_decision)
        self.conv0 = nn.Conv2d(in_channels, hidden_channels, kernel_size, padding=pad)
        self.act0 = nn.ReLU() if conv0_activation == "relu" else nn.Identity()
        self.grus = nn.ModuleList(
            ConvGRUCell(hidden_channels, hidden_channels, kernel_size, dilation=d)
            for d in dilations
        )
        self.conv_flow = nn.Conv2d(hidden_channels, 4, kernel_size, padding=pad)
        if zero_init_flow:
            nn.init.zeros_(self.conv_flow.weight)
            nn.init.zeros_(self.conv_flow.bias)
        if occupancy_head:
            free, occupied = (
                math.log(p / (1.0 - p)) for p in (FREE_PROBABILITY_INIT, OCCUPIED_PROBABILITY_INIT)
            )
            features = hidden_channels * int(self.head_flow_features) + 1
            features += self.memory_channels + int(self.constant_velocity_input)
            features += int(self.visibility_input) + int(self.warp_input)
            features += 2 * int(self.subcell_input)
            head_k = self.head_kernel_size
            if self.head_hidden_channels:
                hidden = self.head_hidden_channels
                self.occupancy_hidden = nn.Conv2d(features, hidden, head_k, padding=head_k // 2)
                self.conv_occupancy = nn.Conv2d(hidden, 1, 1)
            else:
                self.conv_occupancy = nn.Conv2d(features, 1, head_k, padding=head_k // 2)
            nn.init.zeros_(self.conv_occupancy.weight)
            nn.init.constant_(self.conv_occupancy.bias, free)
            self.warp_gain = nn.Parameter(torch.tensor(occupied - free))

    @property
    def input_channels(self) -> int:
        """Channels of the maps ``step`` takes: ``(O, V)``, and ``(edge, near)`` with
        ``subcell_input``."""
        return 4 if self.subcell_input else 2

    def state_channels(self) -> tuple[int, ...]:
        """Three GRU states, then (occupancy head) one tensor of occupancy memories (and, with
        bias correction, one more channel counting the frames seen; with the constant-velocity
        input, one more holding the previous occupancy)."""
        grus = tuple(cell.hidden_channels for cell in self.grus)
        if not self.occupancy_head:
            return grus
        extra = int(self.memory_bias_correction) + int(self.constant_velocity_input)
        return (*grus, self.memory_channels + extra)

    @property
    def memory_channels(self) -> int:
        """The head's memories: one per decay of the occupancy, with ``visibility_memories``
        one per decay of the visibility too, and with ``transition_memories`` two more."""
        per_decay = len(self.memory_decays) * (1 + int(self.visibility_memories))
        return per_decay + 2 * int(self.transition_memories)

    def step(self, maps: Tensor, state: tuple[Tensor, ...]) -> tuple[Tensor, tuple[Tensor, ...]]:
        """One frame: ``maps`` (O, V) ``(B, 2, H, W)`` (with ``subcell_input`` (O, V, edge,
        near) ``(B, 4, H, W)``) and the state -> output and new state."""
        x = self.act0(self.conv0(maps[:, :2] if self.subcell_input else maps))
        new_state = []
        for cell, y_prev in zip(self.grus, state, strict=False):
            x = cell(x, y_prev)
            new_state.append(x)
        flow = self.conv_flow(x)
        if not self.occupancy_head:
            return flow, tuple(new_state)
        occupancy = maps[:, 0:1]
        k = self.memory_channels
        observed = occupancy
        decays = torch.tensor(self.memory_decays, dtype=maps.dtype, device=maps.device)
        if self.visibility_memories:
            n = len(self.memory_decays)
            decays = torch.cat([decays, decays])
            observed = torch.cat(
                [occupancy.expand(-1, n, -1, -1), maps[:, 1:2].expand(-1, n, -1, -1)], dim=1
            )
        past = state[-1][:, :k]
        if self.constant_velocity_input:
            kernel = best_shift_kernel(state[-1][:, -1:], occupancy)
            if self.shift_memories:
                past = apply_shift(past, kernel)
        if self.transition_memories:
            previous = state[-1][:, -1:]
            if self.shift_memories:
                previous = apply_shift(previous, kernel)
            n = decays.numel()
            observed = torch.cat(
                [
                    observed.expand(-1, n, -1, -1),
                    occupancy * (1.0 - previous),
                    (1.0 - occupancy) * previous,
                ],
                dim=1,
            )
            decays = torch.cat([decays, decays.new_full((2,), TRANSITION_DECAY)])
        decays = decays.view(1, -1, 1, 1)
        memory = decays * past + (1.0 - decays) * observed
        features = [x, occupancy] if self.head_flow_features else [occupancy]
        kept = [memory]
        if not self.memory_bias_correction:
            seen = memory
        else:
            # Memories start at zero, so a slow one is a fraction of the mean it tracks for its
            # first ~1/(1-d) frames: all of a 16-frame training window, none of a long stream.
            # Dividing by 1 - d^n (as Adam does) makes it the weighted mean of the frames seen
            # from the first one on; the zero initial state (also ONNX's) stays the start.
            frames = (state[-1][:, k : k + 1] + 1.0).clamp(max=_MAX_FRAMES_COUNTED)
            seen = memory / (1.0 - decays**frames)
            kept.append(frames)
        if self.constant_velocity_input:
            if self.shift_memories:
                # One apply_shift moves the memories and the map into the next frame together.
                moved = apply_shift(torch.cat([seen, occupancy], dim=1), kernel)
                seen, extrapolated = moved[:, :k], moved[:, k:]
            else:
                extrapolated = apply_shift(occupancy, kernel)
            features.extend((seen, extrapolated))
            kept.append(occupancy)
        else:
            features.append(seen)
        if self.visibility_input:
            features.append(maps[:, 1:2])
        if self.warp_input:
            features.append(warp(occupancy, flow[:, 0:2]).clamp(0.0, 1.0))
        if self.subcell_input:
            features.append(maps[:, 2:4])
        head_input = torch.cat(features, dim=1)
        if self.head_hidden_channels:
            head_input = torch.relu(self.occupancy_hidden(head_input))
        residual = self.conv_occupancy(head_input)
        return torch.cat([flow, residual], dim=1), (*new_state, torch.cat(kept, dim=1))

    def predict_next(self, maps: Tensor, out: Tensor) -> Tensor:
        """``P^{t+1}`` ``(B, 1, H, W)`` from maps ``(B, 2, H, W)`` and the step's output
        ``(B, C, H, W)``: ``clamp(W(O^t, B^t), 0, 1)``, or with the occupancy head
        ``sigmoid(next_logit + offset)``, the offset ``decision_offset`` where the warp is
        occupied and ``decision_offset_free`` where it is free (linear in between)."""
        if not self.occupancy_head:
            return warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)
        warped, logit = self._warp_and_logit(maps, out)
        if self.decision_offset_free is None:
            return torch.sigmoid(logit + self.decision_offset)
        free = self.decision_offset_free
        return torch.sigmoid(logit + free + (self.decision_offset - free) * warped)

    def next_logit(self, maps: Tensor, out: Tensor) -> Tensor:
        """Occupancy head only: ``g * W(O^t, B^t) + r`` ``(B, 1, H, W)``."""
        if not self.occupancy_head:
            raise ValueError("next_logit needs a model built with occupancy_head=True")
        return self._warp_and_logit(maps, out)[1]

    def _warp_and_logit(self, maps: Tensor, out: Tensor) -> tuple[Tensor, Tensor]:
        warped = warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)
        return warped, self.warp_gain * warped + out[:, 4:5]


def lidar_flownet(**kwargs: object) -> LidarFlowNet:
    """The paper's LiDAR-FlowNet (Table I); keyword arguments override :class:`LidarFlowNet`'s."""
    return LidarFlowNet(**kwargs)  # type: ignore[arg-type]


__all__ = ["LidarFlowNet", "lidar_flownet"]
