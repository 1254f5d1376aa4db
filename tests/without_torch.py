"""Run Python as an install without the ``torch`` extra would: a prelude for ``python -c``
after which ``torch``, ``safetensors`` and ``onnx`` cannot be imported."""

from __future__ import annotations

from lidarflow.extras import TORCH_EXTRA_MODULES

PRELUDE = (
    f"import sys\nfor name in {sorted(TORCH_EXTRA_MODULES)!r}:\n    sys.modules[name] = None\n"
)
#: ``python -c MAIN ARGS...``: the ``lidarflow`` command, without the torch extra.
MAIN = PRELUDE + "import runpy\nrunpy.run_module('lidarflow', run_name='__main__')\n"
