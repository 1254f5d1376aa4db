"""The run directory (its layout: :mod:`lidarflow.train.checkpoint`): creating and locking it,
``config.json`` and ``run.json`` at the start, the checks of a resume, and at the end
``model.safetensors`` + ``model.json``, the pair :func:`lidarflow.models.weights.load_trained`
reads.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import torch

from lidarflow.atomic import STAMP, discard, is_ours, stamp
from lidarflow.errors import TrainError
from lidarflow.models import count_parameters
from lidarflow.train import checkpoint as ckpt
from lidarflow.train.config import TrainConfig
from lidarflow.train.config_io import config_from_dict, config_to_dict, load_config_file
from lidarflow.train.data import TrainData
from lidarflow.train.distributed import Dist

__all__ = ["abandon_run_dir", "model_record", "prepare_run_dir", "release_run_dir", "write_final"]

#: Held while a process trains into a run folder: its PID and host.
LOCK = "training.lock"


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            cwd=Path(__file__).parent,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def model_record(
    config: TrainConfig,
    model: torch.nn.Module,
    data: TrainData,
    extra: dict[str, Any],
    commit: str | None = None,
) -> dict[str, Any]:
    """What ``model.json`` says: enough to rebuild the net and to know where it came from
    (``commit``: by default the checkout's HEAD now)."""
    return {
        "model": config.model.name,
        "model_kwargs": config.model.spec().to_kwargs(),
        # How its next map is decided: the Predictor's policy, shipped with the model.
        "decision": dataclasses.asdict(config.decision),
        "out_channels": int(getattr(model, "out_channels", 0)),
        "parameters": int(count_parameters(model)),
        "grid": data.grid.to_dict(),
        "threshold": 0.4,
        "warmup": config.data.warmup,
        "weights": "model.safetensors",
        "recipe": config.recipe,
        "training": {
            "sources": config.data.sources,
            "mix": config.data.mix,
            "epochs": config.optim.epochs,
            "epochs_done": extra.get("epochs_done", config.optim.epochs),
            "final_weights": config.runtime.final_weights,
            "best": extra.get("best"),
            "commit": commit if commit is not None else _git_commit(),
        },
        "config": config_to_dict(config),
    }


def _source_sizes(config: TrainConfig) -> dict[str, int]:
    """Each data source's size in bytes (a folder's, summed), which a resume checks."""
    sizes = {}
    for source in config.data.sources:
        path = Path(source)
        if not path.exists():  # the data loader says so, naming it
            continue
        files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
        sizes[source] = sum(f.stat().st_size for f in files)
    return sizes


def _names(sources: list[str]) -> list[str]:
    return [Path(s).name for s in sources]


def _lock(run_dir: Path) -> None:
    """Refuse a run folder that another live process on this machine trains into (even with
    ``--force`` or ``--resume``); take over a lock whose process is gone, or one left on another
    machine (whose liveness cannot be known from here)."""
    path = run_dir / LOCK
    host = socket.gethostname()
    mine = json.dumps({"pid": os.getpid(), "host": host})
    for _ in range(3):
        if _create(path, mine):
            return
        try:
            held = json.loads(path.read_text())
            pid, same_host = int(held["pid"]), held.get("host") == host
        except FileNotFoundError:  # released meanwhile
            continue
        except (OSError, ValueError, KeyError, TypeError):
            pid, same_host = -1, False
        if same_host and pid == os.getpid():
            return
        if same_host and pid > 0 and _alive(pid):
            raise TrainError(
                f"{run_dir} is being trained by process {pid} on this machine; wait for "
                "it, stop it, or train into another -o folder (not even --force takes it over)"
            ) from None
        path.unlink(missing_ok=True)
    raise TrainError(f"{run_dir}: could not lock it ({path} keeps coming back)")


def _create(path: Path, content: str) -> bool:
    """Create ``path`` holding ``content`` if it is absent, in one step (a hard link of a
    finished file): two processes starting together cannot both hold it, and no reader sees
    it empty and takes it for a stale lock. ``False`` where it exists."""
    staged = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        staged.write_text(content)
        os.link(staged, path)
    except FileExistsError:
        return False
    finally:
        staged.unlink(missing_ok=True)
    return True


def _is_lock(name: str) -> bool:
    """Whether ``name`` is a run folder's lock, or one being made (:func:`_create`)."""
    return name == LOCK or name.startswith(f".{LOCK}.")


def _empty(run_dir: Path) -> None:
    """Remove what a run folder holds but its stamp and lock."""
    for entry in run_dir.iterdir():
        if entry.name not in (LOCK, STAMP):
            discard(entry)


def abandon_run_dir(run_dir: Path, created: bool) -> None:
    """Undo a new run stopped before its first epoch finished: remove the folder if this run
    ``created`` it, else what the run wrote in it."""
    if not run_dir.is_dir() or ckpt.latest_epoch(run_dir) > 0:
        return
    _empty(run_dir)
    if created:
        release_run_dir(run_dir)
        discard(run_dir)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


def release_run_dir(run_dir: Path) -> None:
    """Drop the lock :func:`prepare_run_dir` took (if this process holds it)."""
    path = Path(run_dir) / LOCK
    try:
        if json.loads(path.read_text()).get("pid") == os.getpid():
            path.unlink()
    except (OSError, ValueError, AttributeError):
        pass


def _run_facts(ctx: Dist) -> dict[str, Any]:
    return {
        "command": sys.argv,
        "world_size": ctx.world_size,
        "device": str(ctx.device),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "commit": _git_commit(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def _started(run_dir: Path) -> dict[str, Any]:
    """``run.json``: how the run started and was resumed (empty where it is missing)."""
    path = run_dir / "run.json"
    return json.loads(path.read_text()) if path.exists() else {}


def _check_resumable(run_dir: Path, config: TrainConfig) -> None:
    """A resumed run must keep what shaped its weights; only the epoch count (and how it runs:
    device, threads, amp...) may change."""
    path = run_dir / "config.json"
    if not path.exists():
        raise TrainError(f"{run_dir}: not a training run (no config.json), nothing to resume")
    saved = config_from_dict(load_config_file(path))
    saved = dataclasses.replace(
        saved, optim=dataclasses.replace(saved.optim, epochs=config.optim.epochs)
    )
    # the same recordings moved (a run copied to another machine); their sizes are checked
    moved = {
        key: getattr(config.data, key)
        for key in ("sources", "val_sources")
        if _names(getattr(saved.data, key)) == _names(getattr(config.data, key))
    }
    saved = dataclasses.replace(saved, data=dataclasses.replace(saved.data, **moved))
    changed = [
        name
        for name in ("recipe", "model", "data", "optim", "schedule", "loss")
        if getattr(saved, name) != getattr(config, name)
    ]
    if saved.runtime.seed != config.runtime.seed:
        changed.append("runtime.seed")
    if changed:
        raise TrainError(
            f"{run_dir}: cannot resume with a different config ({', '.join(changed)} changed); "
            "only the number of epochs may change; start a new run instead"
        )


def _check_same_data(run_dir: Path, config: TrainConfig, facts: dict[str, Any]) -> None:
    """Refuse a resume whose recordings changed size since the run started (``run.json``)."""
    recorded = list((facts.get("source_bytes") or {}).values())
    now = _source_sizes(config)
    for source, then in zip(config.data.sources, recorded, strict=False):
        if source in now and now[source] != then:
            raise TrainError(
                f"{run_dir}: {source} changed since the run started ({then} bytes then, "
                f"{now[source]} now); a resumed run continues on the same data: start a new run"
            )


def _check_ours(run_dir: Path) -> None:
    """Refuse, even with ``--force``, a new run into a folder lidarflow did not write."""
    if run_dir.exists() and not run_dir.is_dir():
        raise TrainError(f"{run_dir} is a file; name a folder for the run with -o")
    if run_dir.is_dir() and not is_ours(run_dir, ignoring=_is_lock):
        raise TrainError(
            f"{run_dir} holds files lidarflow did not write (no {STAMP} in it); train into a "
            "new or empty folder (not even --force writes into it)"
        )


def prepare_run_dir(
    run_dir: Path, config: TrainConfig, resume: bool, ctx: Dist, start_over: bool = False
) -> bool:
    """Check, start and lock ``run_dir`` for a new run or a resume (``start_over``: ``--force``);
    returns whether this call created the folder. :func:`release_run_dir` unlocks it."""
    created = False
    if ctx.is_main:
        if not resume:
            _check_ours(run_dir)
            created = not run_dir.exists()
            run_dir.mkdir(parents=True, exist_ok=True)
        if run_dir.is_dir():
            _lock(run_dir)
        if not resume:
            stamp(run_dir)
        if start_over and not resume:
            _empty(run_dir)
    if resume:
        _check_resumable(run_dir, config)
        facts = _started(run_dir)
        _check_same_data(run_dir, config, facts)
        done = ckpt.latest_epoch(run_dir)
        if config.optim.epochs < done:
            # Checked before config.json is rewritten: it would say fewer epochs than the
            # weights have, and so would model.json.
            raise TrainError(
                f"{run_dir} has trained {done} epochs; --epochs {config.optim.epochs} cannot "
                f"shorten it: give more than {done} to extend it, or use its model as it is"
            )
        if ctx.is_main:
            ckpt.remove_temporaries(run_dir)  # what a killed run left half-written
            # the config on disk says how many epochs the run is now meant to have
            ckpt.write_json(run_dir / "config.json", config_to_dict(config))
            facts.setdefault("resumed", []).append({**_run_facts(ctx), "after_epoch": done})
            ckpt.write_json(run_dir / "run.json", facts)
        return created
    # with start_over the main process empties it, maybe after the others look
    judged = ctx.is_main or not start_over
    if judged and (ckpt.latest_epoch(run_dir) > 0 or (run_dir / "model.safetensors").exists()):
        raise TrainError(
            f"{run_dir} already holds a training run; use --resume {run_dir} to continue it, "
            "--force to start it over, or another -o folder"
        )
    if ctx.is_main:
        ckpt.write_json(run_dir / "config.json", config_to_dict(config))
        ckpt.write_json(
            run_dir / "run.json", {**_run_facts(ctx), "source_bytes": _source_sizes(config)}
        )
    return created


def write_final(
    run_dir: Path,
    config: TrainConfig,
    model: torch.nn.Module,
    data: TrainData,
    extra: dict[str, Any],
) -> None:
    if config.runtime.final_weights == "best" and (run_dir / "best.safetensors").exists():
        ckpt.load_weights(model, run_dir / "best.safetensors")
    # The code the run trained with is the checkout it started at: HEAD may have moved since.
    record = model_record(config, model, data, extra, _started(run_dir).get("commit"))
    ckpt.save_weights(model, run_dir / "model.safetensors", {"model": config.model.name})
    ckpt.write_json(run_dir / "model.json", record)
