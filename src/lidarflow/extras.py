"""The ``torch`` extra (PyTorch and what comes with it), which the core install leaves out:
where something needing it is asked for without it, one line names the extra."""

from __future__ import annotations

import importlib.util

from lidarflow.errors import LidarflowError

__all__ = ["TORCH_EXTRA_MODULES", "MissingExtraError", "missing_extra", "torch_available"]

#: The packages only the ``torch`` extra installs.
TORCH_EXTRA_MODULES = frozenset({"torch", "safetensors", "onnx"})
INSTALL_TORCH = "pip install 'lidarflow[torch]'"


class MissingExtraError(LidarflowError):
    """What was asked for needs a package of an extra this install lacks."""


def torch_available() -> bool:
    """Whether PyTorch can be imported (looked up, not imported: that takes seconds)."""
    try:
        return importlib.util.find_spec("torch") is not None
    except (ImportError, ValueError):  # ValueError: blocked (sys.modules["torch"] = None)
        return False


def missing_extra(err: ImportError, what: str = "this") -> MissingExtraError | None:
    """The error for ``err`` where it is a package of the ``torch`` extra missing (``what``:
    what needed it), else ``None``."""
    name = (getattr(err, "name", None) or "").split(".")[0]
    if name not in TORCH_EXTRA_MODULES:
        return None
    if torch_available():  # PyTorch is there, another package of its extra is not
        return MissingExtraError(
            f"{what} needs {name}, which comes with PyTorch in the torch extra but is not "
            f"installed; add it with {INSTALL_TORCH}"
        )
    return MissingExtraError(
        f"{what} needs PyTorch ({name} is not installed: the core install runs .onnx models "
        f"and the bundled one); add it with {INSTALL_TORCH}"
    )
