"""``predict_to_bag``: the topic groups written, the flow pictures, and the output's size."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.errors import PredictError
from lidarflow.flowcolor import flow_to_rgb
from lidarflow.outputs.job import (
    DEFAULT_TOPICS,
    FLOW_QUANTUM_CELLS,
    FLOW_RGB_FULL_CELLS,
    TOPIC_GROUPS,
    predict_to_bag,
)
from lidarflow.predict import Predictor
from tests.conftest import FLOW_MODEL, make_model_dir
from tests.outputs.test_rosout import read_all

PREDICTIONS = {"occupancy", "predicted", "decided", "moving"}


def test_by_default_everything_but_the_flow(tmp_path, sample_recording):
    recording = sample_recording.slice(0, 3)
    counts = predict_to_bag(recording, Predictor(FLOW_MODEL), tmp_path / "o.mcap")
    assert set(counts) == {"/right_scan"} | {f"/lidarflow/{t}" for t in PREDICTIONS}
    assert {"input"} | PREDICTIONS == DEFAULT_TOPICS
    # The bundled model, the occupancy head alone since v9: no moving cells, no flow, even asked
    counts = predict_to_bag(recording, Predictor(), tmp_path / "b.mcap", topics=set(TOPIC_GROUPS))
    assert set(counts) == {"/right_scan"} | {
        f"/lidarflow/{t}" for t in PREDICTIONS - {"moving"} | {"planner_grid"}
    }


def test_flow_comes_with_its_colour_wheel_picture(tmp_path, sample_recording):
    recording = sample_recording.slice(0, 3)
    predictor = Predictor(FLOW_MODEL)
    counts = predict_to_bag(
        recording, predictor, tmp_path / "o.mcap", topics=DEFAULT_TOPICS | {"flow"}
    )
    for name in ("backward", "forward"):
        assert counts[f"/lidarflow/flow_{name}"] == counts[f"/lidarflow/flow_{name}_rgb"] == 3
    msgs = read_all(tmp_path / "o.mcap")
    raw, picture = msgs["/lidarflow/flow_forward"][-1], msgs["/lidarflow/flow_forward_rgb"][-1]
    flow = np.moveaxis(np.frombuffer(bytes(raw.data), "<f4").reshape(100, 100, 2), -1, 0)
    assert (picture.encoding, picture.height, picture.width) == ("rgb8", 100, 100)
    assert picture.header == raw.header
    np.testing.assert_array_equal(
        np.asarray(picture.data).reshape(100, 100, 3), flow_to_rgb(flow, FLOW_RGB_FULL_CELLS)
    )
    # the flow as the predictor gave it, to the quantum that lets it compress
    predictor.reset()
    for scan in recording:
        p = predictor.update(scan)
    np.testing.assert_allclose(flow, p.forward_flow, rtol=0, atol=FLOW_QUANTUM_CELLS / 2 + 1e-6)
    assert np.all(flow * 1024 == np.round(flow * 1024))


def test_only_the_groups_asked_for(tmp_path, sample_recording):
    bag = sample_bag_path()
    counts = predict_to_bag(
        sample_recording.slice(0, 3), Predictor(), tmp_path / "o.bag", topics={"predicted"},
        source=bag,
    )  # fmt: skip
    assert counts == {"/lidarflow/predicted": 3}
    with pytest.raises(PredictError, match="unknown topic group 'flwo'"):
        predict_to_bag(sample_recording, Predictor(), tmp_path / "x.bag", topics={"flwo"})
    assert not (tmp_path / "x.bag").exists()


@pytest.mark.parametrize("name", ["out.mcap", "out.bag"])
def test_a_prediction_file_is_at_most_five_times_its_input(tmp_path, name):
    # issue 37's target, with every default topic; uncompressed and with the flow it was 63x
    bag = sample_bag_path()
    # a small random flownet: quick, and its maps no easier to compress than a trained one's
    model = make_model_dir(
        tmp_path / "random", zero_init_flow=False, hidden_channels=4, dilations=(1,)
    )
    counts = predict_to_bag(read_bag(bag), Predictor(model), tmp_path / name, source=bag)
    assert set(counts) >= {f"/lidarflow/{t}" for t in PREDICTIONS}
    assert (tmp_path / name).stat().st_size <= 5 * bag.stat().st_size
