"""The core install, without PyTorch (issue 37): the user commands run on ONNX Runtime with the
bundled model's ONNX export, and what needs the ``torch`` extra says so in one line.

The commands run in a child process in which ``torch``, ``safetensors`` and ``onnx`` cannot be
imported (``sys.modules[name] = None``), as in an install without the extra; a real core install
(a fresh venv) is measured in the issue's closing note.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lidarflow.data import read_bag, sample_bag_path
from tests.without_torch import PRELUDE

CLI = "from lidarflow.cli import main\ntry:\n    main(sys.argv[1:])\nexcept SystemExit as e:\n"
CLI += "    if e.code:\n        raise\n"


def without_torch(body: str, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    # the parent's choice of BLAS kernels (OPENBLAS_CORETYPE): outputs are compared to the bit
    blas = {k: v for k, v in os.environ.items() if k.startswith("OPENBLAS_")}
    return subprocess.run(
        [sys.executable, "-c", PRELUDE + body, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
        env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin", **blas},
    )


@pytest.fixture(scope="module")
def short(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("core")
    return read_bag(sample_bag_path()).slice(0, 40).save(folder / "short.npz")


@pytest.mark.slow
def test_user_commands_run_the_bundled_model_without_torch(short):
    folder = short.parent
    info = without_torch(CLI, "info", str(sample_bag_path()), cwd=folder)
    assert info.returncode == 0 and "right_scan" in info.stdout, info.stderr
    converted = without_torch(CLI, "convert", str(sample_bag_path()), "-o", "c.npz", cwd=folder)
    assert converted.returncode == 0 and (folder / "c.npz").exists(), converted.stderr
    predicted = without_torch(CLI, "predict", str(short), "-o", "p.mcap", "--learn", cwd=folder)
    assert predicted.returncode == 0, predicted.stderr
    assert "/lidarflow/predicted x40" in predicted.stdout
    assert len(read_bag(folder / "p.mcap", topic="/right_scan")) == 40
    scored = without_torch(
        CLI, "evaluate", str(short), "--warmup", "5", "-o", "e.json", "--report", "r", "--learn",
        cwd=folder,
    )
    assert scored.returncode == 0, scored.stderr
    assert (folder / "r" / "index.html").exists()  # the HTML report's pictures: no PyTorch
    report = json.loads((folder / "e.json").read_text())
    bundled = report["config"]["models"]["bundled"]
    assert bundled["weights_path"].endswith("model.safetensors")  # read without PyTorch
    # the head learns on its own weights read without PyTorch
    assert set(report["recordings"][0]["methods"]) >= {"copy_last", "bundled", "bundled_learning"}


def test_what_needs_the_torch_extra_says_so_in_one_line(short, random_flownet_dir):
    folder = short.parent
    for argv, names in (
        (["train", str(short), "-o", "run"], "`lidarflow train` needs PyTorch"),
        (["export", "-o", "m.onnx"], "`lidarflow export` needs PyTorch"),
        (
            ["predict", str(short), "-m", str(random_flownet_dir), "-o", "q.mcap"],
            f"the model {random_flownet_dir} needs PyTorch",
        ),
    ):
        done = without_torch(CLI, *argv, cwd=folder)
        assert done.returncode == 1, (argv, done.stderr)
        lines = done.stderr.strip().splitlines()
        assert len(lines) == 1 and "lidarflow[torch]" in lines[0], (argv, done.stderr)
        assert names in lines[0] and "internal error" not in lines[0]
    assert not any((folder / name).exists() for name in ("run", "m.onnx", "q.mcap"))


def test_the_python_api_runs_the_bundled_model_without_torch_as_with_it(tmp_path, monkeypatch):
    # Both sides run the NumPy references (the child has no numba): on SIMD builds NumPy's
    # arctan2 may round a last bit apart from the C library's, which the kernels call.
    from lidarflow import compiled

    monkeypatch.setattr(compiled, "numba", None)
    body = (
        "import numpy as np\n"
        "from lidarflow.data import read_bag, sample_bag_path\n"
        "from lidarflow.predict import Predictor\n"
        "p = Predictor(horizon=2)\n"
        "rec = read_bag(sample_bag_path())\n"
        "out = [p.update(rec.scan(i)) for i in range(12)][-1]\n"
        "assert type(p.backend).__name__ == 'HeadStepBackend'\n"
        "np.save('probability.npy', out.probability)\n"
    )
    done = without_torch(body, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    from lidarflow.predict import Predictor

    torch_predictor = Predictor(horizon=2)  # the bundled weights, on PyTorch
    recording = read_bag(sample_bag_path())
    expected = [torch_predictor.update(recording.scan(i)) for i in range(12)][-1]
    # the same NumPy step on the same weights, read with and without PyTorch
    np.testing.assert_array_equal(np.load(tmp_path / "probability.npy"), expected.probability)


def test_a_non_finite_onnx_model_is_refused_without_the_onnx_package(tmp_path):
    import onnx
    from onnx import numpy_helper

    from lidarflow.models.presets import bundled_onnx

    graph = onnx.load(str(bundled_onnx()[0]))
    weight = max(graph.graph.initializer, key=lambda i: int(np.prod(i.dims)))
    values = numpy_helper.to_array(weight).copy()
    values.flat[0] = np.nan
    weight.CopyFrom(numpy_helper.from_array(values, weight.name))
    onnx.save(graph, str(tmp_path / "nan.onnx"))
    body = (
        "from lidarflow.errors import ModelError\n"
        "from lidarflow.predict import Predictor\n"
        "try:\n"
        "    Predictor('nan.onnx')\n"
        "except ModelError as err:\n"
        "    print(err)\n"
    )
    done = without_torch(body, cwd=tmp_path)
    assert done.returncode == 0 and "weights are not finite" in done.stdout, done.stderr
