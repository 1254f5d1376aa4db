"""SOGMP as a lidarflow model: shapes, the window as state, the KL term, samples, export
parity with onnxruntime, model.json round trip, and a tiny run of `lidarflow train --arch
sogmp` that `lidarflow evaluate -m RUN` scores."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from lidarflow.cli import main
from lidarflow.losses import sogmp_loss
from lidarflow.models import SOGMP, build_model, count_parameters
from lidarflow.models.sogmp import kl_to_standard_normal
from lidarflow.predict.step import StepInputs
from tests.conftest import make_model_dir

H = W = 16


def _seq(b: int = 2, t: int = 12, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    occ = (torch.rand(b, t, 1, H, W, generator=g) < 0.1).float()
    return torch.cat([occ, torch.ones_like(occ)], dim=2)


def _net(seed: int = 0, **kwargs) -> SOGMP:
    torch.manual_seed(seed)
    return SOGMP(**kwargs).eval()


def test_shapes_state_and_parameters():
    net = _net()
    out, state = net.step(torch.zeros(3, 2, H, W), net.init_state(3, H, W))
    assert out.shape == (3, 2, H, W) and len(state) == 1 and state[0].shape == (3, 10, H, W)
    assert net.capabilities.out_channels == 2 and not net.capabilities.flow
    assert count_parameters(net) == 730_245  # the published SOGMP's, grid-independent
    vis = _net(visibility_input=True, window=4)
    assert vis.state_channels() == (8,)
    # a grid that is not a multiple of 4 is padded inside and the prediction cropped back:
    # empty cells beyond the far (row 0) and right edges, the sensor's edge as it was
    odd = torch.zeros(1, 2, 18, 19)
    odd[0, 0, 5, 7] = 1.0
    with torch.no_grad():
        out, _ = net.step(odd, net.init_state(1, 18, 19))
        full, _ = net.step(torch.nn.functional.pad(odd, (0, 1, 2, 0)), net.init_state(1, 20, 20))
    assert out.shape == (1, 2, 18, 19)
    torch.testing.assert_close(out[:, :1], full[:, :1, 2:, :19], atol=1e-5, rtol=1e-5)


def test_window_keeps_exactly_the_last_maps():
    """The state holds the last ``window`` maps, newest last: a map older than the window no
    longer changes the output; one inside it does."""
    net = _net(window=4)
    a, b = _seq(1, 6, seed=1), _seq(1, 6, seed=1)
    b[:, 0, 0] = 1.0 - b[:, 0, 0]  # only the first map differs
    with torch.no_grad():
        out_a, state_a = net(a)
        out_b, _ = net(b)
    torch.testing.assert_close(state_a[0][:, -1], a[:, -1, 0])
    torch.testing.assert_close(state_a[0], a[:, -4:, 0])
    assert not torch.allclose(out_a[:, 3], out_b[:, 3])  # map 0 is in the window of step 3
    torch.testing.assert_close(out_a[:, 4], out_b[:, 4])  # and gone from step 4's


def test_step_equals_forward_over_a_sequence_also_ego_compensated():
    net = _net()
    seq = _seq()
    with torch.no_grad():
        outs, last = net(seq)
        state = net.init_state(2, H, W)
        for t in range(seq.shape[1]):
            out, state = net.step(seq[:, t], state)
            torch.testing.assert_close(out, outs[:, t])
    torch.testing.assert_close(state[0], last[0])
    torch.manual_seed(0)
    ego = build_model("sogmp", ego_motion=True).eval()
    motions = torch.tensor([0.5, -0.3, 0.05]).expand(2, seq.shape[1], 3).contiguous()
    with torch.no_grad():
        outs, _ = ego(seq, None, motions)
        state = ego.init_state(2, H, W)
        for t in range(seq.shape[1]):
            out, state = ego.step(seq[:, t], state, motions[:, t])
            torch.testing.assert_close(out, outs[:, t])
    # the KL channel is a statistic of the step, not moved with the frame
    with torch.no_grad():
        plain, _ = ego.inner(seq)
    torch.testing.assert_close(outs[:, 0, 1], plain[:, 0, 1])


def test_kl_is_finite_zero_when_posterior_is_prior_and_sums_over_the_map():
    mu, log_sd = torch.randn(2, 2, 4, 4), torch.randn(2, 2, 4, 4)
    kl = kl_to_standard_normal(mu, log_sd)
    assert torch.isfinite(kl).all() and (kl >= 0).all() and kl.sum() > 0
    # the closed form against torch's
    ref = torch.distributions.kl_divergence(
        torch.distributions.Normal(mu, log_sd.exp()), torch.distributions.Normal(0.0, 1.0)
    )
    torch.testing.assert_close(kl, ref)
    net = _net()
    seq = _seq(1, 3)
    with torch.no_grad():
        out, state = net(seq)
        m, s = net.encode(state[0])
    # the KL channel spreads the step's KL over the map: its sum is the latent's KL
    torch.testing.assert_close(out[0, -1, 1].sum(), kl_to_standard_normal(m, s).sum())
    for head in (net.encoder.mu, net.encoder.log_sd):  # q(z | past) = N(0, I), the prior
        torch.nn.init.zeros_(head.weight)
        torch.nn.init.zeros_(head.bias)
    with torch.no_grad():
        out, _ = net(seq)
    assert out[:, :, 1].abs().max() == 0.0
    assert sogmp_loss(seq, out, warmup=0) == sogmp_loss(seq, out, warmup=0, kl_weight=0.0)


def test_loss_is_bce_summed_per_map_plus_weighted_kl():
    seq = _seq(2, 5)
    out = torch.randn(2, 5, 2, H, W)
    target, logit = seq[:, 2:, 0], out[:, 1:4, 0]
    bce = torch.nn.functional.binary_cross_entropy_with_logits(logit, target, reduction="none")
    kl = out[:, 1:4, 1].sum(dim=(2, 3))
    expected = (bce.sum(dim=(2, 3)) + 0.5 * kl).mean()
    torch.testing.assert_close(sogmp_loss(seq, out, warmup=1, kl_weight=0.5), expected)
    with pytest.raises(ValueError, match="model output"):
        sogmp_loss(seq, out[:, :, :1], warmup=1)


def test_mean_path_is_deterministic_and_samples_spread_around_it():
    net = _net()
    seq = _seq(1, 10)
    with torch.no_grad():
        out, state = net(seq)
        again, _ = net(seq)
    torch.testing.assert_close(out, again)  # eval: z = mu
    samples = net.sample(state, 5, generator=torch.Generator().manual_seed(0))
    assert samples.shape == (5, 1, 1, H, W)
    assert ((samples >= 0) & (samples <= 1)).all()
    assert not torch.allclose(samples[0], samples[1])  # draws of q differ
    moved = net.sample(state, 2, torch.tensor([[2.0, 0.0, 0.0]]), torch.Generator().manual_seed(0))
    assert moved.shape == (2, 1, 1, H, W) and not torch.allclose(moved, samples[:2])
    torch.nn.init.constant_(net.encoder.log_sd.bias, -30.0)  # sd ~ 0: every draw is the mean
    torch.nn.init.zeros_(net.encoder.log_sd.weight)
    with torch.no_grad():
        mean = net.predict_next(seq[:, -1], net(seq)[0][:, -1])
    torch.testing.assert_close(net.sample(state, 3)[1], mean)
    net.train()
    with torch.no_grad():
        torch.nn.init.constant_(net.encoder.log_sd.bias, 0.0)
        first, _ = net(seq)
        second, _ = net(seq)
    assert not torch.allclose(first[:, -1, 0], second[:, -1, 0])  # training draws z


def test_model_json_round_trip(tmp_path):
    from lidarflow.models.weights import load_trained

    folder = make_model_dir(tmp_path / "s", name="sogmp", window=6, ego_motion=True)
    card = json.loads((folder / "model.json").read_text())
    assert card["model"] == "sogmp" and card["model_kwargs"]["window"] == 6
    model, _ = load_trained(folder)
    torch.manual_seed(0)
    fresh = build_model("sogmp", window=6, ego_motion=True)
    assert model.capabilities.ego_motion and model.inner.window == 6
    loaded = model.state_dict()
    assert set(loaded) == set(fresh.state_dict())
    assert all(torch.equal(v, fresh.state_dict()[k]) for k, v in loaded.items())


def test_export_matches_pytorch_in_onnxruntime(tmp_path):
    pytest.importorskip("onnxruntime")
    from lidarflow.outputs.export import export_onnx
    from lidarflow.predict.backends import OnnxBackend, TorchBackend

    torch.manual_seed(0)
    model = build_model("sogmp", ego_motion=True, window=4).eval()
    path = export_onnx(model, tmp_path / "s.onnx", height=H, width=W, res=0.1)
    onnx, torch_ = OnnxBackend(path, threads=1), TorchBackend(model, threads=1)
    assert onnx.capabilities == torch_.capabilities
    s_onnx, s_torch = onnx.init_state(H, W), torch_.init_state(H, W)
    seq = _seq(1, 6, seed=3).numpy()
    for t in range(6):
        motion = np.array([0.4, 0.2 * t, 0.03], np.float32)
        p1, o1, s_onnx = onnx.run(StepInputs(seq[:, t], motion), s_onnx)
        p2, o2, s_torch = torch_.run(StepInputs(seq[:, t], motion), s_torch)
        np.testing.assert_allclose(p1, p2, atol=2e-5)
        np.testing.assert_allclose(o1, o2, atol=2e-4)
    assert float(np.abs(p1 - p1.mean()).max()) > 0  # not a constant map


def _cli(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    out = capsys.readouterr()
    assert exc.value.code in (0, None), out.err
    return out.out


@pytest.mark.slow
def test_train_arch_sogmp_writes_a_run_evaluate_scores(tmp_path, capsys):
    sim = tmp_path / "sim.npz"
    _cli(["simulate", "-o", str(sim), "-n", "24", "--grid", "16", "--seed", "2"], capsys)
    run = tmp_path / "run"
    tiny = ["--grid", "16", "--seq-len", "11", "--warmup", "9", "--batch-size", "2"]
    sets = ["--set", "runtime.tensorboard=false", "--set", "data.stride=5"]
    args = ["train", str(sim), "--arch", "sogmp", "-o", str(run), "--epochs", "1"]
    _cli([*args, *tiny, *sets, "--threads", "1"], capsys)
    config = json.loads((run / "config.json").read_text())
    assert config["recipe"] == "sogmp" and config["model"]["name"] == "sogmp"
    assert config["loss"]["kl_weight"] == 0.01 and config["optim"]["lr"] == 1e-4
    assert config["model"]["ego_motion"] is True
    assert json.loads((run / "model.json").read_text())["model"] == "sogmp"
    report = tmp_path / "eval.json"
    evaluate = ["evaluate", str(sim), "-m", str(run), "--grid", "16", "--horizon", "2"]
    _cli([*evaluate, "--threads", "1", "-o", str(report)], capsys)
    scores = json.loads(report.read_text())["recordings"][0]["methods"][run.name]
    assert scores["frames"] > 0 and math.isfinite(scores["ap"]) and 0 <= scores["f1"] <= 1
