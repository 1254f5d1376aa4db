"""How the next map is decided from a model's probability: a fixed offset, or offsets chosen
online, on the stream itself.

An occupancy-head model gives a calibrated probability ``sigmoid(logit)`` (trained by
cross-entropy). Cross-entropy predicts a change only when it is likelier than the 0.4
threshold, so a calibrated model gives up most cells that change; a decision *offset* added to
the logit buys them back at a small price in F1. The offset ``a`` applies on the cells that the
last map, moved by the model's backward flow, says are occupied and ``b`` on the free ones. The
:class:`DecisionPolicy` is the Predictor's configuration (a model ships with its own, in its
``model.json``): a fixed offset chosen on the training recordings (``lidarflow tune-offset``),
and whether to choose the offsets online, starting from it: a recording from another robot may
want other offsets than the training recordings (``docs/research/online_decision/``).

Every frame that arrives is the target of the prediction made one frame before, so the stream
scores itself as it goes. :class:`OnlineDecision` keeps, for every pair ``(a, b)`` of a grid,
recent (decayed) true-positive / predicted / positive counts of the decisions that pair would
have made, over all cells and over the cells that changed; and, decayed more slowly
(``history_decay``), the counts of the decisions it did make and of the three baselines run
beside it (copy-last, temporal average, constant velocity). The criterion is the *win
margin* of a whole recording, ``min(F1 - best baseline F1, changed F1 - best baseline changed
F1)``. Each frame predicts with the pair that would leave that margin largest if the next
``lookahead`` frames went as the pair's recent ones did, on top of the decisions made so far:
where the stream is behind in F1 it picks a pair that gains F1, where behind in changed-cell
F1 one that gains those (the rule and its grid are chosen in
``docs/research/online_decision/``). Only past frames are used; nothing is trained.

Why the decisions made are decayed too: a robot's stream runs through places that want other
decisions, and with counts since the stream began the margin of the first place steers the
choices in the next (``python -m studies.long_stream``, docs/research/online_decision/).

Every pair is also tried on the last map *unmoved* (``unmoved``, given the head's warp gain
``g``): the head's logit is ``g * W(O^t, B^t) + r``, and ``g * O^t + r`` is what it would say
if the flow moved nothing. Where the flow moves cells that stay put the unmoved candidates win
more; on a driving platform the unmoved map is in the wrong frame and the choice keeps to the
moved one.

Every pair is counted at the cost of a few sorted searches (:mod:`lidarflow.predict.offsets`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lidarflow.baselines import (
    TA_THRESHOLD,
    TA_WINDOW,
    ConstantVelocity,
    CopyLast,
    Method,
    TemporalAverage,
)
from lidarflow.predict.logits import calibrated_logit, shifted_probability, sigmoid32
from lidarflow.predict.lookahead import best_candidate, lookahead_terms
from lidarflow.predict.offsets import (
    THRESHOLD,
    counts_all_and_changed,
    moved_last_map,
    pair_counts_each,
)

__all__ = [
    "THRESHOLD",
    "DecisionPolicy",
    "OnlineDecision",
    "OnlineDecisionConfig",
    "moved_last_map",
]

_THRESHOLD_LOGIT = float(np.log(THRESHOLD / (1.0 - THRESHOLD)))
_TIE_BREAK = 1e-3
MOVED, UNMOVED = 0, 1  # the candidates' maps: moved by the model's flow, or as it is
_OCCUPIED = tuple(round(-4.8 + 0.3 * i, 1) for i in range(31))  # -4.8 ... 4.2
_FREE = tuple(round(-0.6 + 0.3 * i, 1) for i in range(13))  # -0.6 ... 3.0


@dataclass(frozen=True)
class OnlineDecisionConfig:
    """``occupied_offsets`` x ``free_offsets``: the pairs tried. Each pair's recent counts weigh
    the past by ``decay`` per frame (0.98: about the last 50 frames), and count as
    ``lookahead`` frames to come. Until ``min_frames`` predictions have been scored the model's
    own offsets are used. ``unmoved``: every pair is also tried on the last map unmoved (needs
    the head's warp gain; see the module's docstring). ``ta_window`` / ``ta_threshold``: the
    temporal-average baseline it measures itself against (`lidarflow evaluate` passes the one it
    reports). ``history_decay``: the decisions made and the baselines' counts weigh the past by
    this per frame (0.98: about the last 50 frames; 1: since the stream began, as a recording
    is scored; see the module's docstring)."""

    occupied_offsets: tuple[float, ...] = _OCCUPIED
    free_offsets: tuple[float, ...] = _FREE
    decay: float = 0.98
    lookahead: float = 20.0
    min_frames: int = 10
    unmoved: bool = True
    ta_window: int = TA_WINDOW
    ta_threshold: float = TA_THRESHOLD
    history_decay: float = 0.98

    def __post_init__(self) -> None:
        if not self.occupied_offsets or not self.free_offsets:
            raise ValueError("the online decision needs at least one offset of each kind")
        if not 0.0 < self.decay <= 1.0:
            raise ValueError(f"decay must be in (0, 1], got {self.decay}")
        if not 0.0 < self.history_decay <= 1.0:
            raise ValueError(f"history_decay must be in (0, 1], got {self.history_decay}")
        if not self.lookahead > 0:
            raise ValueError(f"lookahead must be > 0 frames, got {self.lookahead}")
        if self.min_frames < 1:
            raise ValueError(f"min_frames must be >= 1, got {self.min_frames}")
        TemporalAverage(self.ta_window, self.ta_threshold)  # raises on a bad window / threshold


class OnlineDecision:
    """Re-decides a model's next-map probability with the offset pair (and map: moved or
    unmoved) that should leave the stream's win margin largest (see the module's docstring).

    ``update(probability, occupancy, visibility, moved)`` once per frame, in order: the model's
    calibrated probability for the next frame (until ``config.min_frames`` are scored it is
    decided with ``offset``), this frame's maps, and the last map moved into the next frame by the
    model's flow (``occupancy`` itself for a model without flow). Returns the probability with
    the chosen pair; :attr:`offsets` is that pair and :attr:`unmoved` whether it was applied to
    the unmoved map. ``gain``: the head's warp gain ``g``; without it (or with
    ``config.unmoved`` false) only the moved map is tried.
    """

    def __init__(
        self,
        offset: float = 0.0,
        config: OnlineDecisionConfig | None = None,
        gain: float | None = None,
    ) -> None:
        self.config = config or OnlineDecisionConfig()
        self.own = (float(offset), float(offset))
        self.gain = None if gain is None or not self.config.unmoved else float(gain)
        self._maps = 1 if self.gain is None else 2
        self._a = np.asarray(self.config.occupied_offsets, np.float64)
        self._b = np.asarray(self.config.free_offsets, np.float64)
        self.reset()

    def reset(self) -> None:
        average = TemporalAverage(self.config.ta_window, self.config.ta_threshold)
        self._baselines: list[Method] = [CopyLast(), average, ConstantVelocity()]
        shape = (2, self._maps, len(self._a), len(self._b))  # [all / changed cells, map, a, b]
        # Every pair's recent counts (decayed; ``_weight`` frames' worth) ...
        self._tp, self._predicted = np.zeros(shape), np.zeros(shape)
        self._positives, self._weight = np.zeros(2), 0.0
        # ... and the decisions made and the baselines' (decayed by ``history_decay``).
        self._made = np.zeros((2, 3))  # [mask, (tp, predicted, positives)]
        self._base = np.zeros((2, len(self._baselines), 3))  # [mask, baseline, (tp, ...)]
        self._scored = 0
        self._pending: _Pending | None = None
        self.offsets = self.own
        self.unmoved = False

    def margins(self) -> np.ndarray:
        """``(M, A, B)`` (map: moved, then unmoved if tried): the stream's win margin if
        ``lookahead`` more frames went as each pair's recent ones did, after those decided so
        far (``-inf`` before any frame is scored)."""
        return self._terms().min(axis=0)

    def _terms(self) -> np.ndarray:
        """``(2, M, A, B)``: the look-ahead F1 and changed-cell F1 less the best baselines'."""
        if not self._scored:
            return np.full(self._tp.shape, -np.inf)
        positives = np.broadcast_to(self._positives[:, None, None, None], self._tp.shape)
        recent = np.stack([self._tp, self._predicted, positives], axis=-1)
        return lookahead_terms(self._made, recent, self._weight, self._base, self.config.lookahead)

    def _choice(self) -> tuple[bool, tuple[float, float]]:
        # Where the binding term cannot tell pairs apart (a model that never predicts a changed
        # cell), the other one decides: the tie break.
        best = best_candidate(
            self._made, self._tp, self._predicted, self._positives, self._weight, self._base,
            self.config.lookahead, _TIE_BREAK,
        )  # fmt: skip
        m, i, j = np.unravel_index(best, self._tp.shape[1:])
        return bool(m == UNMOVED), (float(self._a[i]), float(self._b[j]))

    def _score(self, target: np.ndarray) -> None:
        pending = self._pending
        assert pending is not None
        target = target.astype(bool)
        decay = self.config.decay
        self._tp *= decay
        self._predicted *= decay
        self._positives *= decay
        self._weight = decay * self._weight + 1.0
        self._made *= self.config.history_decay
        self._base *= self.config.history_decay
        a, b = pending.offsets
        need, moved = pending.need[pending.map], pending.moved[pending.map]
        made = moved * a + (1.0 - moved) * b >= need
        changed = pending.last != target
        # per map tried: all cells (k = 0) and the changed ones (k = 1) in one pass
        each = pair_counts_each(pending.need, pending.moved, target, [None, changed], self._a,
                                self._b)  # fmt: skip
        for m, both in enumerate(each):
            for k, (tp, predicted, _) in enumerate(both):
                self._tp[k, m] += tp
                self._predicted[k, m] += predicted
        table = counts_all_and_changed([made, *pending.baselines], target, changed)
        self._positives += table[:, 0, 2]  # the target's, over all cells and the changed ones
        self._made += table[:, 0]
        self._base += table[:, 1:]
        self._scored += 1

    def update(
        self,
        probability: np.ndarray,
        occupancy: np.ndarray,
        visibility: np.ndarray,
        moved: np.ndarray,
    ) -> np.ndarray:
        occupancy = np.asarray(occupancy)
        if self._pending is not None:
            if self._pending.last.shape != occupancy.shape:
                raise ValueError(
                    f"map shape changed from {self._pending.last.shape} to {occupancy.shape} "
                    "within one stream; reset() first"
                )
            self._score(occupancy)
        baselines = [m.update(occupancy, visibility) >= THRESHOLD for m in self._baselines]
        logits, maps = self._candidates(probability, occupancy, moved)
        if self._scored >= self.config.min_frames:
            self.unmoved, self.offsets = self._choice()
        else:
            self.unmoved, self.offsets = False, self.own
        self._pending = _Pending(
            [_THRESHOLD_LOGIT - x for x in logits],
            maps,
            occupancy.astype(bool),
            baselines,
            self.offsets,
            UNMOVED if self.unmoved else MOVED,
        )
        return self._decided(logits, maps)

    def apply(
        self, probability: np.ndarray, occupancy: np.ndarray, moved: np.ndarray
    ) -> np.ndarray:
        """``probability`` re-decided with the current choice (:attr:`offsets`, :attr:`unmoved`),
        nothing scored: for the predictions a roll-out feeds back (``occupancy`` may then be a
        fed-back probability map). The same as :meth:`update`'s decided map within a float32
        rounding (:func:`~lidarflow.predict.logits.shifted_probability`)."""
        a, b = self.offsets
        split = np.clip(np.asarray(moved, np.float64), 0.0, 1.0)
        shift: np.ndarray | float = 0.0
        if self.unmoved:  # g * O^t + r, split by O^t
            last = np.clip(np.asarray(occupancy, np.float64), 0.0, 1.0)
            shift, split = self.gain * (last - split), last  # type: ignore[operator]
        return shifted_probability(probability, shift + b + (a - b) * split)

    def _candidates(
        self, probability: np.ndarray, occupancy: np.ndarray, moved: np.ndarray
    ) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """The head's logit (no offset) and the map splitting occupied from free cells, for
        the moved map and (with a gain) the unmoved one."""
        moved = np.clip(np.asarray(moved, np.float64), 0.0, 1.0)
        logit = calibrated_logit(probability)
        logits, maps = [logit], [moved]
        if self.gain is not None:
            last = np.clip(np.asarray(occupancy, np.float64), 0.0, 1.0)
            logits.append(logit + self.gain * (last - moved))  # g * O^t + r
            maps.append(last)
        return logits, maps

    def _decided(self, logits: list[np.ndarray], maps: list[np.ndarray]) -> np.ndarray:
        chosen = UNMOVED if self.unmoved else MOVED
        a, b = self.offsets
        logit, moved = logits[chosen], maps[chosen]
        return sigmoid32(logit + b + (a - b) * moved)


@dataclass(frozen=True)
class _Pending:
    """The prediction made for the frame to come, to be scored when it arrives."""

    need: list[np.ndarray]  # per map tried: the logit the threshold asks for, minus the model's
    moved: list[np.ndarray]  # per map tried: the map splitting occupied from free cells
    last: np.ndarray  # the map it was made from (bool): the changed cells are where they differ
    baselines: list[np.ndarray]  # the baselines' predictions (bool)
    offsets: tuple[float, float]  # the pair it was made with ...
    map: int  # ... on this map (MOVED / UNMOVED)


@dataclass(frozen=True)
class DecisionPolicy:
    """How an occupancy-head model's next map is decided: ``offset`` added to its logit, and
    with ``online`` a config the offsets chosen on the stream (:class:`OnlineDecision`,
    starting from ``offset``). The default decides the calibrated probability at 0.4 as it is.
    ``tracks``: the objects a tracker follows on the stream join the decided map where they
    will be (:class:`lidarflow.tracking.Tracker`, run beside the model by the engine),
    so that a head that keeps walls but lets a passer-by fade still carries people forward."""

    offset: float = 0.0
    online: OnlineDecisionConfig | None = None
    tracks: bool = False

    @classmethod
    def from_record(
        cls, record: dict[str, Any] | None, config: OnlineDecisionConfig | None = None
    ) -> DecisionPolicy:
        """The policy a model ships with (``model.json``'s ``decision``: ``{"offset",
        "online", "movers"}``; ``movers`` is the file's key for :attr:`tracks`), its online
        decision configured by ``config``."""
        record = record or {}
        online = (config or OnlineDecisionConfig()) if record.get("online") else None
        return cls(float(record.get("offset", 0.0)), online, bool(record.get("movers")))

    def to_record(self) -> dict[str, Any]:
        return {"offset": self.offset, "online": self.online is not None, "movers": self.tracks}

    def with_online(
        self,
        online: bool | OnlineDecisionConfig | None,
        config: OnlineDecisionConfig | None = None,
    ) -> DecisionPolicy:
        """This policy with the online choice overridden (``None``: as it is; ``True``: on,
        with ``config``, else its own, else the default; ``False``: off; a config: on, with
        it)."""
        if online is None:
            return self
        if online is False:
            return DecisionPolicy(self.offset, None, self.tracks)
        chosen = online if isinstance(online, OnlineDecisionConfig) else config
        online_config = chosen or self.online or OnlineDecisionConfig()
        return DecisionPolicy(self.offset, online_config, self.tracks)

    def decision(self, gain: float | None) -> OnlineDecision | None:
        """A fresh :class:`OnlineDecision` where the policy is online, else ``None``."""
        if self.online is None:
            return None
        return OnlineDecision(self.offset, self.online, gain)
