"""Issue 51: input that is at fault is said to be, in one line naming the option or file (not
an internal error, not gigabytes asked of PyTorch, not an exit 0 with nonsense)."""

from __future__ import annotations

import pytest

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.scan import MAX_RES
from tests.test_cli import run
from tests.test_cli_faults import one_line


@pytest.fixture
def short(tmp_path):
    return read_bag(sample_bag_path()).slice(0, 14).save(tmp_path / "short.npz")


@pytest.mark.parametrize(
    "argv",
    [
        ["predict", "{rec}", "-o", "{out}/p.mcap", "--res", "1e300"],
        ["evaluate", "{rec}", "--baselines-only", "--res", "1e300"],
        ["simulate", "--frames", "3", "-o", "{out}/s.npz", "--res", "1e300"],
        ["show", "{rec}", "-o", "{out}/s.png", "--res", "1e300"],
        ["convert", "{rec}", "-o", "{out}/c.npz", "--res", "1e300"],
        ["choose-offset", "{rec}", "-o", "{out}/m", "--res", "1e300"],
        ["train", "{rec}", "-o", "{out}/run", "--res", "1e300", "--epochs", "1"],
    ],
)
def test_a_cell_size_beyond_reason_is_refused(argv, short, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run([a.format(rec=short, out=out) for a in argv], capsys)
    line = one_line(err)
    assert code == 1 and "--res" in line and "1e+300 m" in line, line
    assert f"at most {MAX_RES:g} m" in line, line
    assert not out.exists() or not any(out.iterdir())
