"""The Predictor's moving cells and the /lidarflow/moving grid in written bags."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.errors import PredictError
from lidarflow.outputs.job import predict_to_bag
from lidarflow.outputs.rosout import map_from_grid_data
from lidarflow.predict import Predictor
from lidarflow.predict.moving import moving_mask
from tests.conftest import FLOW_MODEL, make_model_dir
from tests.outputs.test_rosout import read_all

# A trained flow model (v8, the bundled one until v9 dropped the flow network): a random flow
# head's flow is too small and smooth to move anything.


def test_prediction_moving_is_the_segmentation_of_its_forward_flow(sample_recording):
    predictor = Predictor(FLOW_MODEL, moving_threshold=0.3)
    for i in range(3):
        p = predictor.update(sample_recording.scan(i))
    assert p.moving.dtype == bool and p.moving.shape == (100, 100)
    np.testing.assert_array_equal(p.moving, moving_mask(p.occupancy, p.forward_flow, 0.3))
    assert not (p.moving & ~p.occupancy).any()
    assert p.moving.any()
    still = Predictor(FLOW_MODEL, moving_threshold=1e6).update(sample_recording.scan(0))
    assert not still.moving.any()


def test_no_flow_no_moving_and_bad_threshold(tmp_path, sample_recording):
    p = Predictor(make_model_dir(tmp_path / "dt", name="deeptracking")).update(
        sample_recording.scan(0)
    )
    assert p.moving is None
    # nor from the bundled model, the occupancy head alone since v9
    assert Predictor().update(sample_recording.scan(0)).moving is None
    with pytest.raises(PredictError, match="moving_threshold"):
        Predictor(tmp_path / "dt", moving_threshold=-1.0)


@pytest.mark.parametrize("name", ["out.bag", "out.mcap"])
def test_moving_grid_is_written_and_reads_back(tmp_path, sample_recording, name):
    recording = sample_recording.slice(0, 4)
    predictor = Predictor(FLOW_MODEL)
    counts = predict_to_bag(recording, predictor, tmp_path / name)
    assert counts["/lidarflow/moving"] == 4
    grid = read_all(tmp_path / name)["/lidarflow/moving"][-1]
    back = map_from_grid_data(grid.data, grid.info.width, grid.info.height)
    predictor.reset()
    for scan in recording:
        p = predictor.update(scan)
    expected = np.where(p.moving, 100, 0)
    expected[~p.visibility] = -1
    np.testing.assert_array_equal(back, expected)
    assert set(np.unique(back)) <= {-1, 0, 100} and (back == 100).any()


@pytest.mark.parametrize("flow_free", ["deeptracking", "bundled"])
def test_a_flow_free_models_bag_has_no_moving_topic(tmp_path, sample_recording, flow_free):
    model = make_model_dir(tmp_path / "dt", name="deeptracking") if flow_free != "bundled" else None
    predictor = Predictor(model)
    counts = predict_to_bag(sample_recording.slice(0, 2), predictor, tmp_path / "o.mcap")
    assert "/lidarflow/moving" not in counts and counts["/lidarflow/predicted"] == 2


@pytest.mark.parametrize("copy", [False, True], ids=["recording", "bag copied"])
@pytest.mark.parametrize("name", ["out.bag", "out.mcap"])
def test_predictions_keep_the_bags_own_stamps_where_its_clock_went_back(tmp_path, name, copy):
    # read, the second session is re-stamped to follow the first; written, it must line up with
    # the bag it came from again
    from lidarflow.data import read_bag
    from tests.bagutil import write_bag

    t0, period = 1_700_000_000 * 10**9, 100_000_000
    headers = [t0 + (i if i < 8 else i - 8) * period for i in range(14)]
    frames = [np.full(50, 2.0 + 0.01 * i) for i in range(14)]
    bag = write_bag(tmp_path / "j.bag", "ros1", {"/scan": frames}, header_stamps=headers)
    recording = read_bag(bag)
    assert recording.meta["clock_jumps"] and recording.stamps_ns[8] > headers[7]
    predict_to_bag(recording, Predictor(), tmp_path / name, source=bag if copy else None)
    written = read_all(tmp_path / name)

    def stamps(messages, field="header"):
        times = [m.header.stamp if field == "header" else m.info.map_load_time for m in messages]
        return [t.sec * 10**9 + t.nanosec for t in times]

    # in the order recorded, each with its own stamp; a prediction for one period later (the
    # first scan's for its own time: no period known yet), made from its scan
    assert stamps(written["/scan"]) == headers
    assert stamps(written["/lidarflow/occupancy"]) == headers
    ahead = [headers[0]] + [h + period for h in headers[1:]]
    assert stamps(written["/lidarflow/predicted"]) == ahead
    assert stamps(written["/lidarflow/predicted"], "made") == headers
    # and read back, the output is the same two sessions, not interleaved
    back = read_bag(tmp_path / name)
    np.testing.assert_array_equal(back.stamps_ns, recording.stamps_ns)
    assert back.meta["clock_jumps"] == recording.meta["clock_jumps"]
