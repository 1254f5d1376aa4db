"""What a command refuses before any work (issue 43): a horizon the recording cannot use, an
output that is one of its inputs."""

from __future__ import annotations

import numpy as np
import pytest

from tests.bagutil import write_bag
from tests.test_cli import run


@pytest.fixture
def short_bag(tmp_path):
    """A ROS 1 bag of 14 scans."""
    return write_bag(tmp_path / "short.bag", "ros1", {"/scan": [np.full(50, 3.0)] * 14})


@pytest.mark.parametrize("command", ["predict", "live"])
def test_a_horizon_the_recording_cannot_use_is_refused_at_once(tmp_path, capsys, short_bag,
                                                               command):  # fmt: skip
    # 14 frames hold predictions up to 13 ahead; 100000 ahead ran with no bound (issue 43)
    out = ["-o", str(tmp_path / "x.mcap")] if command == "predict" else ["--port", "0"]
    for horizon in ("14", "100000"):
        code, _, err = run([command, str(short_bag), *out, "--horizon", horizon], capsys)
        assert code == 1 and len(err.strip().splitlines()) == 1, err
        assert f"{short_bag}: too short for --horizon {horizon}: needs at least" in err
        assert "has 14 frames" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["short.bag"]
