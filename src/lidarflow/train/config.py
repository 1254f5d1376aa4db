"""Training configuration: typed dataclasses whose defaults are the paper's recipe.

The paper (Section V-A, design notes §4): sequences of 20 frames, the first 10 only warm up the
hidden state; batch 32; learning rate 0.01 halved every 25 epochs; 200 epochs; Gaussian filter
size 9 at first, minus 2 every 25 epochs down to 1.

The optimiser is **Adam** (``optim.name = "adam"``): the paper does not name it, but its
learning rate of 0.01 with step halving is Adam's regime, not SGD's — the loss is a mean squared
error of order 1e-3 over mostly empty maps, so its raw gradients are tiny and plain SGD at 0.01
barely moves; Adam's per-parameter scaling is what makes such a loss trainable at that rate, and
it is what the FlowNet family of flow networks the paper builds on was trained with. ``sgd`` and
``adamw`` are available as configuration.

A configuration is built in layers from a named *recipe* (:mod:`lidarflow.train.recipes`):
:mod:`lidarflow.train.config_io`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from lidarflow.errors import ScanError, TrainError
from lidarflow.losses import LossConfig
from lidarflow.models.config import MODEL_NAMES, FlowConfig, HeadConfig, ModelSpec
from lidarflow.scan import GridSpec

__all__ = [
    "DataConfig",
    "DecisionConfig",
    "ModelConfig",
    "OptimConfig",
    "RuntimeConfig",
    "ScheduleConfig",
    "TrainConfig",
]


@dataclass
class ModelConfig:
    """Which network to train, typed as the model is built (:class:`lidarflow.models.ModelSpec`):
    ``name`` (``flownet``, ``deeptracking`` or ``sogmp``), Table I's ``flow`` network (``None``,
    ``--set model.flow=null``: none, the occupancy head alone; ``--recipe head_only``), the
    occupancy ``head`` (``None``: none; ``--set model.head.hidden_channels=16`` adds one), the
    ego-motion wrapper (``ego_motion``, ``poses_optional``) and, for DeepTracking and SOGMP,
    their own ``options`` (e.g. ``--set model.options.visibility_input=true``).
    Configs written before the model was built from blocks gave these as one flat
    ``model.kwargs`` table, which is still
    read (:func:`lidarflow.train.config_io.build_config`).

    ``init``: weights to start from instead of the initialisation (a run folder or weights file
    of the same architecture, or ``"bundled"``), e.g. to fine-tune a simulator-pretrained net on
    real recordings; ``None`` (the paper) starts from scratch.
    """

    name: str = "flownet"
    flow: FlowConfig | None = field(default_factory=FlowConfig)
    head: HeadConfig | None = None
    ego_motion: bool = False
    poses_optional: bool = False
    options: dict[str, Any] = field(default_factory=dict)
    init: str | None = None

    def spec(self) -> ModelSpec:
        """The model to build (raises ``ValueError`` naming what does not fit)."""
        return ModelSpec(
            self.name, self.flow, self.head, self.ego_motion, self.poses_optional, self.options
        )


@dataclass
class DecisionConfig:
    """How the trained model's next map is to be decided, written beside it (``model.json``'s
    ``decision`` record): the Predictor's policy, not the model's (training never uses it).
    ``offset`` is added to the occupancy head's logit; ``online``: offsets chosen on the stream
    itself, starting from it (:mod:`lidarflow.predict.decision`); ``movers``: a tracker's moved
    objects join the decided map (:class:`lidarflow.predict.decision.DecisionPolicy`)."""

    offset: float = 0.0
    online: bool = False
    movers: bool = False


@dataclass
class DataConfig:
    """Where the windows come from and how they are split.

    ``sources``: one entry per data *source* (a recording, a bag, a folder of ``.npz``
    recordings or a glob pattern); ``mix``: relative sampling weight per source (empty: every
    window equally likely, i.e. the natural proportions). ``val_split``: ``"tail"`` holds out
    the last ``val_fraction`` of the frames of every recording (a contiguous block, so
    validation windows never overlap training windows in time); ``"recordings"`` holds out
    whole recordings (the last ``ceil(val_fraction * n)`` of them, at least one); ``val_sources``
    names validation recordings explicitly instead. ``pose_dropout`` (ego-motion models only):
    the fraction of training windows served without their poses (identity motion, as a
    recording without odometry), so that a model meant to run both ways (``poses_optional``)
    also learns from a moving platform seen uncompensated; which windows is fixed per window,
    so ``--resume`` sees the same. ``memories_from_stream`` (occupancy-head models): every
    window starts with the head's memories as streaming its recording leaves them at the
    window's first frame, not at zero (:mod:`lidarflow.train.warm`).
    """

    sources: list[str] = field(default_factory=list)
    mix: list[float] = field(default_factory=list)
    val_sources: list[str] = field(default_factory=list)
    val_fraction: float = 0.1
    val_split: str = "tail"
    seq_len: int = 20
    warmup: int = 10
    stride: int = 0  # 0: seq_len (non-overlapping windows, as the paper's 1,800 sequences)
    grid: int = 100
    res: float = 0.1
    topic: str | None = None
    epoch_windows: int = 0  # windows drawn per epoch; 0: the number of training windows
    max_gap_periods: float = 2.5
    num_workers: int = 0
    pose_dropout: float = 0.0
    memories_from_stream: bool = False


@dataclass
class OptimConfig:
    """Optimiser and batch. ``grad_clip``: max global gradient norm, 0 = no clipping (paper).
    ``head_lr_scale``: the occupancy head's learning rate is ``lr`` times this. Its few weights
    start far from where they end (the memory weights and bias move by several logits), and
    Adam moves a weight by about ``lr`` per step, so at the flow's learning rate a CPU-sized
    run of a few hundred steps leaves the head near copy-last."""

    name: str = "adam"
    lr: float = 0.01
    batch_size: int = 32
    epochs: int = 200
    weight_decay: float = 0.0
    momentum: float = 0.9  # sgd only
    grad_clip: float = 0.0
    head_lr_scale: float = 1.0


@dataclass
class ScheduleConfig:
    """Step schedules: the learning rate times ``lr_gamma`` every ``lr_step_epochs``; the
    Gaussian size from ``gaussian_start`` minus 2 every ``gaussian_step_epochs`` down to
    ``gaussian_min``; ``gaussian = False`` is the paper's ablation (no filter at all)."""

    lr_step_epochs: int = 25
    lr_gamma: float = 0.5
    gaussian: bool = True
    gaussian_start: int = 9
    gaussian_step_epochs: int = 25
    gaussian_min: int = 1


AMP_MODES = ("none", "bf16", "auto")


@dataclass
class RuntimeConfig:
    """How the run executes; none of it changes the maths of the fp32 eager reference path.

    ``device``: ``auto`` (CUDA when available), ``cpu``, ``cuda``; ``amp``: ``none``, ``bf16``
    autocast, or ``auto`` (bf16 where the device computes it natively, fp32 elsewhere, where
    emulated bf16 is slower: :func:`lidarflow.models.speed.native_bf16`); ``channels_last`` /
    ``compile``: see :func:`lidarflow.models.speed.accelerate` (compiling costs tens of seconds
    up front on a small CPU, so it pays on long runs only); ``threads``: torch intra-op threads,
    0 = torch's default. ``max_minutes``: a wall-clock budget for this process (0: none): the
    run stops after the first epoch that ends past it, and is finished as if ``optim.epochs``
    were that epoch (``model.json`` says ``epochs_done``; ``--resume`` continues it), so that
    models are compared at equal budgets whatever their speed.
    """

    device: str = "auto"
    amp: str = "none"
    compile: str = "none"  # torch.compile: "cells" (each ConvGRU cell) or "step" (whole step)
    channels_last: bool = False
    threads: int = 0
    max_minutes: float = 0.0
    seed: int = 0
    eval_before_training: bool = True
    final_weights: str = "last"  # which weights become model.safetensors: "last" (paper) or "best"
    tensorboard: bool = True  # used only when tensorboard is installed
    # |loss|, gradient norm or |model output| beyond this stops the run as diverged: a flow of
    # a million cells (or a logit of a million) is divergence in all but name
    divergence_limit: float = 1e6


@dataclass
class TrainConfig:
    """The whole training configuration; ``recipe`` records which preset it started from."""

    recipe: str = "paper"
    model: ModelConfig = field(default_factory=ModelConfig)
    data: DataConfig = field(default_factory=DataConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    loss: LossConfig = field(default_factory=LossConfig.paper)
    runtime: RuntimeConfig = field(default_factory=RuntimeConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)

    def validate(self) -> TrainConfig:
        """Raise :class:`TrainError` naming the first impossible setting; return self."""
        d, o, s, r = self.data, self.optim, self.schedule, self.runtime
        checks = [
            (self.model.name in MODEL_NAMES, f"model.name must be one of {MODEL_NAMES}"),
            (d.seq_len >= 2, "data.seq_len must be at least 2"),
            (0 <= d.warmup < d.seq_len - 1, "data.warmup must be in [0, seq_len - 2]"),
            (d.stride >= 0, "data.stride must be >= 0"),
            (0 <= d.val_fraction < 1, "data.val_fraction must be in [0, 1)"),
            (d.val_split in ("tail", "recordings"), "data.val_split must be tail or recordings"),
            (
                all(w >= 0 for w in d.mix) and (not d.mix or sum(d.mix) > 0),
                "data.mix weights must be >= 0 and not all 0",
            ),
            (d.grid >= 4 and d.res > 0, "data.grid must be >= 4 and data.res > 0"),
            (d.max_gap_periods > 1, "data.max_gap_periods must be > 1 (frame periods)"),
            (
                0 <= d.pose_dropout <= 1,
                "data.pose_dropout is a fraction of windows, in [0, 1]",
            ),
            (o.name in ("adam", "adamw", "sgd"), "optim.name must be adam, adamw or sgd"),
            (
                o.lr > 0 and o.batch_size >= 1 and o.epochs >= 1,
                "optim.lr, optim.batch_size and optim.epochs must be positive",
            ),
            (o.grad_clip >= 0, "optim.grad_clip must be >= 0 (0 = off)"),
            (o.head_lr_scale > 0, "optim.head_lr_scale must be > 0"),
            (
                s.lr_step_epochs >= 1 and s.gaussian_step_epochs >= 1,
                "schedule step lengths must be >= 1 epoch",
            ),
            (
                s.gaussian_start % 2 == 1 and s.gaussian_min % 2 == 1 and s.gaussian_min >= 1,
                "Gaussian sizes must be odd and >= 1",
            ),
            (
                r.device in ("auto", "cpu", "cuda") or r.device.startswith("cuda:"),
                "runtime.device must be auto, cpu or cuda[:N]",
            ),
            (r.amp in AMP_MODES, f"runtime.amp must be one of {', '.join(AMP_MODES)}"),
            (r.compile in ("none", "cells", "step"), "runtime.compile must be none, cells or step"),
            (r.final_weights in ("last", "best"), "runtime.final_weights must be last or best"),
            (r.max_minutes >= 0, "runtime.max_minutes must be >= 0 (0: no budget)"),
            (0 <= r.seed < 2**32, "runtime.seed (--seed) must be in [0, 2**32 - 1]"),
        ]
        for ok, message in checks:
            if not ok:
                raise TrainError(f"bad training config: {message}")
        try:  # the grid's own bound (a size that cannot fit), checked before the run folder
            GridSpec(d.grid, d.grid, d.res)
        except ScanError as err:
            raise TrainError(f"bad training config: data.grid: {err}") from err
        try:
            self.model.spec()
        except (TypeError, ValueError) as err:
            raise TrainError(f"bad training config: model: {err}") from err
        return self
