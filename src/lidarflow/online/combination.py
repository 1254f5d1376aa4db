"""The online combination: the predictors a robot already runs, weighed per horizon by what
the scans that arrive say about them (docs/guide/online.md).

Each frame ``t`` the experts (:mod:`lidarflow.online.experts`) predict ``t + 1 .. t + K``; frame
``t``'s map labels what was predicted for it ``k`` frames before. Per horizon, the stacked
combination (:class:`~lidarflow.online.stacking.HorizonStacking`) learns from that pair, every
candidate is scored on it (:class:`~lidarflow.online.leader.Leader`) and the best lately decides,
the common cells and the rare ones apart. Causal: what is predicted at ``t`` depends on frames
up to ``t`` only.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lidarflow.online.experts import EXPERTS, ExpertMaps
from lidarflow.online.leader import Leader
from lidarflow.online.stacking import DECIDED, HorizonStacking, StackingConfig

if TYPE_CHECKING:
    from lidarflow.predict.engine import Rollout, Step
    from lidarflow.tracking import Tracker

__all__ = ["CANDIDATES", "Combination", "Combined"]

#: The experts laid over each other (the larger probability).
UNIONS = (("model", "tracks"), ("copy_last", "tracks"))

#: The candidates that may decide a kind of cell: each expert alone, the unions, then the
#: stacked combination.
CANDIDATES = (*EXPERTS, *(f"{a}+{b}" for a, b in UNIONS), "stacked")
_UNIONS = [(EXPERTS.index(a), EXPERTS.index(b)) for a, b in UNIONS]


@dataclass(frozen=True)
class Combined:
    """The combination's output for frames ``t + 1 .. t + K``: ``probability`` ``(K, H, W)``
    and ``decided`` ``(K, H, W)``, rescaled so that 0.4 decides as the chosen candidate does."""

    probability: np.ndarray
    decided: np.ndarray


class Combination:
    """The online combination for the frames ``1 .. horizon`` ahead, starting as the model
    alone."""

    def __init__(self, horizon: int, config: StackingConfig | None = None) -> None:
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        self.horizon = horizon
        self.experts = ExpertMaps(horizon)
        config = config or StackingConfig()
        first = EXPERTS.index("model")
        self.stacks = [HorizonStacking(len(EXPERTS), config, first) for _ in range(horizon)]
        # the simple predictors among the candidates, copy-last first (the tolerant F1's judge)
        simple = tuple(CANDIDATES.index(n) for n in ("copy_last", "temporal_average", "tracker"))
        self.leaders = [
            Leader(len(CANDIDATES), first, config.decay, baselines=simple) for _ in range(horizon)
        ]
        self._waiting: list[deque[tuple[np.ndarray, ...]]] = [
            deque(maxlen=k) for k in range(1, horizon + 1)
        ]

    def reset(self) -> None:
        """Forget the stream and what was learnt: back to the model alone."""
        self.experts.reset()
        for stack, leader, waiting in zip(self.stacks, self.leaders, self._waiting, strict=True):
            stack.reset()
            leader.reset()
            waiting.clear()

    def forget_pending(self) -> None:
        """Drop the predictions still waiting for their label (the next frame does not follow
        the last: a new stream, or a gap), keeping what was learnt."""
        for waiting in self._waiting:
            waiting.clear()

    def step(
        self,
        tracker: Tracker,
        step: Step,
        rollout: Rollout,
        occupancy: np.ndarray,
        visibility: np.ndarray,
    ) -> Combined:
        """Learn from the frame whose maps are ``occupancy`` and ``visibility`` ``(H, W)`` as the
        label of the predictions made for it, then combine the experts after the engine's
        ``step`` and its ``rollout`` (an engine that runs ``tracker``) for ``t + 1 .. t + K``."""
        experts = self.experts.of(tracker, step, rollout, occupancy, visibility)
        maps = experts.maps
        occupied = np.asarray(occupancy) > 0.5
        probability, decided = [], []
        for k in range(self.horizon):
            stack, leader, waiting = self.stacks[k], self.leaders[k], self._waiting[k]
            if len(waiting) == k + 1:  # the oldest was made k + 1 frames ago: for this frame
                stored, rare, before = waiting[0]
                past = stored.astype(np.float64) / 255.0
                stacked = stack.learn(past, rare, occupied)  # as decided before this step
                candidates = np.concatenate([_with_unions(past), stacked[None]]) >= DECIDED
                leader.score(candidates, rare, experts.region, occupied, before)
            rare = experts.rare[k]
            # the candidates in the order of CANDIDATES: each expert's own and the unions
            # (decided at 0.4), then the stacked combination's
            p, d = stack.decided(maps[:, k], rare)
            own = _with_unions(maps[:, k])
            p, d = np.concatenate([own, p[None]]), np.concatenate([own, d[None]])
            a, b = leader.choice
            probability.append(np.where(rare, p[b], p[a]))
            decided.append(np.where(rare, d[b], d[a]))
            quantised = np.rint(np.clip(maps[:, k], 0.0, 1.0) * 255).astype(np.uint8)
            waiting.append((quantised, rare.copy(), occupied))
        return Combined(np.stack(probability).astype(np.float32), np.stack(decided))

    @property
    def nbytes(self) -> int:
        """The bytes of the arrays it holds: the maps waiting for their label, what it
        learnt, the experts' counts (a bound: the queues hold ``K (K + 1) / 2`` frames)."""
        waiting = sum(a.nbytes for queue in self._waiting for item in queue for a in item)
        learnt = sum(np.asarray(v).nbytes for v in self.state().values())
        return int(waiting + learnt + self.experts.nbytes)

    def chosen(self) -> list[tuple[str, str]]:
        """Per horizon, the candidates deciding the common and the rare cells now."""
        return [(CANDIDATES[a], CANDIDATES[b]) for a, b in (x.choice for x in self.leaders)]

    def weights(self) -> dict[str, list[float]]:
        """Per horizon, the stacked combination's weight of each feature by name."""
        names = ["bias", "rare", *EXPERTS, *(f"{n}_if_rare" for n in EXPERTS)]
        return {
            name: [float(stack.weights[i]) for stack in self.stacks] for i, name in enumerate(names)
        }

    def state(self) -> dict[str, np.ndarray]:
        """What was learnt, as arrays (the predictions waiting for their label are not
        kept): :meth:`load_state` takes it back."""
        out: dict[str, np.ndarray] = {"horizon": np.array(self.horizon)}
        for k, (stack, leader) in enumerate(zip(self.stacks, self.leaders, strict=True)):
            for key, value in {**stack.state(), **leader.state()}.items():
                out[f"{k + 1}/{key}"] = value
        return out

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Continue from what :meth:`state` kept (a ``ValueError`` where it does not fit)."""
        if int(state.get("horizon", -1)) < self.horizon:
            raise ValueError(f"learnt for fewer than {self.horizon} frames ahead")
        for k, (stack, leader) in enumerate(zip(self.stacks, self.leaders, strict=True)):
            prefix = f"{k + 1}/"
            mine = {key[len(prefix) :]: v for key, v in state.items() if key.startswith(prefix)}
            stack.load_state(mine)
            leader.load_state(mine)
        self.forget_pending()


def _with_unions(experts: np.ndarray) -> np.ndarray:
    """The candidates' maps but the stacked one's ``(C - 1, H, W)``: the ``experts``'
    ``(E, H, W)``, then their unions (:data:`UNIONS`)."""
    unions = [np.maximum(experts[i], experts[j]) for i, j in _UNIONS]
    return np.concatenate([experts, np.stack(unions)])
