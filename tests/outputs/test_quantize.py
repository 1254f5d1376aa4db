"""Int8 export: the quantized graph holds int8 convolutions and predicts (nearly) what the float
graph predicts; bad calibration input is refused in one line."""

from __future__ import annotations

import numpy as np
import onnx
import pytest

from lidarflow.errors import PredictError
from lidarflow.evaluate.metrics import confusion
from lidarflow.models.presets import resolve_model
from lidarflow.outputs.export import export_onnx
from lidarflow.outputs.quantize import head_convs, quantize_onnx
from lidarflow.predict import Predictor
from lidarflow.predict.decision import DecisionPolicy
from tests.conftest import FLOW_MODEL
from tests.test_cli import run

#: every test here quantizes an exported model (a module fixture of seconds): slow as a whole
pytestmark = pytest.mark.slow


def stacked_maps(recording, start, stop, subcell=True):
    """A recording's maps as v8 and the bundled model take them (they have ``subcell_input``)."""
    return recording.stacked_maps(start=start, stop=stop, subcell=subcell)


@pytest.fixture(scope="module")
def float_and_int8(tmp_path_factory, sample_recording):
    folder = tmp_path_factory.mktemp("q")
    # v8, a trained flow model (the bundled one is the head alone since v9): realistic ranges
    net, card = resolve_model(FLOW_MODEL)
    policy = DecisionPolicy.from_record(card["decision"])
    float_path = export_onnx(net, folder / "float.onnx", decision=policy)
    calibration = stacked_maps(sample_recording, 0, 40)
    int8_path = quantize_onnx(float_path, folder / "int8.onnx", calibration)
    return float_path, int8_path


@pytest.mark.slow
def test_convolutions_are_int8_and_the_rest_is_float(float_and_int8):
    _, int8_path = float_and_int8
    graph = onnx.load(str(int8_path)).graph
    ops = [node.op_type for node in graph.node]
    assert ops.count("Conv") > 0 and "DequantizeLinear" in ops
    int8_weights = [t for t in graph.initializer if t.data_type == onnx.TensorProto.INT8]
    assert len(int8_weights) >= 8  # Table I's eight convs store their weights as int8
    assert "GridSample" in ops and "Sigmoid" in ops  # warp and gates stay float


@pytest.mark.slow
def test_table_one_convs_are_int8_and_the_head_stays_float(float_and_int8):
    float_path, int8_path = float_and_int8
    graph = onnx.load(str(int8_path)).graph
    dequantized = {out for n in graph.node if n.op_type == "DequantizeLinear" for out in n.output}
    convs = [n for n in graph.node if n.op_type == "Conv"]
    int8 = {n.name for n in convs if n.input[1] in dequantized}
    head = set(head_convs(float_path))
    assert len(head) == 2 and head <= {n.name for n in convs}  # v8's head: hidden, output
    assert not head & int8
    assert {"/flow/conv0/Conv", "/flow/conv_flow/Conv"} <= int8
    assert sum("/grus." in name for name in int8) == 6  # three ConvGRUs, two convs each


@pytest.mark.slow
def test_int8_predicts_what_float_predicts(float_and_int8, sample_recording):
    float_path, int8_path = float_and_int8
    # The arithmetic, with the model's fixed offsets: chosen online, a pair picked differently
    # for one frame moves probabilities by far more than int8 does (the F1 is compared below).
    a, b = (Predictor(p, online_decision=False) for p in (float_path, int8_path))
    scans = [sample_recording.scan(t) for t in range(40, 100)]  # not calibrated on
    occupancy = sample_recording.maps(start=40, stop=100)[0]
    predicted_a, predicted_b, differences = [], [], []
    for scan in scans:
        pa, pb = a.update(scan), b.update(scan)
        predicted_a.append(pa.occupied)
        predicted_b.append(pb.occupied)
        differences.append(np.abs(pa.probability - pb.probability).max())
    assert max(differences) > 0  # it did change the arithmetic
    assert max(differences) < 0.35
    targets = occupancy[11:]
    f1_float = confusion(np.stack(predicted_a[10:-1]), targets).f1
    f1_int8 = confusion(np.stack(predicted_b[10:-1]), targets).f1
    assert abs(f1_float - f1_int8) < 0.01 and f1_float > 0.9
    online = [Predictor(p) for p in (float_path, int8_path)]  # v8's policy asks for it
    assert all(p.online is not None for p in online)
    decided = [[p.update(scan).occupied for scan in scans] for p in online]
    f1_online = [confusion(np.stack(d[10:-1]), targets).f1 for d in decided]
    assert abs(f1_online[0] - f1_online[1]) < 0.01 and f1_online[0] > 0.9


def test_too_short_calibration_is_refused(float_and_int8, tmp_path, sample_recording):
    float_path, _ = float_and_int8
    with pytest.raises(PredictError, match="calibration needs more than 10 frames"):
        quantize_onnx(float_path, tmp_path / "x.onnx", stacked_maps(sample_recording, 0, 5))
    with pytest.raises(PredictError, match="no such folder for the ONNX file"):
        quantize_onnx(float_path, tmp_path / "no" / "x.onnx", stacked_maps(sample_recording, 0, 20))
    with pytest.raises(PredictError, match="calibration maps have 2 channels, the model takes 4"):
        quantize_onnx(float_path, tmp_path / "x.onnx", stacked_maps(sample_recording, 0, 20, False))


@pytest.mark.slow
def test_cli_export_int8(tmp_path, capsys, sample_recording):
    calibration = sample_recording.slice(0, 30).save(tmp_path / "cal.npz")
    out = tmp_path / "m8.onnx"
    code, stdout, err = run(
        ["export", "-o", str(out), "--int8", "--calibration", str(calibration)], capsys
    )
    assert code == 0, err
    assert "int8 convolutions calibrated on 30 frames of cal.npz" in stdout
    assert Predictor(out).update(sample_recording.scan(0)).probability.shape == (100, 100)
    code, _, err = run(
        ["export", "-o", str(tmp_path / "again.onnx"), "--int8", "--calibration",
         str(tmp_path / "no.bag")], capsys,
    )  # fmt: skip
    assert code == 1 and err.count("\n") == 1 and "no such file" in err
    assert not (tmp_path / "again.onnx").exists()


@pytest.mark.slow
def test_computed_kernels_of_the_constant_velocity_input_stay_float(tmp_path, sample_recording):
    from lidarflow.outputs.quantize import data_dependent_convs
    from tests.conftest import make_model_dir

    folder = make_model_dir(tmp_path / "cv", occupancy_head=True, constant_velocity_input=True)
    net, _ = resolve_model(folder)
    float_path = export_onnx(net, tmp_path / "cv.onnx")
    computed = data_dependent_convs(float_path)
    assert len(computed) == 3  # the overlap correlation and the one-hot shift's two axes
    int8_path = quantize_onnx(
        float_path, tmp_path / "cv8.onnx", stacked_maps(sample_recording, 0, 20, subcell=False)
    )
    graph = onnx.load(str(int8_path)).graph
    dequantized = {out for n in graph.node if n.op_type == "DequantizeLinear" for out in n.output}
    convs = [n for n in graph.node if n.op_type == "Conv"]
    float_convs = {n.name for n in convs if not set(n.input[:2]) & dequantized}
    head = head_convs(float_path)  # this head has no hidden layer: its output conv
    assert len(head) == 1 and float_convs == {*computed, *head} and len(convs) > 4
