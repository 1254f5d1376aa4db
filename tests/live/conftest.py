"""The ROS 1 master fixture and the short recording served to the Foxglove clients."""

import pytest

from tests.live.rosmaster import ros_env  # noqa: F401


@pytest.fixture(scope="module")
def short_flow(tmp_path_factory, flow_onnx):
    """The first ``serve_recording.SCANS`` scans of the bundled sample, and a flow model."""
    from lidarflow.data import read_bag, sample_bag_path
    from tests.live.serve_recording import SCANS

    folder = tmp_path_factory.mktemp("served")
    return read_bag(sample_bag_path()).slice(0, SCANS).save(folder / "short.npz"), flow_onnx
