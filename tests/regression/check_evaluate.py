"""Compare ``lidarflow evaluate`` reports with the numbers main ``a4a22da`` reported (the
baselines, and v8, the bundled model then: a flow model, ``tests/fixtures/flownet_v8``, scored
under its folder's name) and with those of the bundled model when it was installed (v10, issue
44: v9's head with the tracked movers laid over its decided map; v9's own pins are
``git show d2cbbbf:tests/regression/evaluate_v9.json``).

    M=tests/fixtures/flownet_v8
    lidarflow evaluate ../shared/data/*.bag ../shared/data/*.zip -m bundled -m $M --json eval.json
    lidarflow evaluate ../shared/data/positive_1.bag ../shared/data/datmo_overtakes.bag \\
        -m $M --horizon 10 --json horizon.json
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
#: The bundled model v10's scores when it was installed (one step ahead).
PINNED_V10 = Path(__file__).with_name("evaluate_v10.json")
#: evaluate's name for v8, the model ``bundled`` named in a4a22da's pins.
V8 = "flownet_v8"
TOLERANCE = 1e-4
KEYS = ("f1", "precision", "recall", "ap", "changed_f1")


def pinned_reports() -> list[dict[str, Any]]:
    """a4a22da's pins with their bundled model under v8's name, and v10's pins."""
    v8 = json.loads(PINNED.read_text())["recordings"]
    for pin in v8.values():
        pin["methods"][V8] = pin["methods"].pop("bundled")
        if "bundled" in (pin.get("horizon10_f1") or {}):
            pin["horizon10_f1"][V8] = pin["horizon10_f1"].pop("bundled")
    return [v8, json.loads(PINNED_V10.read_text())["recordings"]]


def moved(report: dict[str, Any], pinned: dict[str, Any] | None = None) -> list[str]:
    """What differs between ``report`` (an evaluate JSON) and the pinned numbers (default: both
    sets of :func:`pinned_reports`) of the methods it scored."""
    if pinned is None:
        return [d for pins in pinned_reports() for d in moved(report, pins)]
    out = []
    for entry in report["recordings"]:
        name = Path(entry["path"]).name
        pin = pinned[name]
        if entry["frames_evaluated"] != pin["frames"]:
            out.append(f"{name}: {entry['frames_evaluated']} frames, pinned {pin['frames']}")
        for method, values in pin["methods"].items():
            if method not in entry["methods"]:
                continue  # not scored in this report (v8 is scored only when asked for)
            for key in KEYS:
                now = entry["methods"][method][key]
                if abs(now - values[key]) > TOLERANCE:
                    out.append(f"{name} {method} {key}: {now:.6f}, pinned {values[key]:.6f}")
        horizon = entry.get("horizon_f1") or {}
        for method, was_values in (pin.get("horizon10_f1") or {}).items() if horizon else ():
            if method not in horizon:
                continue
            values = horizon[method]  # the baselines rolled forward since are not pinned
            for k, (now, was) in enumerate(zip(values, was_values, strict=False)):
                if abs(now - was) > TOLERANCE:
                    out.append(f"{name} {method} k={k + 1}: {now:.6f}, pinned {was:.6f}")
    return out


def main(paths: list[str]) -> int:
    differences = [d for p in paths for d in moved(json.loads(Path(p).read_text()))]
    print("\n".join(differences) or "every number as pinned (a4a22da; v9 at its install)")
    return 1 if differences else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
