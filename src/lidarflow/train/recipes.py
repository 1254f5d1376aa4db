"""The named training recipes (`lidarflow train --recipe NAME`): each a function returning a
fresh :class:`~lidarflow.train.config.TrainConfig`, whose dataclass defaults stay the paper's."""

from __future__ import annotations

from collections.abc import Callable

from lidarflow.errors import TrainError
from lidarflow.losses import LossConfig
from lidarflow.models.config import HeadConfig
from lidarflow.train.config import TrainConfig

__all__ = ["DEFAULT_FLOWNET_RECIPE", "RECIPES", "default_recipe", "recipe"]


def _paper() -> TrainConfig:
    return TrainConfig(recipe="paper", loss=LossConfig.paper())


def _blurred() -> TrainConfig:
    return TrainConfig(recipe="blurred", loss=LossConfig.blurred_both())


def _head() -> TrainConfig:
    """An occupancy head trained by cross-entropy on top of a trained, nearly frozen flow
    network given as ``model.init`` (``--init RUN``; the bundled model has no flow network).
    Half the windows lose their poses, so the ego-motion model learns both ways
    (``docs/research/leave_one_out/``, ``docs/research/online_decision/``)."""
    # The warp loss blurred on both sides keeps the (nearly frozen) flow where it was.
    config = TrainConfig(recipe="head", loss=LossConfig.blurred_both().replace(occupancy_bce=1.0))
    config.model.head = HeadConfig(
        memory_decays=(0.5, 0.8, 0.95, 0.98, 0.995),
        constant_velocity_input=True,
        shift_memories=True,
        hidden_channels=16,
        visibility_input=True,
        subcell_input=True,
    )
    config.model.ego_motion = config.model.poses_optional = True
    config.decision.online = True
    # The head keeps walls but lets passers-by fade; a tracker's objects laid over its map
    # carry them forward (docs/research/carry_movers/; the head is trained as before).
    config.decision.movers = True
    config.model.init = "bundled"
    # The flow keeps its weights (Adam moves each by about lr per step: 1e-6 x a few hundred
    # steps); the head learns at 0.03.
    config.optim.lr = 1e-6
    config.optim.head_lr_scale = 30_000.0
    config.optim.batch_size = 4
    config.optim.epochs = 3
    config.schedule.lr_step_epochs = 3
    config.schedule.gaussian_step_epochs = 2
    config.data.seq_len = 16
    config.data.warmup = 6
    config.data.stride = 8
    config.data.epoch_windows = 200
    config.data.pose_dropout = 0.5
    config.data.memories_from_stream = True
    config.schedule.gaussian_start = 1
    # bf16 where the machine computes it natively (the bundled model was trained under it);
    # emulated bf16 is far slower than fp32 (docs/guide/training.md).
    config.runtime.amp = "auto"
    config.runtime.channels_last = True
    return config


def _head_only() -> TrainConfig:
    """The ``head`` recipe without the flow network (``docs/research/flow_share/``), at the
    ``head`` recipe's head rate."""
    config = _head()
    config.recipe = "head_only"
    config.model.flow = None
    config.loss = config.loss.replace(warp=0.0)
    config.schedule.gaussian = False
    config.optim.lr = 0.03
    config.optim.head_lr_scale = 1.0
    return config


def _sogmp() -> TrainConfig:
    """SOGMP's own recipe, as its public training code sets it
    (``docs/research/peer_comparison/``). The batch and epochs are a GPU's: on a CPU give
    ``--batch-size`` and ``--epochs``, or ``--max-minutes``, that fit."""
    config = TrainConfig(recipe="sogmp", loss=LossConfig(kl_weight=0.01))
    config.model.name = "sogmp"
    config.model.ego_motion = config.model.poses_optional = True
    config.optim.lr = 1e-4
    config.optim.weight_decay = 1e-3
    config.optim.batch_size = 13  # x 10 counted pairs: the peer's batch of 128 predictions
    config.optim.epochs = 50
    config.schedule.lr_gamma = 1.0  # constant
    config.schedule.lr_step_epochs = 50
    config.schedule.gaussian = False  # the flow loss's filter: no part of this loss
    config.data.seq_len = 20
    config.data.warmup = 9
    config.data.stride = 10
    return config


def _supervised_flow() -> TrainConfig:
    """The flow network alone, with ego motion, taught by the simulator's exact flow
    (:mod:`lidarflow.flow_supervision`), no warp loss; needs ``lidarflow simulate`` recordings.
    Fit a head on top with ``--recipe head --init RUN``."""
    config = TrainConfig(recipe="supervised_flow", loss=LossConfig(warp=0.0, flow_epe=1.0))
    config.model.ego_motion = config.model.poses_optional = True
    # Short windows: a dense loss needs little warm-up, and every frame after it is taught.
    config.data.seq_len = 12
    config.data.warmup = 4
    config.data.stride = 6
    config.data.epoch_windows = 120
    # Adam at the paper's 0.01 (a zero-initialised flow head barely moves at lower rates);
    # clipped, as a dense loss on a moving platform gives large early gradients.
    config.optim.lr = 0.01
    config.optim.batch_size = 4
    config.optim.epochs = 40
    config.optim.grad_clip = 10.0
    config.schedule.lr_step_epochs = 12
    config.schedule.gaussian = False  # no warp loss to filter
    config.runtime.amp = "auto"
    return config


RECIPES: dict[str, Callable[[], TrainConfig]] = {
    "paper": _paper,  # the loss exactly as written in the paper (Table II reproduction)
    "blurred": _blurred,  # both sides of the loss blurred: zero flow is optimal when nothing moves
    "head": _head,  # the head on a trained flow network: the bundled one up to v8
    "head_only": _head_only,  # the same head without the flow network: the bundled one (v9)
    "sogmp": _sogmp,  # the SOGMP peer's own recipe
    "supervised_flow": _supervised_flow,  # the flow taught by simulated exact flow
}


#: LiDAR-FlowNet's default recipe: ``head_only``, the ``head`` recipe's head without the flow
#: network, which bought nothing leave-one-recording-out; ``head`` fits a head onto a
#: flow network of your own (``--init RUN``).
DEFAULT_FLOWNET_RECIPE = "head_only"


def default_recipe(model: str | None = None, ego_motion: bool = False) -> str:
    """The recipe `lidarflow train` uses when none is named: :data:`DEFAULT_FLOWNET_RECIPE` for
    LiDAR-FlowNet, SOGMP's own for SOGMP, the paper's for DeepTracking and ego-motion models."""
    if model == "sogmp":
        return "sogmp"
    return DEFAULT_FLOWNET_RECIPE if model in (None, "flownet") and not ego_motion else "paper"


def recipe(name: str) -> TrainConfig:
    """A fresh config of the named recipe."""
    if name not in RECIPES:
        raise TrainError(f"unknown recipe {name!r}; known: {', '.join(sorted(RECIPES))}")
    return RECIPES[name]()
