"""``choose-offset``: a trained model's fixed decision offset, chosen on the user's recordings."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.cli.app import (
    DEFAULT_THREADS,
    TORCH_MODEL_SOURCES,
    ForceOpt,
    GridOpt,
    OdomOpt,
    ResOpt,
    ThreadsOpt,
    TopicOpt,
    app,
    eval_progress,
    refuse_existing,
    use_threads,
)
from lidarflow.evaluate.offsets import DEFAULT_OFFSETS

_OFFSETS = ", ".join(f"{o:g}" for o in DEFAULT_OFFSETS)


@app.command("choose-offset")
def choose_offset(
    inputs: Annotated[
        list[Path], typer.Argument(help="Recordings (.npz) or bags/MCAP to choose on.")
    ],
    output: Annotated[
        Path,
        typer.Option("--output", "-o", help="Model folder to write: the model with the offset."),
    ],
    model: Annotated[
        Path | None,
        typer.Option(
            "--model",
            "-m",
            help=f"Model with an occupancy head: {TORCH_MODEL_SOURCES} or `bundled` (the "
            "default).",
        ),
    ] = None,
    offset: Annotated[
        list[float] | None,
        typer.Option("--offset", help=f"Candidate offset (repeatable; default {_OFFSETS})."),
    ] = None,
    topic: TopicOpt = None,
    odom_topic: OdomOpt = None,
    warmup: Annotated[
        int, typer.Option(help="Frames per recording that only warm the state up.", min=0)
    ] = 10,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    force: ForceOpt = False,
    threads: ThreadsOpt = DEFAULT_THREADS,
) -> None:
    """Choose an occupancy-head model's fixed decision offset on your recordings: each
    candidate is scored beside the baselines, and the one with the largest summed win margin
    goes into a copy of the model (-o), with every score in its offsets.json.

    A larger offset predicts more changed cells at some cost in calibration; a model that
    chooses offsets online uses the fixed one for its first frames."""
    from lidarflow.cli.scorable import read_scorable
    from lidarflow.evaluate.offsets import choose_offset as choose
    from lidarflow.evaluate.offsets import decided_online, score_offsets, with_offset
    from lidarflow.models.weights import check_decision_offset
    from lidarflow.scan import GridSpec

    refuse_existing(output, force=force, folder=True, inputs=[*inputs, model])
    use_threads(threads)
    offsets = [check_decision_offset(o, "--offset") for o in dict.fromkeys(offset or ())]
    offsets = offsets or list(DEFAULT_OFFSETS)
    card = _head_model_card(model)
    weights = Path(card["weights_path"])
    spec = GridSpec(grid, grid, res)
    named = [(str(p), read_scorable(p, topic, odom_topic, warmup, 1, False)) for p in inputs]
    report, names = score_offsets(named, card, weights, offsets, spec, warmup, eval_progress)
    _refuse_nothing_scored(report["recordings"])
    best, totals = choose(report["recordings"], names)
    _say_scores(report["recordings"], names, totals)
    chosen = with_offset(card, best, online=decided_online(card))  # the model's own rule kept
    record = {
        "command": "lidarflow " + " ".join(sys.argv[1:]),
        "model": str(weights),
        "recordings": [name for name, _ in named],
        "offsets": offsets,
        "summed_win_margin": {f"{o:g}": t for o, t in totals.items()},
        "chosen": best,
        "scores": {
            entry["path"]: {f"{o:g}": entry["methods"][n] for o, n in names.items()}
            for entry in report["recordings"]
        },
    }
    chosen["decision_offset_chosen_on"] = record["recordings"]
    _write_model(output, weights, chosen, record)
    typer.echo(f"wrote {output}: decision offset {best:g} (use it with -m {output})")


def _head_model_card(model: Path | None) -> dict[str, Any]:
    """The card of ``model``; a :class:`ModelError` where it has no occupancy head."""
    from lidarflow.errors import ModelError
    from lidarflow.models.presets import resolve_model

    net, card = resolve_model(model)
    if not net.capabilities.occupancy_head:
        raise ModelError(
            f"{card.get('weights_path')}: this model has no occupancy head, so no decision "
            "offset to choose (train one with the default recipe)"
        )
    return card


def _refuse_nothing_scored(recordings: list[dict[str, Any]]) -> None:
    """Warn of each recording on which nothing was scored; an :class:`EvaluateError` where
    that is every one."""
    from lidarflow.cli.scorable import nothing_scored, warn_nothing_scored
    from lidarflow.errors import EvaluateError

    for entry in recordings:
        warn_nothing_scored(entry)
    if all(nothing_scored(entry) for entry in recordings):
        raise EvaluateError(
            "nothing was scored on any recording (no occupied cell in a scored frame): no "
            "offset to choose; choose on recordings whose scans see something"
        )


def _say_scores(
    recordings: list[dict[str, Any]], names: dict[float, str], totals: dict[float, float]
) -> None:
    """Each recording's F1 / changed F1 by offset, then the summed win margins."""
    for entry in recordings:
        scores = ", ".join(
            f"{o:g}: {entry['methods'][n]['f1']:.3f}/{entry['methods'][n]['changed_f1']:.3f}"
            for o, n in names.items()
        )
        typer.echo(f"{Path(entry['path']).name} (F1/changed F1 by offset): {scores}")
    typer.echo("summed win margin: " + ", ".join(f"{o:g}: {t:+.4f}" for o, t in totals.items()))


def _write_model(
    output: Path, weights: Path, chosen: dict[str, Any], record: dict[str, Any]
) -> None:
    """Write the model folder ``output``: the weights, the model.json deciding with the chosen
    offset, and offsets.json with every score."""
    from lidarflow.atomic import atomic_path, write_text

    with atomic_path(output) as folder:
        folder.mkdir()
        shutil.copyfile(weights, folder / "model.safetensors")
        write_text(folder / "model.json", json.dumps(chosen, indent=2) + "\n")
        write_text(folder / "offsets.json", json.dumps(record, indent=2) + "\n")
