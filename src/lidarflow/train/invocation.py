"""A ``train`` command line resolved to the config a run trains with: a new run's layered
(:func:`new_run_config`), or a resumed run's own (:func:`resumed_run_config`), where only the
epochs and ``runtime.*`` but the seed may change and moved recordings may be named again.
"""

from __future__ import annotations

import dataclasses
import glob
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidarflow.errors import TrainError
from lidarflow.train.config import TrainConfig
from lidarflow.train.config_io import build_config, config_from_dict, load_config_file
from lidarflow.train.recipes import default_recipe

__all__ = [
    "ResumeConflictError",
    "TrainRequest",
    "new_run_config",
    "refuse_inputs_in",
    "resumed_run_config",
    "where_it_stopped",
]


class ResumeConflictError(TrainError):
    """A resumed run was asked to change what shaped its weights (the command line's fault)."""


@dataclass(frozen=True)
class TrainRequest:
    """What a ``train`` command line asks for; ``flags``: its options as config keys (``None``:
    not given; paths already absolute)."""

    data: list[str] = field(default_factory=list)
    flags: dict[str, Any] = field(default_factory=dict)
    recipe: str | None = None
    config: Path | None = None
    sets: list[str] = field(default_factory=list)
    ego_motion: bool = False
    val: list[str] = field(default_factory=list)


def _free(key: str) -> bool:
    """Whether a resumed run may change ``key``: the epochs, and how it runs (not the seed)."""
    return key == "optim.epochs" or (key.startswith("runtime.") and key != "runtime.seed")


def new_run_config(request: TrainRequest) -> TrainConfig:
    """The config of a new run: recipe (the architecture's default unless named), config file,
    flags, then ``--set``."""
    flags = dict(request.flags)
    if request.data:  # absolute, so that --resume works from any folder (globs too)
        flags["data.sources"] = [os.path.abspath(d) for d in request.data]
    in_file = load_config_file(request.config) if request.config else {}
    recipe = request.recipe
    if recipe is None and "recipe" not in in_file:
        section = in_file.get("model")  # not a table: build_config says so, in one line
        named = flags.get("model.name") or (
            section.get("name") if isinstance(section, dict) else None
        )
        recipe = default_recipe(named, request.ego_motion)
    config = build_config(recipe, request.config, flags, request.sets)
    if request.ego_motion:  # added to, not replacing, the rest of the model
        model = dataclasses.replace(config.model, ego_motion=True)
        config = dataclasses.replace(config, model=model)
    return config


def resumed_run_config(run_dir: Path, request: TrainRequest) -> TrainConfig:
    """The config ``run_dir`` continues with: its own, with the epochs and runtime the request
    changes. :class:`ResumeConflictError` where the request changes anything else;
    :class:`TrainError` where ``run_dir`` is not a run or its recordings are not found."""
    moved = {"data.val_sources"}  # a run copied elsewhere names its recordings again
    changed = [
        k for k, v in request.flags.items() if v is not None and not _free(k) and k not in moved
    ]
    changed += ["--ego-motion"] if request.ego_motion else []
    keys = {o: o.split("=", 1)[0].strip() for o in request.sets}
    runtime_sets = [o for o, k in keys.items() if _free(k)]
    changed += [f"--set {o}" for o in keys if o not in runtime_sets]
    if changed or request.recipe or request.config:
        raise ResumeConflictError(
            "a resumed run keeps its config (only --epochs and runtime options may change); "
            f"drop {', '.join(changed) or '--recipe/--config'} or start a new run"
        )
    if not (run_dir / "config.json").is_file():
        raise TrainError(
            f"{run_dir}: not a training run (no config.json); --resume takes a folder that "
            "`lidarflow train -o` wrote"
        )
    saved = config_from_dict(load_config_file(run_dir / "config.json"))
    kept = {k: v for k, v in request.flags.items() if _free(k)}
    for key, recorded, given, how in (
        ("data.sources", saved.data.sources, request.data, "DATA..."),
        ("data.val_sources", saved.data.val_sources, request.val, "--val V..."),
    ):
        absolute = [os.path.abspath(g) for g in given]
        found = _found_again(run_dir, list(recorded), absolute, how)
        if found is not None:
            kept[key] = found
    return build_config(saved.recipe, run_dir / "config.json", kept, runtime_sets)


def _found_again(run: Path, recorded: list[str], given: list[str], how: str) -> list[str] | None:
    """The recordings a resumed run continues on: ``None`` to keep ``recorded``, or ``given``
    where the run was copied elsewhere (every recorded path gone, the same names given);
    :class:`TrainError` otherwise."""
    missing = [r for r in recorded if not os.path.exists(r)]
    if given and given != recorded:
        names = [os.path.basename(r) for r in recorded]
        if missing != recorded or [os.path.basename(g) for g in given] != names:
            raise TrainError(f"{run} was trained on {recorded}, not {given}")
        return given
    if missing:
        raise TrainError(
            f"{run} was trained on {', '.join(missing)}, not there any more; give the "
            f"recordings again where they are now: lidarflow train {how} --resume {run}"
        )
    return None


def refuse_inputs_in(run_dir: Path, config: TrainConfig) -> None:
    """Refuse a run folder that is, or holds, what the run reads (``--force`` would remove it):
    its sources, validation sources and initial weights, glob patterns expanded."""
    from lidarflow.atomic import check_not_input

    inputs = [*config.data.sources, *config.data.val_sources, config.model.init]
    check_not_input(run_dir, [m for s in inputs if s for m in [s, *glob.glob(s)]])


def where_it_stopped(run_dir: Path) -> str:
    """What a user whose run stopped needs next: whether it resumes, and how."""
    from lidarflow.train.checkpoint import latest_epoch

    try:
        done = latest_epoch(run_dir)
    except TrainError:
        done = 0
    if done:
        return f"`lidarflow train --resume {run_dir}` continues {run_dir} after epoch {done}"
    return f"no epoch of {run_dir} finished; run the same command again to start it over"
