"""Compare ``lidarflow evaluate`` reports with the numbers main ``a4a22da`` reported.

    lidarflow evaluate ../shared/data/*.bag ../shared/data/*.zip --json eval.json
    lidarflow evaluate ../shared/data/positive_1.bag ../shared/data/datmo_overtakes.bag \\
        --horizon 10 --json horizon.json
    python tests/regression/check_evaluate.py eval.json horizon.json

Prints every number that moved by more than ``TOLERANCE`` (none, when the house restructuring
changed nothing it should not) and exits 1 if any did.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

PINNED = Path(__file__).with_name("evaluate_a4a22da.json")
TOLERANCE = 1e-4
KEYS = ("f1", "precision", "recall", "ap", "changed_f1")


def moved(report: dict[str, Any], pinned: dict[str, Any] | None = None) -> list[str]:
    """What differs between ``report`` (an evaluate JSON) and the pinned numbers."""
    pinned = pinned or json.loads(PINNED.read_text())["recordings"]
    out = []
    for entry in report["recordings"]:
        name = Path(entry["path"]).name
        pin = pinned[name]
        if entry["frames_evaluated"] != pin["frames"]:
            out.append(f"{name}: {entry['frames_evaluated']} frames, pinned {pin['frames']}")
        for method, values in pin["methods"].items():
            for key in KEYS:
                now = entry["methods"][method][key]
                if abs(now - values[key]) > TOLERANCE:
                    out.append(f"{name} {method} {key}: {now:.6f}, pinned {values[key]:.6f}")
        horizon = entry.get("horizon_f1") or {}
        for method, was_values in (pin.get("horizon10_f1") or {}).items() if horizon else ():
            values = horizon[method]  # the baselines rolled forward since are not pinned
            for k, (now, was) in enumerate(zip(values, was_values, strict=False)):
                if abs(now - was) > TOLERANCE:
                    out.append(f"{name} {method} k={k + 1}: {now:.6f}, pinned {was:.6f}")
    return out


def main(paths: list[str]) -> int:
    differences = [d for p in paths for d in moved(json.loads(Path(p).read_text()))]
    print("\n".join(differences) or "every number as a4a22da reported it")
    return 1 if differences else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
