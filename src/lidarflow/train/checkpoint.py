"""Checkpoints: weights as safetensors, config as JSON, the rest of the training state apart.

Layout of a run directory::

    config.json, run.json       the TrainConfig; the command, commit, device and resumes
    metrics.csv, metrics.jsonl  one row per epoch
    checkpoints/epoch_NNNN.safetensors   weights after epoch NNNN
    checkpoints/epoch_NNNN.state.pt      optimizer, scheduler, RNG states, epoch, best score
    checkpoints/latest.json     {"epoch": N}: the newest *complete* checkpoint
    last.safetensors, best.safetensors   weights of the last / best epoch
    model.safetensors, model.json        the final model other commands load

Every file is written to a temporary name and renamed into place, and ``latest.json`` moves only
after both files of an epoch are on disk, so a killed run resumes from the last complete epoch.
The state file holds tensors and plain values only (``torch.load(weights_only=True)``).
"""

from __future__ import annotations

import io
import json
import random
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors import SafetensorError
from safetensors.torch import load_file, save

from lidarflow.atomic import atomic_path, discard
from lidarflow.errors import TrainError

__all__ = [
    "atomic_write",
    "capture_rng",
    "latest_epoch",
    "load_checkpoint",
    "load_weights",
    "remove_temporaries",
    "restore_rng",
    "save_checkpoint",
    "save_weights",
    "unwrap",
    "write_json",
]


KEEP = 2  # epochs of checkpoints kept on disk (the newest and the one before)


def atomic_write(path: Path, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp)`` for a temporary file beside ``path``, then rename it to ``path``."""
    with atomic_path(path) as tmp:
        write(tmp)
    return path


def remove_temporaries(run_dir: Path) -> int:
    """Delete what a killed writer left behind (``.NAME.PID.partial*``, ``.NAME.*.tmp``);
    returns how many."""
    folders = (run_dir, _ckpt_dir(run_dir))
    stale = [p for d in folders for pattern in (".*.tmp", ".*.partial*") for p in d.glob(pattern)]
    for path in stale:
        discard(path)
    return len(stale)


def write_json(path: Path, data: Any) -> Path:
    return atomic_write(path, lambda tmp: tmp.write_text(json.dumps(data, indent=2) + "\n"))


def unwrap(model: torch.nn.Module) -> torch.nn.Module:
    """The plain module under DistributedDataParallel and/or torch.compile wrappers."""
    while True:
        if hasattr(model, "module"):
            model = model.module
        elif hasattr(model, "_orig_mod"):
            model = model._orig_mod
        else:
            return model


def save_weights(model: torch.nn.Module, path: Path, meta: dict[str, Any] | None = None) -> Path:
    """Weights as safetensors (contiguous CPU copies); ``meta`` goes in as JSON strings."""
    state = {k: v.detach().to("cpu").contiguous() for k, v in unwrap(model).state_dict().items()}
    bad = [k for k, v in state.items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise TrainError(f"refusing to save non-finite weights to {path} ({', '.join(bad[:3])})")
    metadata = {k: json.dumps(v) for k, v in (meta or {}).items()}
    # serialised in memory, written as one file: a full disk is then an OSError naming it
    return atomic_write(path, lambda tmp: tmp.write_bytes(save(state, metadata=metadata)))


#: A checkpoint file that cannot be read: written by something not atomic (a copy, a full disk).
_DAMAGED = "damaged checkpoint ({what} cannot be read: the file is cut short or overwritten)"


def load_weights(model: torch.nn.Module, path: Path) -> None:
    if not path.exists():
        raise TrainError(f"{path}: no such weights file")
    try:
        state = load_file(str(path))
    except (OSError, SafetensorError) as err:
        raise TrainError(f"{path}: {_DAMAGED.format(what='its weights')}") from err
    try:
        unwrap(model).load_state_dict(state)
    except RuntimeError as err:
        raise TrainError(f"{path}: weights do not fit this model ({err})") from err


def capture_rng() -> dict[str, Any]:
    """Every random generator a training step may touch."""
    version, keys, gauss = random.getstate()
    state: dict[str, Any] = {"torch": torch.get_rng_state(), "python": [*keys, version, gauss]}
    np_state = np.random.get_state()
    state["numpy"] = {
        "keys": torch.from_numpy(np_state[1].astype(np.int64)),
        "pos": int(np_state[2]),
    }
    if torch.cuda.is_available():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def restore_rng(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    py = state["python"]
    random.setstate((py[-2], tuple(py[:-2]), py[-1]))
    keys = state["numpy"]["keys"].numpy().astype(np.uint32)
    np.random.set_state(("MT19937", keys, state["numpy"]["pos"], 0, 0.0))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])


def _ckpt_dir(run_dir: Path) -> Path:
    return run_dir / "checkpoints"


def save_checkpoint(
    run_dir: Path,
    epoch: int,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    scheduler: Any,
    extra: dict[str, Any],
) -> None:
    """Write the checkpoint of a finished ``epoch`` (1-based), then point ``latest`` at it."""
    folder = _ckpt_dir(run_dir)
    stem = folder / f"epoch_{epoch:04d}"
    save_weights(model, stem.with_suffix(".safetensors"), {"epoch": epoch})
    state = {
        "epoch": epoch,
        "optimizer": optimizer.state_dict(),
        "scheduler": scheduler.state_dict(),
        "rng": capture_rng(),
        "extra": extra,
    }
    buffer = io.BytesIO()  # torch.save on a full disk says "unexpected pos", not ENOSPC
    torch.save(state, buffer)
    atomic_write(stem.with_suffix(".state.pt"), lambda tmp: tmp.write_bytes(buffer.getvalue()))
    write_json(folder / "latest.json", {"epoch": epoch})
    for old in folder.glob("epoch_*"):
        number = int(old.name.split(".")[0].removeprefix("epoch_"))
        if number <= epoch - KEEP:
            old.unlink(missing_ok=True)


def latest_epoch(run_dir: Path) -> int:
    """The newest complete checkpoint's epoch, 0 when there is none."""
    pointer = _ckpt_dir(run_dir) / "latest.json"
    if not pointer.exists():
        return 0
    try:
        return int(json.loads(pointer.read_text())["epoch"])
    except (ValueError, KeyError, TypeError) as err:
        raise TrainError(f"{pointer}: corrupt checkpoint pointer ({err})") from err


def load_checkpoint(
    run_dir: Path, model: torch.nn.Module, optimizer: torch.optim.Optimizer, scheduler: Any
) -> tuple[int, dict[str, Any]]:
    """Restore weights, optimizer, scheduler and RNG of the newest checkpoint; returns
    ``(epoch, extra)``."""
    epoch = latest_epoch(run_dir)
    if epoch == 0:
        raise TrainError(
            f"{run_dir}: no checkpoint to resume from (no epoch finished); run the command "
            "that started it again (run.json) to start it over"
        )
    stem = _ckpt_dir(run_dir) / f"epoch_{epoch:04d}"
    load_weights(model, stem.with_suffix(".safetensors"))
    state_path = stem.with_suffix(".state.pt")
    try:
        state = torch.load(state_path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except Exception as err:  # torch says a cut file many ways, EOFError (click's Ctrl-D) too
        raise TrainError(f"{state_path}: {_DAMAGED.format(what='its training state')}") from err
    try:
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        restore_rng(state["rng"])
    except (OSError, RuntimeError, KeyError, ValueError) as err:
        raise TrainError(f"{stem}.state.pt: cannot restore the training state ({err})") from err
    if state["epoch"] != epoch:
        raise TrainError(f"{stem}.state.pt holds epoch {state['epoch']}, expected {epoch}")
    return epoch, dict(state["extra"])
