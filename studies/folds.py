"""Training for the studies through :mod:`lidarflow.train`: a model on some recordings, and a
study's *variant* (a name, a recipe and the config keys it sets) given on the command line.

A finished run (its ``model.safetensors`` written) is reused, so an interrupted study continues
where it stopped."""

from __future__ import annotations

import argparse
import os
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lidarflow.train import build_config, train


@dataclass(frozen=True)
class Variant:
    """A training recipe and the config keys that change it: ``NAME=RECIPE [KEY=VALUE ...]``
    on the command line (``head=head optim.epochs=3``), the keys as `lidarflow train --set`
    takes them."""

    name: str
    recipe: str
    overrides: tuple[str, ...] = ()

    @classmethod
    def parse(cls, text: str) -> Variant:
        name, _, spec = text.partition("=")
        words = shlex.split(spec)
        if not name or not words or "=" in words[0]:
            raise argparse.ArgumentTypeError(
                f"a variant is NAME=RECIPE [KEY=VALUE ...], got {text!r}"
            )
        return cls(name, words[0], tuple(words[1:]))


def train_model(
    sources: Sequence[str | Path],
    run_dir: Path,
    recipe: str,
    overrides: Sequence[str] = (),
    flags: dict[str, Any] | None = None,
) -> Path:
    """Train ``recipe`` (with ``flags`` ``{"model.name": ...}`` and ``overrides``
    ``["optim.epochs=3"]``, applied last) on ``sources`` into ``run_dir``, unless a finished run
    is there already; returns ``run_dir``."""
    if (run_dir / "model.safetensors").exists():
        return run_dir
    # absolute, so that the run's config names its data wherever it is read again
    data = {"data.sources": [os.path.abspath(s) for s in sources]}
    config = build_config(recipe, None, {**data, **(flags or {})}, overrides)
    print(f"training {recipe} {' '.join(overrides)} on {len(sources)} sources -> {run_dir}")
    train(config, run_dir)
    return run_dir


def train_variant(variant: Variant, sources: Sequence[str | Path], run_dir: Path) -> Path:
    return train_model(sources, run_dir, variant.recipe, variant.overrides)
