"""What the studies share: the command line (``-o/--output``), the development recordings,
writing a study's config and results atomically, reading an evaluation's model and baselines,
and the one rule for "wins" (F1 above the best baseline's, changed-cell F1 above every
baseline's and, where the mover metric was scored, tolerant mover F1 above copy-last's: the rule
of :func:`lidarflow.evaluate.report.against_baselines`).

Scoring through the library lives in :mod:`studies.scoring`, training folds in
:mod:`studies.folds`; this module needs no PyTorch, so that the studies that only read reports
start fast."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, BinaryIO

# The tracker since issue 44; reports made before it lack it and are judged by the three.
BASELINES = ("copy_last", "temporal_average", "constant_velocity", "tracker")
#: Every verdict :func:`verdict` gives.
VERDICTS = ("wins", "loses movers", "F1 only", "changed only", "loses")
METRICS = ("f1", "changed_f1", "ap")
# The mover metric (issue 44), kept where an evaluation scored it; reports made before it lack it.
MOVER_METRICS = ("mover_f1", "mover_f1_tolerant")
# A model must also beat copy-last on it (lidarflow.evaluate.report.MOVER_KEY).
MOVER_KEY = "mover_f1_tolerant"
# Scored beside ego-motion models on recordings with poses; reported, not counted in a verdict
# (the baselines need no odometry).
REFERENCES = ("copy_last_ego", "copy_last_ego_oracle")
# The seven development recordings of ../shared/data, in the order the studies list them.
DEVELOPMENT = (
    "positive_1.bag", "positive_2.bag", "positive_3.bag", "positive_4.bag",
    "demo_stationary_simple_environment.bag", "datmo_overtakes.bag",
    "general_tracking_moving_1.bag.zip",
)  # fmt: skip
DATA = Path("../shared/data")
RUNS = Path("runs/studies")


def parser(name: str, doc: str | None) -> argparse.ArgumentParser:
    """The study's argument parser: its docstring as the help, and ``-o/--output`` (default
    ``runs/studies/<name>/``)."""
    text = doc or name
    out = argparse.ArgumentParser(
        prog=f"python -m studies.{name}",
        description=text,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    out.add_argument(
        "-o", "--output", type=Path, default=RUNS / name,
        help=f"folder for the study's files (default {RUNS / name})",
    )  # fmt: skip
    return out


def stretch_arguments(
    p: argparse.ArgumentParser, what: str, before: int, after: int, early: int
) -> None:
    """The arguments of the studies that change a drive at a few places and score the
    stretches after them: the recordings (``what`` they must be), the model, ``--places``,
    ``--before``, ``--after`` and ``--early`` with their defaults."""
    p.add_argument(
        "recordings", nargs="*", type=Path,
        help=f"{what} (default: general_tracking_moving_1 and a simulated drive)",
    )  # fmt: skip
    p.add_argument("--model", default="bundled")
    p.add_argument("--places", type=int, default=4)
    p.add_argument("--before", type=int, default=before, help="frames kept before each place")
    p.add_argument("--after", type=int, default=after, help="frames kept after each place")
    p.add_argument("--early", type=int, default=early, help="predictions scored as early")


def parse(p: argparse.ArgumentParser, argv: Sequence[str] | None) -> argparse.Namespace:
    """``p``'s arguments, with ``command``: the line that reruns the study (kept in its JSON)."""
    args = p.parse_args(argv)
    given = list(argv) if argv is not None else sys.argv[1:]
    args.command = p.prog + " " + shlex.join(given)
    return args


def fold(spec: str) -> tuple[Path, str]:
    """``--fold RECORDING=MODEL``: a recording and the model that never trained on it."""
    recording, _, model = spec.partition("=")
    if not recording or not model:
        raise argparse.ArgumentTypeError(f"--fold wants RECORDING=MODEL, got {spec!r}")
    return Path(recording), model


def development(folder: Path = DATA) -> list[Path]:
    """The development recordings found in ``folder`` (those missing are left out)."""
    return [folder / name for name in DEVELOPMENT if (folder / name).exists()]


def stem(path: str | Path) -> str:
    name = Path(path).name
    for suffix in (".bag.zip", ".bag", ".mcap", ".npz"):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


def _plain(value: Any) -> Any:
    """``value`` as JSON holds it (paths as text, tuples as lists)."""
    if isinstance(value, Path):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _plain(dataclasses.asdict(value))
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def write_atomic(path: Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file beside it, so that a killed study
    leaves the previous file or the new one, never half of one."""
    return _replaced(path, lambda handle: handle.write(text.encode()))


def write_arrays(path: Path, arrays: dict[str, Any]) -> Path:
    """``arrays`` (NumPy's) to ``path`` as a compressed npz, atomically as
    :func:`write_atomic`."""
    import numpy as np  # here: the studies that only read reports need none

    return _replaced(path, lambda handle: np.savez_compressed(handle, **arrays))


def _replaced(path: Path, write: Callable[[BinaryIO], object]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_json(path: Path, data: Any) -> Path:
    return write_atomic(path, json.dumps(_plain(data), indent=1) + "\n")


def read_json(path: Path) -> Any:
    return json.loads(path.read_text())


def write_summary(
    args: argparse.Namespace, name: str, results: Any, markdown: str | None = None
) -> Path:
    """``OUT/<name>.json`` (``{"config": the study's arguments and command, "results"}``) and,
    with ``markdown``, ``OUT/<name>.md``; prints the markdown. Returns the JSON's path."""
    config = {k: v for k, v in vars(args).items() if k != "output"}
    path = write_json(args.output / f"{name}.json", {"config": config, "results": results})
    if markdown is not None:
        write_atomic(args.output / f"{name}.md", markdown)
        print(markdown, end="")
    return path


def best_baselines(baselines: dict[str, dict[str, float]]) -> tuple[float, float]:
    """The best F1 and the best changed-cell F1 among the baselines (not necessarily one's)."""
    best_f1 = max(b["f1"] for b in baselines.values())
    return best_f1, max(b["changed_f1"] for b in baselines.values())


def margins(scores: dict) -> tuple[float, float]:
    """The model's F1 and changed-cell F1 less the best baselines' (:func:`best_baselines`), of
    ``scores`` as :func:`model_and_baselines` gives them."""
    best_f1, best_changed = best_baselines(scores["baselines"])
    return scores["model"]["f1"] - best_f1, scores["model"]["changed_f1"] - best_changed


def model_and_baselines(methods: dict[str, dict]) -> dict[str, dict]:
    """``{"model": ..., "baselines": {name: ...}}`` (METRICS only) from an evaluation's
    methods of one recording that holds one model beside the baselines."""
    # Besides the baselines an evaluation may hold references the verdict does not count
    # (copy_last_ego, scored beside an ego-motion model on a recording with poses).
    (model_key,) = [k for k in methods if k not in (*BASELINES, *REFERENCES)]
    scores = {
        "model": _metrics(methods[model_key]),
        "baselines": {b: _metrics(methods[b]) for b in BASELINES if b in methods},
    }
    if refs := {r: _metrics(methods[r]) for r in REFERENCES if r in methods}:
        scores["references"] = refs
    return scores


def _metrics(scores: dict[str, Any]) -> dict[str, Any]:
    """METRICS of one method's scores, and the mover metric where it was scored (not None)."""
    kept = {k: scores[k] for k in METRICS}
    kept.update({k: scores[k] for k in MOVER_METRICS if scores.get(k) is not None})
    return kept


def mover_margin(model: dict[str, Any], baselines: dict[str, dict[str, Any]]) -> float | None:
    """The model's tolerant mover F1 less copy-last's; ``None`` where either was not scored
    (then the mover metric does not decide a verdict)."""
    copy_last = baselines.get("copy_last", {})
    if model.get(MOVER_KEY) is None or copy_last.get(MOVER_KEY) is None:
        return None
    return float(model[MOVER_KEY] - copy_last[MOVER_KEY])


def split_online(methods: dict[str, dict]) -> tuple[dict[str, dict], dict | None]:
    """An evaluation's methods of one recording scored with both decision rules, split into
    those with the model's own rule (the offsets chosen online) and the other rule's scores
    (the fixed offsets; ``None`` when it holds one rule only)."""
    # The model's own rule is NAME; the other is NAME_fixed, or NAME when it has NAME_online.
    if fixed_keys := [k for k in methods if k.endswith("_fixed")]:
        (other,) = fixed_keys
    elif online_keys := [k for k in methods if k + "_online" in methods]:
        (other,) = online_keys
    else:
        return dict(methods), None
    kept = {k: v for k, v in methods.items() if k != other}
    return kept, methods[other]


def verdict(model: dict[str, float], baselines: dict[str, dict[str, float]]) -> str:
    """``wins``: F1 above the best baseline's, changed-cell F1 above every baseline's and
    tolerant mover F1 above copy-last's where it was scored (``loses movers`` where only that
    fails); else ``F1 only``, ``changed only`` or ``loses``."""
    best_f1, best_changed = best_baselines(baselines)
    wins_f1, wins_changed = model["f1"] > best_f1, model["changed_f1"] > best_changed
    if wins_f1 and wins_changed:
        movers = mover_margin(model, baselines)
        return "wins" if movers is None or movers > 0 else "loses movers"
    if wins_f1:
        return "F1 only"
    if wins_changed:
        return "changed only"
    return "loses"


def judged(methods: dict[str, dict]) -> dict[str, Any]:
    """:func:`model_and_baselines` of ``methods`` (the model's own decision rule where both
    were scored) with the verdict and the margins over the best baselines."""
    scores: dict[str, Any] = model_and_baselines(split_online(methods)[0])
    f1_margin, changed_margin = margins(scores)
    scores["verdict"] = verdict(scores["model"], scores["baselines"])
    scores["margins"] = {"f1": round(f1_margin, 4), "changed_f1": round(changed_margin, 4)}
    if (movers := mover_margin(scores["model"], scores["baselines"])) is not None:
        scores["margins"]["mover_f1_tolerant"] = round(movers, 4)
    return scores
