"""What the ros1/ros2 commands say around their node, without ROS: a --moving the model cannot
serve is refused before the node starts, and a node that got no scan says so."""

from __future__ import annotations

import pytest

from lidarflow.cli import robot
from lidarflow.errors import ModelError


def test_moving_with_a_model_without_flow_is_refused():
    with pytest.raises(ModelError, match="estimates no flow; name a flow model"):
        robot._live_step(robot.NodeOptions(moving=True))


def test_moving_with_a_flow_model_is_served(random_flownet_dir):
    step = robot._live_step(robot.NodeOptions(model=random_flownet_dir, moving=True))
    assert step.predictor.backend.capabilities.flow


class _Idle:
    """A node that starts and stops with no scan."""

    def start(self) -> None: ...

    def spin(self) -> None: ...


@pytest.mark.parametrize("scans", [0, 2])
def test_the_last_line_says_whether_any_scan_arrived(scans, capsys):
    step = robot._live_step(robot.NodeOptions())
    step.latency.all_ms.extend([1.0] * scans)
    robot._run("ros2", step, _Idle, robot.NodeOptions(topic="/front_scan"))
    err = capsys.readouterr().err.strip().splitlines()[-1]
    if scans:
        assert err.startswith("lidarflow ros2: latency over 2 scans: median")
    else:
        assert err == "lidarflow ros2: no scan arrived on /front_scan"
