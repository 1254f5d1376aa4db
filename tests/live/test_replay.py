"""The replay loop behind ``lidarflow live``: the recorded pace, passes, and what the server is
handed (a recording server stands in for the WebSocket one)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from lidarflow.live.replay import Served, loop_shift_ns, replay
from lidarflow.predict import Predictor
from lidarflow.scan import GridSpec
from tests.conftest import make_model_dir


class Recorder:
    """Stands in for a LiveServer: keeps what it is handed, and when."""

    def __init__(self) -> None:
        self.got: list[tuple[float, int, int]] = []  # (time, scan stamp, prediction stamp)

    def publish(self, scan, prediction, log_time_ns=None) -> None:
        self.got.append((time.monotonic(), scan.stamp_ns, prediction.stamp_ns))


@pytest.fixture(scope="module")
def predictor(tmp_path_factory):
    folder = make_model_dir(tmp_path_factory.mktemp("model"))
    return Predictor(folder, GridSpec(32, 32, 0.2))  # small: the loop is tested, not the model


def short(sample_recording, n=6):
    return sample_recording.slice(0, n)


def test_scans_go_out_at_the_recorded_pace_and_a_pass_ends(sample_recording, predictor):
    recording = short(sample_recording)
    server = Recorder()
    served = replay(recording, predictor, server, speed=2.0)
    assert (served.scans, served.passes) == (len(recording), 1)
    assert len(served.update_s) == len(served.publish_s) == len(recording)
    times, stamps, predicted = (np.array(x) for x in zip(*server.got, strict=True))
    np.testing.assert_array_equal(stamps, recording.stamps_ns)  # every scan, in order, once
    np.testing.assert_array_equal(predicted, stamps)  # each prediction made from its own scan
    # at twice the pace: each scan not before its time (stamp offset / 2), give or take a tick
    due = (stamps - stamps[0]) / 1e9 / 2
    assert np.all(times - times[0] >= due - due[1] / 2)
    assert times[-1] - times[0] >= 0.9 * due[-1]


def test_speed_zero_waits_for_nothing_and_loop_moves_the_stamps_on(sample_recording, predictor):
    recording = short(sample_recording)
    shift = loop_shift_ns(recording)
    step = int(np.median(np.diff(recording.stamps_ns)))
    span = int(recording.stamps_ns[-1] - recording.stamps_ns[0])
    assert shift - span == pytest.approx(step, rel=0.01)  # as if recorded again right after

    class Stopping(Recorder):  # Ctrl-C in the middle of the third pass
        def publish(self, scan, prediction, log_time_ns=None) -> None:
            super().publish(scan, prediction, log_time_ns)
            if len(self.got) == 2 * len(recording) + 3:
                raise KeyboardInterrupt

    server, served = Stopping(), Served()
    with pytest.raises(KeyboardInterrupt):
        replay(recording, predictor, server, speed=0, loop=True, served=served)
    assert (served.passes, served.scans) == (2, 2 * len(recording) + 2)  # the last one unpublished
    stamps = np.array([s for _, s, _ in server.got])
    n = len(recording)
    np.testing.assert_array_equal(stamps[n : 2 * n], recording.stamps_ns + shift)
    np.testing.assert_array_equal(stamps[2 * n :], recording.stamps_ns[:3] + 2 * shift)
    assert np.all(np.diff(stamps) > 0)  # the clock a client sees never goes back
    assert served.worst_lag_s == 0.0  # nothing was due
