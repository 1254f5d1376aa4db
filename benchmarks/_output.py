"""What every benchmark writes beside its numbers: the machine, and the JSON file itself."""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path
from typing import Any


def machine() -> dict[str, Any]:
    """CPU count, platform, Python and (where installed) torch versions of this machine."""
    info: dict[str, Any] = {
        "cpus": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
    }
    try:
        import torch
    except ImportError:
        return info
    info["torch"] = torch.__version__
    return info


def write_json(path: Path, result: dict[str, Any]) -> None:
    """Write ``result`` to ``path`` (folders made as needed), whole or not at all (a killed
    benchmark leaves the previous file), and say so."""
    from lidarflow.atomic import write_text

    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(result, indent=2))
    print(f"wrote {path}")
