"""Training configuration: typed dataclasses whose defaults are the paper's recipe (Section V-A):
windows of 20 frames, 10 of warm-up, batch 32, Adam at 0.01 halved every 25 epochs, 200 epochs,
Gaussian size 9 minus 2 every 25 epochs down to 1. Configurations are built in layers from a
named recipe by :mod:`lidarflow.train.config_io`.
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
    ``name`` (``flownet``, ``deeptracking`` or ``sogmp``), Table I's ``flow`` network (``None``:
    the occupancy head alone), the occupancy ``head`` (``None``: none), the ego-motion wrapper
    (``ego_motion``, ``poses_optional``) and DeepTracking's and SOGMP's own ``options``.
    ``init``: weights to start from (a run folder or weights file of the same architecture, or
    ``"bundled"``); ``None`` starts from scratch.
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
    """How the trained model's next map is decided, ``model.json``'s ``decision`` record (the
    Predictor's policy; training never uses it): ``offset`` added to the head's logit, ``online``
    offsets chosen on the stream, ``movers`` (:class:`lidarflow.predict.decision.DecisionPolicy`).
    """

    offset: float = 0.0
    online: bool = False
    movers: bool = False


@dataclass
class DataConfig:
    """Where the windows come from and how they are split (:mod:`lidarflow.train.data`).

    ``sources``: recordings, bags, folders of ``.npz`` or glob patterns; ``mix``: relative
    sampling weight per source (empty: natural proportions). ``val_split``: ``"tail"`` or
    ``"recordings"``; ``val_sources`` names validation recordings instead. ``pose_dropout``:
    the fraction of training windows served without poses (fixed per window).
    ``memories_from_stream``: windows start from the head's streamed memories
    (:mod:`lidarflow.train.warm`).
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
    ``head_lr_scale``: the occupancy head's learning rate is ``lr`` times this."""

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
    or ``auto`` (:mod:`lidarflow.train.precision`); ``channels_last`` / ``compile``:
    :func:`lidarflow.models.speed.accelerate`; ``threads``: 0 = torch's default.
    ``max_minutes``: a wall-clock budget (0: none): the run stops, resumable, after the first
    epoch that ends past it (``model.json`` says ``epochs_done``).
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
            (0 <= d.pose_dropout <= 1, "data.pose_dropout is a fraction of windows, in [0, 1]"),
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
