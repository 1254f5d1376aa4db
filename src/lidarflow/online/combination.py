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

from lidarflow.compiled import ready
from lidarflow.online.experts import EXPERTS, ExpertMaps
from lidarflow.online.leader import Arrived, Leader, choose_each, score_counts_each
from lidarflow.online.loops import quantised_loop
from lidarflow.online.stacking import (
    DECIDED,
    HorizonStacking,
    StackingConfig,
    choose_thresholds,
)

if TYPE_CHECKING:
    from lidarflow.predict.engine import Rollout, Step
    from lidarflow.tracking import Tracker

__all__ = ["CANDIDATES", "Combination", "Combined", "candidate_maps", "quantised"]

#: The experts laid over each other (the larger probability).
UNIONS = (("model", "tracks"), ("copy_last", "tracks"))

#: The candidates that may decide a kind of cell: each expert alone, the unions, then the
#: stacked combination.
CANDIDATES = (*EXPERTS, *(f"{a}+{b}" for a, b in UNIONS), "stacked")
_UNIONS = [(EXPERTS.index(a), EXPERTS.index(b)) for a, b in UNIONS]


@dataclass(frozen=True)
class Combined:
    """The combination's output for the frames ``t + first .. t + K`` it decides:
    ``probability`` and ``decided`` ``(K - first + 1, H, W)``, rescaled so that 0.4 decides as
    the chosen candidate does."""

    probability: np.ndarray
    decided: np.ndarray


class Combination:
    """The online combination for the frames ``first .. horizon`` ahead, starting as the model
    alone (the frames before ``first`` are left to the model: nothing is learnt for them)."""

    def __init__(self, horizon: int, config: StackingConfig | None = None, first: int = 1) -> None:
        if horizon < 1 or not 1 <= first <= horizon:
            raise ValueError(f"need 1 <= first <= horizon, got first {first}, horizon {horizon}")
        self.horizon, self.first = horizon, first
        self.experts = ExpertMaps(horizon, first)
        config = config or StackingConfig()
        model = EXPERTS.index("model")
        self.stacks = [HorizonStacking(len(EXPERTS), config, model) for _ in range(horizon)]
        # the simple predictors among the candidates, copy-last first (the tolerant F1's judge)
        simple = tuple(CANDIDATES.index(n) for n in ("copy_last", "temporal_average", "tracker"))
        self.leaders = [
            Leader(len(CANDIDATES), model, config.decay, baselines=simple) for _ in range(horizon)
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
        shape = (self.horizon - self.first + 1, *occupied.shape)
        self._learn(occupied, experts.region)
        probability, decided = np.empty(shape, np.float32), np.empty(shape, np.float32)
        for k in range(self.first - 1, self.horizon):
            j = k + 1 - self.first
            rare = experts.rare[j]
            choice = self.leaders[k].choice
            probability[j], decided[j] = _chosen(self.stacks[k], choice, maps[:, j], rare)
            self._waiting[k].append((quantised(maps[:, j]), rare.copy(), occupied))
        return Combined(probability, decided)

    def _learn(self, occupied: np.ndarray, region: np.ndarray) -> None:
        """Learn from the frame that came (``occupied``, its mover ``region``) as the label of
        the oldest predictions waiting (those made ``k`` frames before, for each ``k``): each
        horizon's stacking takes a step, its leader scores every candidate's map."""
        ks = range(self.first - 1, self.horizon)
        labelled = [k for k in ks if len(self._waiting[k]) == k + 1]  # made k + 1 frames ago
        if not labelled:
            return
        candidates, rares, befores = [], [], []
        for k in labelled:
            stored, rare, before = self._waiting[k][0]
            # as decided before the step; the thresholds chosen below, every horizon's at once
            stacked = self.stacks[k].learn(stored, rare, occupied, choose=False)
            candidates.append(_candidates_decided(stored, _DECIDED_LEVEL, stacked))
            rares.append(rare)
            befores.append(before)
        counts = score_counts_each(
            np.stack(candidates), np.stack(rares), np.stack(befores), Arrived(occupied, region)
        )
        for k, f1, tolerant in zip(labelled, *counts, strict=True):
            self.leaders[k].add(f1, tolerant, choose=False)
        choose_thresholds([self.stacks[k] for k in labelled])
        choose_each([self.leaders[k] for k in labelled])

    def joined(self, model: np.ndarray, combined: np.ndarray) -> np.ndarray:
        """The frames ``1 .. K`` ahead ``(K, H, W)``: the model's own ``model`` ``(K, H, W)``
        before :attr:`first`, then the combination's ``combined`` (a field of
        :class:`Combined`)."""
        return np.concatenate([model[: self.first - 1], combined])

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


#: The index of the stacked combination among the candidates.
_STACKED = CANDIDATES.index("stacked")

#: The smallest quantised probability ``q`` decided occupied (``q / 255 >= DECIDED``).
_DECIDED_LEVEL = int(np.argmax(np.arange(256) / 255.0 >= DECIDED))


def quantised(maps: np.ndarray) -> np.ndarray:
    """The experts' maps ``(E, H, W)`` float32 (finite) as they are kept until their labels
    come: ``(E, H, W)`` uint8, ``q = rint(255 p)`` (``p`` clipped to [0, 1]). Compiled where
    available, the same bits."""
    if ready(quantised_loop, maps):
        return quantised_loop(maps)  # type: ignore[no-any-return]
    return np.rint(np.clip(maps, 0.0, 1.0) * 255).astype(np.uint8)


def candidate_maps(stack: HorizonStacking, experts: np.ndarray, rare: np.ndarray) -> np.ndarray:
    """Every candidate's decided map ``(C, H, W)`` bool, in the order of :data:`CANDIDATES`,
    of the experts' maps ``(E, H, W)`` for one horizon with its ``rare`` cells, as
    :meth:`Combination.step` would output each if it were chosen (``stack``: that horizon's
    stacking, as it is now)."""
    return _candidates_decided(experts, DECIDED, stack.decided(experts, rare)[1])


def _candidates_decided(experts: np.ndarray, level: float | int, stacked: np.ndarray) -> np.ndarray:
    """The candidates' decided maps ``(C, H, W)`` bool in the order of :data:`CANDIDATES`: of
    the ``experts`` ``(E, H, W)`` and their unions, occupied at or above ``level`` (``DECIDED``
    for probabilities, ``_DECIDED_LEVEL`` for the kept uint8 maps), and of the ``stacked``
    decided probability ``(H, W)``."""
    out = np.empty((len(CANDIDATES), *experts.shape[1:]), bool)
    np.greater_equal(experts, level, out=out[: len(experts)])
    for n, (i, j) in enumerate(_UNIONS, start=len(experts)):
        np.logical_or(out[i], out[j], out=out[n])  # the larger is decided if either is
    np.greater_equal(stacked, DECIDED, out=out[_STACKED])
    return out


def _chosen(
    stack: HorizonStacking, choice: tuple[int, int], experts: np.ndarray, rare: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The probability and decided maps ``(H, W)`` of the candidates ``choice`` (deciding the
    common and the ``rare`` cells) of the experts' maps ``(E, H, W)``; the stacked
    combination's computed only where chosen."""
    stacked = stack.decided(experts, rare) if _STACKED in choice else None
    (p_common, d_common), (p_rare, d_rare) = (
        _candidate(experts, stacked, index) for index in choice
    )
    return np.where(rare, p_rare, p_common), np.where(rare, d_rare, d_common)


def _candidate(
    experts: np.ndarray, stacked: tuple[np.ndarray, np.ndarray] | None, index: int
) -> tuple[np.ndarray, np.ndarray]:
    """Candidate ``index``'s probability and decided map: an expert's own map (decided at
    :data:`DECIDED` as it is), a union's (the larger), or ``stacked``'s."""
    if index < len(EXPERTS):
        return experts[index], experts[index]
    if index < _STACKED:
        i, j = _UNIONS[index - len(EXPERTS)]
        union = np.maximum(experts[i], experts[j])
        return union, union
    assert stacked is not None
    return stacked
