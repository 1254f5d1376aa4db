"""The methods ``lidarflow evaluate`` scores, built once for the command line and the studies:
the baselines, each model as the engine streams it, the variants asked for, and the
configuration a report states them by."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lidarflow.baselines import (
    TA_THRESHOLD,
    TA_WINDOW,
    ConstantVelocity,
    CopyLast,
    CopyLastEgo,
    TemporalAverage,
)
from lidarflow.evaluate.combined_method import CombinedMethod
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.report import ORACLE_SUFFIX
from lidarflow.models.weights import describe_source
from lidarflow.online.experts import EXPERTS
from lidarflow.predict.backends import learning_backend, load_backend
from lidarflow.predict.decision import OnlineDecisionConfig
from lidarflow.predict.learning import LearningConfig
from lidarflow.predict.moving import MOVING_THRESHOLD
from lidarflow.tracking import Tracker, TrackerConfig

__all__ = ["methods_and_config"]


def methods_and_config(
    sources: Sequence[str | Path | None],
    ta_window: int = TA_WINDOW,
    ta_threshold: float = TA_THRESHOLD,
    moving_threshold: float | None = None,
    ego_oracle: bool = False,
    online: bool = False,
    res: float = 0.1,
    names: Sequence[str] | None = None,
    device: str = "cpu",
    threads: int | None = None,
    combine: int | None = None,
    learn: bool = False,
    combined_ahead: int | None = None,
) -> tuple[list[Any], dict[str, Any]]:
    """The baselines plus the methods of each model source (``None`` or ``"bundled"``: the bundled
    model, else named by ``names`` or its folder or file), and the report's configuration of
    them. An ego-motion model brings ``copy_last_ego``; ``ego_oracle`` adds the variants that
    know the true next pose, ``online`` each model's other decision rule (``NAME_online`` or
    ``NAME_fixed``), ``combine`` each model combined online with the simple predictors that many
    frames ahead (``NAME_combined``), ``learn`` each head-only model run in NumPy with its head
    learning on the stream (``NAME_learning``, on a copy of its weights). ``combined_ahead``
    ``K``: each model (and ``NAME_learning``) as the Predictor runs it by default, the online
    combination deciding its frames ``2 .. K`` ahead where its policy lays tracked objects
    (:class:`~lidarflow.evaluate.model_method.ModelMethod`). PyTorch models run on ``device``,
    each on ``threads`` CPU threads (``None``: the backend's default)."""
    if moving_threshold is None:
        moving_threshold = MOVING_THRESHOLD
    methods: list[Any] = [
        CopyLast(),
        TemporalAverage(ta_window, ta_threshold),
        ConstantVelocity(),
        Tracker(res=res),
    ]
    # An online decision measures itself against the temporal average reported here.
    online_config = OnlineDecisionConfig(ta_window=ta_window, ta_threshold=ta_threshold)
    models_used: dict[str, Any] = {}
    for i, source in enumerate(sources):
        name = names[i] if names else None
        methods += _model_methods(
            source, name, {m.name for m in methods}, moving_threshold, online_config, res,
            ego_oracle, online, models_used, device, threads, learn, combined_ahead,
        )  # fmt: skip
    # the tracker takes the motion too, but copy_last_ego stands beside ego-motion models only
    ego_models = any(isinstance(m, ModelMethod) and m.takes.motion for m in methods)
    if ego_models:
        methods[4:4] = [CopyLastEgo()] + ([CopyLastEgo(oracle=True)] if ego_oracle else [])
    if combine is not None:
        models = [m for m in methods if isinstance(m, ModelMethod) and m.name in models_used]
        learners = [m for m in methods if isinstance(m, ModelMethod) and m.engine.learning]
        methods += [_combined(m, combine, res) for m in models]
        methods += [_combined(m, combine, res, learning=True) for m in learners]
    config = _report_config(
        methods, ta_window, ta_threshold, moving_threshold, models_used, online_config, online
    )
    if combine is not None:
        config["combined"] = {"horizon": combine, "experts": list(EXPERTS)}
    ahead = [m.name for m in methods if isinstance(m, ModelMethod) and m.combination is not None]
    if ahead:  # their frames 2..K: the online combination's, as the Predictor's by default
        config["combined_from_k2"] = {"horizon": combined_ahead, "methods": ahead}
    if learn:
        config["learning"] = dataclasses.asdict(LearningConfig())
    return methods, config


def _combined(model: ModelMethod, horizon: int, res: float, learning: bool = False) -> Any:
    """``model`` combined online with the simple predictors ``horizon`` frames ahead
    (``NAME_combined``); a ``model`` that learns (``NAME_learning``) learning as it did, on a
    copy of its weights (``NAME_learning_combined``)."""
    policy = model.engine.policy.to_record()
    if not learning:
        return CombinedMethod(f"{model.name}_combined", model.backend, horizon, res, policy)
    backend = copy.deepcopy(model.backend)
    name = f"{model.name}_combined"
    return CombinedMethod(name, backend, horizon, res, policy, learning=LearningConfig())


def _model_methods(
    source: str | Path | None,
    name: str | None,
    taken: set[str],
    moving_threshold: float,
    online_config: OnlineDecisionConfig,
    res: float,
    ego_oracle: bool,
    online: bool,
    models_used: dict[str, Any],
    device: str,
    threads: int | None,
    learn: bool = False,
    combined_ahead: int | None = None,
) -> list[Any]:
    """The methods of one model ``source`` (see :func:`methods_and_config`), named ``name`` or
    after it (a name ``taken`` gets underscores), its record put in ``models_used``; with
    ``learn`` also ``NAME_learning``, its head learning on a copy of its weights."""
    bundled = source is None or str(source) == "bundled"
    net, card = load_backend(None if bundled else source, threads=threads, device=device)
    name = name or ("bundled" if bundled else describe_source(source))
    while name in taken:
        name += "_"
    own = card["decision"]  # the decision policy the model ships with
    method = ModelMethod(
        name, net, moving_threshold, online_config=online_config, res=res, decision=own,
        combined_ahead=combined_ahead,
    )  # fmt: skip
    keys = ("model", "weights_path", "weights_sha256", "grid")
    models_used[name] = {k: card.get(k) for k in keys}
    methods = [method]
    if method.takes.motion and ego_oracle:
        methods.append(ModelMethod(name + ORACLE_SUFFIX, net, oracle=True, res=res, decision=own))
    if online:  # the other decision rule beside the model's own
        wants_online = method.online is not None
        methods.append(
            ModelMethod(
                name + ("_fixed" if wants_online else "_online"),
                net,
                moving_threshold,
                online=not wants_online,
                online_config=online_config,
                res=res,
                decision=own,
            )
        )
    if learn:
        learner = copy.deepcopy(learning_backend(net))
        learning = ModelMethod(
            name + "_learning", learner, moving_threshold, online_config=online_config,
            res=res, decision=own, learning=LearningConfig(), combined_ahead=combined_ahead,
        )  # fmt: skip
        methods.append(learning)
    return methods


def _report_config(
    methods: Sequence[Any],
    ta_window: int,
    ta_threshold: float,
    moving_threshold: float,
    models_used: dict[str, Any],
    online_config: OnlineDecisionConfig,
    online: bool,
) -> dict[str, Any]:
    """What the report says of its ``methods``: the rules each follows, for a reader of the
    numbers (see :func:`methods_and_config`)."""
    config: dict[str, Any] = {
        "threshold": 0.4,
        # what knows the future or only moves the last map is reported, never judged
        "no_verdict": [
            m.name
            for m in methods
            if isinstance(m, CopyLastEgo) or (isinstance(m, ModelMethod) and m.oracle)
        ],
        "temporal_average": {
            "window": ta_window,
            "threshold": ta_threshold,
            "chosen": "the default: of a grid of windows and thresholds, the highest mean F1 on "
            "the development recordings among settings that predict changes "
            "(docs/research/temporal_average/)"
            if (ta_window, ta_threshold) == (TA_WINDOW, TA_THRESHOLD)
            else "given on the command line",
        },
        "constant_velocity": "best integer rigid shift (radius 3 cells) of the last two maps",
        "tracker": {
            **dataclasses.asdict(TrackerConfig()),
            "rule": "running background rate in the world frame; foreground cells clustered "
            "(link metres), matched to the tracks' predicted centroids (gate metres), a "
            "constant-velocity Kalman filter per track; k ahead: the background stays, each "
            "track's cells move k times its velocity (lidarflow.tracking); the ego "
            "motion from the poses, on a recording without them matched from its scans",
        },
        # how a reading became a map (lidarflow.scan), since it changed: numbers made under
        # another rule are not these
        "beams": "a return where range_min <= range < range_max; range_max itself, beyond and "
        "+inf no return (free to range_max), and in a scan with 1 % of its beams at range_max "
        "also readings within 1 % (3 cm) under it; NaN, -inf, 0 and below range_min unknown",
        "models": models_used,
        "calibration": {"bins": 10, "over": "every cell of every scored frame"},
        "moving_segmentation": {
            "threshold_cells": moving_threshold,
            "rule": "occupied and |forward flow - fitted background flow| > threshold",
        },
    }
    if online or any(isinstance(m, ModelMethod) and m.online is not None for m in methods):
        config["online_decision"] = {
            **dataclasses.asdict(online_config),
            "rule": "each frame, the (occupied, free) offset pair, on the last map moved by the "
            "flow or unmoved, that would leave the recording's win margin over the three "
            "baselines largest if the next `lookahead` frames went as its recent (decayed) ones; "
            "the decisions made and the baselines' counts decay by `history_decay`",
        }
    if any(isinstance(m, CopyLastEgo) for m in methods):
        config["ego_motion"] = (
            "models built with ego_motion get the recordings' poses (odometry); the motion to "
            "the next frame is the last one again (constant velocity, causal); *_oracle* "
            "variants use the true next pose instead; copy_last_ego moves the last map by the same "
            "motion (reported beside, not one of the baselines a model must beat); "
            "on a recording without poses, models built with poses_optional (the head recipe's, "
            "the bundled one) and copy_last_ego get the motion matched from the scans "
            "(lidarflow.motion.scanmatch; uncompensated where no match counts)"
        )
    return config
