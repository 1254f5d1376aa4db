"""Shared fixtures: small recordings made in memory, and the bundled real sample."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

from lidarflow.data import Recording, read_bag, sample_bag_path
from lidarflow.scan import BeamGeometry, Scan

# The machines are shared: a loaded core makes generating examples "too slow" and examples miss
# deadlines, which says nothing about the code under test.
settings.register_profile("shared", suppress_health_check=[HealthCheck.too_slow], deadline=None)
settings.load_profile("shared")


def make_recording(
    n: int = 30, beams: int = 181, rate_hz: float = 10.0, seed: int = 0, poses: bool = False
) -> Recording:
    """A synthetic recording: a wall at 4 m with a few random returns, 180 degrees."""
    rng = np.random.default_rng(seed)
    geom = BeamGeometry(beams, -np.pi / 2, np.pi / (beams - 1), 0.05, 8.0)
    scans = []
    for i in range(n):
        ranges = np.full(beams, 4.0, dtype=np.float32) + rng.normal(0, 0.01, beams).astype(
            np.float32
        )
        ranges[rng.integers(0, beams, 5)] = np.inf
        ranges[rng.integers(0, beams, 3)] = np.nan
        scans.append(Scan(ranges, geom, int(1_000_000_000 + i * 1e9 / rate_hz)))
    pose_arr = np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.zeros(n)]) if poses else None
    return Recording.from_scans(scans, poses=pose_arr, meta={"source": "synthetic"})


#: lidarflow's bundled model to v8: the head on a trained flow network. The bundled model is the
#: head alone since v9 (issue 36), so tests of the flow path (flow fields, moving cells, flow
#: topics) stream this one.
FLOW_MODEL = Path(__file__).parent / "fixtures" / "flownet_v8"


@pytest.fixture
def synthetic_recording() -> Recording:
    return make_recording()


@pytest.fixture(scope="session")
def sample_recording() -> Recording:
    return read_bag(sample_bag_path())


#: Tests slow as a whole (left out of the fast tier, ``scripts/test.sh --fast``): the studies'
#: smoke tests, the regression pins and the benchmarks, and those that need what only
#: scripts/test.sh installs (ROS 1 and 2, a browser, the npm client). Others say so one by one
#: (``@pytest.mark.slow``: over about a second on a quiet 2-core machine).
SLOW_FOLDERS = ("studies", "regression", "benchmarks")
SLOW_MODULES = {
    "test_ros1_node.py", "test_ros1_poses.py", "test_ros2_node.py", "test_foxglove_npm.py",
    "test_html_render.py",
}  # fmt: skip


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    tests = Path(__file__).parent
    for item in items:
        where = item.path.relative_to(tests).parts
        if where[0] in SLOW_FOLDERS or where[-1] in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def short(tmp_path) -> Path:
    """The sample's first 14 scans as a recording file: the smallest real input a command
    runs on."""
    return read_bag(sample_bag_path()).slice(0, 14).save(tmp_path / "short.npz")


@pytest.fixture
def compile_now(monkeypatch):
    """The compiled kernels compile in their first caller, not in the background: a test that
    compares a kernel with its NumPy reference gets the kernel on its first call."""
    from lidarflow import compiled

    monkeypatch.setattr(compiled, "background", False)


def make_model_dir(folder, name: str = "flownet", seed: int = 0, **kwargs):
    """A run folder as `lidarflow train` leaves it, holding an untrained (random) model."""
    import json

    import torch
    from safetensors.torch import save_file

    from lidarflow.models import ModelSpec, build
    from lidarflow.models.weights import decision_record

    torch.manual_seed(seed)
    spec, decision = ModelSpec.from_kwargs(name, kwargs)  # the decision keys: its policy
    net = build(spec)
    folder.mkdir(parents=True, exist_ok=True)
    save_file(
        {k: v.contiguous() for k, v in net.state_dict().items()}, folder / "model.safetensors"
    )
    record = {"model": name, "model_kwargs": spec.to_kwargs()}
    record["decision"] = decision_record({"model_kwargs": decision})
    (folder / "model.json").write_text(json.dumps(record))
    return folder


@pytest.fixture
def random_flownet_dir(tmp_path):
    """A flownet whose flow head is random (not zero), so its flow is not trivially zero."""
    return make_model_dir(tmp_path / "random_flownet", zero_init_flow=False)


@pytest.fixture(scope="session")
def flow_onnx(tmp_path_factory) -> Path:
    """:data:`FLOW_MODEL` as ONNX with its decision policy, as `lidarflow export` writes it:
    what the live tests of moving cells and the flow image serve."""
    from lidarflow.models.presets import resolve_model
    from lidarflow.outputs.export import export_onnx
    from lidarflow.predict.decision import DecisionPolicy

    net, card = resolve_model(FLOW_MODEL)
    path = tmp_path_factory.mktemp("flow_onnx") / "flownet_v8.onnx"
    return export_onnx(net, path, 100, 100, 0.1, DecisionPolicy.from_record(card["decision"]))
