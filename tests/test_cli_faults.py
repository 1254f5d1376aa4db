"""Issue 43: what the commands say of useless or impossible input, in lidarflow's words.

Each message names the file at fault and what it is not, in one line on stderr (never a
library's text, a temporary's name or a traceback); a grid that cannot fit is refused before
anything is allocated; a recording whose beams are mostly invalid, or that leaves nothing to
score, is said to be so rather than scored in silence.
"""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lidarflow.data import sample_bag_path
from lidarflow.scan import MAX_GRID_CELLS
from tests.bagutil import write_bag
from tests.test_cli import run

ROOT = Path(__file__).resolve().parents[1]


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "internal error" not in lines[0] and "Traceback" not in err, err
    return lines[0]


@pytest.mark.parametrize(
    "argv",
    [
        ["predict", "{rec}", "-o", "{out}/p.mcap", "--grid", "100000"],
        ["evaluate", "{rec}", "--baselines-only", "--grid", "100000"],
        ["simulate", "--frames", "3", "-o", "{out}/s.npz", "--grid", "100000"],
        ["show", "{rec}", "-o", "{out}/s.png", "--grid", "100000"],
        ["choose-offset", "{rec}", "-o", "{out}/m", "--grid", "100000"],
        ["train", "{rec}", "-o", "{out}/run", "--grid", "100000", "--epochs", "1"],
    ],
)
def test_a_grid_that_cannot_fit_is_refused_before_allocating(argv, short, tmp_path, capsys):
    out = tmp_path / "out"
    args = [a.format(rec=short, out=out) for a in argv]
    code, _, err = run(args, capsys)
    line = one_line(err)
    assert code == 1 and "100000 x 100000" in line and f"{MAX_GRID_CELLS:,}" in line, line
    assert not out.exists() or not any(out.iterdir())


def test_the_largest_grid_that_fits_is_a_grid():
    from lidarflow.errors import ScanError
    from lidarflow.scan import GridSpec

    side = int(MAX_GRID_CELLS**0.5)
    assert GridSpec(side, side).shape == (side, side)
    with pytest.raises(ScanError, match="too large"):
        GridSpec(side + 1, side + 1)


def _object_npz(path: Path) -> Path:
    np.savez(path, a=np.array([{"x": 1}], dtype=object))
    return path


def _plain_npy(path: Path) -> None:
    buffer = io.BytesIO()
    np.save(buffer, np.arange(3))
    path.write_bytes(buffer.getvalue())


@pytest.mark.parametrize(
    ("name", "make", "says"),
    [
        ("objects.npz", _object_npz, "not a lidarflow recording"),
        ("bytes.npz", lambda p: p.write_bytes(os.urandom(3000)), "not a lidarflow recording"),
        ("text.npz", lambda p: p.write_text("hello\n"), "not a lidarflow recording"),
        ("blank.npz", lambda p: p.write_bytes(b""), "is empty"),
        ("npy.npz", _plain_npy, "not a lidarflow recording"),
        ("bytes.bag", lambda p: p.write_bytes(os.urandom(5000)), "not a ROS 1 bag"),
        ("text.bag", lambda p: p.write_text("hello\n"), "not a ROS 1 bag"),
        ("blank.bag", lambda p: p.write_bytes(b""), "is empty"),
        ("bytes.mcap", lambda p: p.write_bytes(os.urandom(5000)), "not an MCAP file"),
    ],
)
def test_a_file_that_is_no_recording_or_bag_says_what_it_is_not(
    name, make, says, tmp_path, capsys
):
    path = tmp_path / name
    make(path)
    code, _, err = run(["evaluate", str(path), "--baselines-only"], capsys)
    line = one_line(err)
    assert code == 1 and str(path) in line and says in line, line
    for library_text in ("allow_pickle", "UnicodeDecodeError", "magic", "zip", "Error:"):
        assert library_text not in line, line


def test_a_recording_cut_short_says_so(short, tmp_path, capsys):
    cut = tmp_path / "cut.npz"
    cut.write_bytes(short.read_bytes()[: short.stat().st_size // 2])
    code, _, err = run(["evaluate", str(cut), "--baselines-only"], capsys)
    line = one_line(err)
    assert code == 1 and str(cut) in line and "cut short" in line, line


def test_an_output_that_cannot_be_written_is_named_not_its_temporary(capsys):
    code, _, err = run(["convert", str(sample_bag_path()), "-o", "/proc/x.npz"], capsys)
    line = one_line(err)
    assert code == 1 and "/proc/x.npz" in line and "partial" not in line, line


@pytest.fixture
def nan_bag(tmp_path):
    return write_bag(tmp_path / "nan.bag", scans={"/scan": [np.full(200, np.nan)] * 30})


@pytest.mark.slow
def test_evaluate_warns_of_invalid_beams_and_nothing_scored(nan_bag, capsys):
    code, _, err = run(["evaluate", str(nan_bag), "--baselines-only"], capsys)
    assert code == 0
    warnings = [line for line in err.splitlines() if line.startswith("warning:")]
    assert any("nan.bag" in w and "100% of its beams are invalid" in w for w in warnings), err
    assert any("nan.bag" in w and "nothing was scored" in w for w in warnings), err


@pytest.mark.slow
def test_choose_offset_writes_no_offset_from_nothing(nan_bag, tmp_path, capsys):
    out = tmp_path / "chosen"
    code, _, err = run(["choose-offset", str(nan_bag), "-o", str(out)], capsys)
    assert code == 1 and not out.exists()
    errors = [line for line in err.splitlines() if line.startswith("lidarflow: error:")]
    assert len(errors) == 1 and "nothing was scored" in errors[0], err
    assert "100% of its beams are invalid" in err


@pytest.mark.slow
@pytest.mark.parametrize("model", [None, "run"])
def test_a_model_needing_a_missing_package_is_named(model, tmp_path, short, random_flownet_dir):
    # torch there, safetensors not: a run folder was said to need PyTorch (and the bundled
    # model, called "the model None", too; it now reads its weights without either)
    body = (
        "import sys\nsys.modules['safetensors'] = None\n"
        "import runpy\nrunpy.run_module('lidarflow', run_name='__main__')\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    argv = ["evaluate", str(short)] + ([] if model is None else ["-m", str(random_flownet_dir)])
    done = subprocess.run(
        [sys.executable, "-c", body, *argv],
        capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    if model is None:  # the bundled model is read without either package
        assert done.returncode == 0, done.stderr[-2000:]
        return
    line = one_line(done.stderr)
    named = f"the model {random_flownet_dir}"
    assert done.returncode == 1 and "None" not in line and named in line, line
    assert "safetensors" in line and "lidarflow[torch]" in line, line
    assert "needs PyTorch" not in line, line  # PyTorch is there: safetensors is what is missing


def test_a_run_folder_without_its_weights_is_named(short, random_flownet_dir, capsys):
    (random_flownet_dir / "model.safetensors").unlink()
    code, _, err = run(["evaluate", str(short), "-m", str(random_flownet_dir)], capsys)
    line = one_line(err)
    assert code == 1 and str(random_flownet_dir) in line and "model.safetensors" in line, line
