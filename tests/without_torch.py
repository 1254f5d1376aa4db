"""Run Python as the core install would (no ``torch`` or ``fast`` extra): a prelude for
``python -c`` after which ``torch``, ``safetensors``, ``onnx`` and ``numba`` cannot be
imported, so the NumPy references of the compiled kernels run."""

from __future__ import annotations

from lidarflow.extras import TORCH_EXTRA_MODULES

#: What the core install lacks: the torch extra's modules and the fast extra's numba.
CORE_MISSING = sorted({*TORCH_EXTRA_MODULES, "numba"})
PRELUDE = f"import sys\nfor name in {CORE_MISSING!r}:\n    sys.modules[name] = None\n"
#: ``python -c MAIN ARGS...``: the ``lidarflow`` command, without the torch extra.
MAIN = PRELUDE + "import runpy\nrunpy.run_module('lidarflow', run_name='__main__')\n"
