"""Speed options must not change what the model computes."""

from __future__ import annotations

import pytest
import torch

from lidarflow.losses import LossConfig, flow_loss
from lidarflow.models import build_model
from lidarflow.models.speed import accelerate, native_bf16


def _seq(b=2, t=3, h=11, w=9) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    occ = (torch.rand(b, t, 1, h, w, generator=g) > 0.8).float()
    return torch.cat([occ, torch.ones_like(occ)], dim=2)


@pytest.mark.parametrize("name", ["flownet", "deeptracking"])
def test_channels_last_gives_the_same_outputs_and_gradients(name):
    torch.manual_seed(0)
    plain = build_model(name)
    with torch.no_grad():
        for p in plain.parameters():
            p.add_(0.1 * torch.randn_like(p))
    fast = build_model(name)
    fast.load_state_dict(plain.state_dict())
    accelerate(fast, channels_last=True)
    state = fast.init_state(2, 11, 9)
    assert all(s.is_contiguous(memory_format=torch.channels_last) for s in state)
    assert all(s.is_contiguous() for s in plain.init_state(2, 11, 9))
    seq = _seq()
    out_plain, _ = plain(seq)
    out_fast, _ = fast(seq)
    torch.testing.assert_close(out_fast, out_plain, atol=1e-5, rtol=1e-4)
    out_plain.square().sum().backward()
    out_fast.square().sum().backward()
    for (n, a), b in zip(plain.named_parameters(), fast.parameters(), strict=True):
        torch.testing.assert_close(b.grad, a.grad, atol=1e-4, rtol=1e-3, msg=n)


def test_bf16_autocast_keeps_the_loss_in_fp32_and_close():
    torch.manual_seed(0)
    net = build_model("flownet")
    with torch.no_grad():
        net.flow.conv_flow.weight.normal_(0, 0.1)
    seq = _seq(t=4)
    flows, _ = net(seq)
    ref = flow_loss(seq, flows, 3, LossConfig(), warmup=1)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        flows_bf, _ = net(seq)
        loss = flow_loss(seq, flows_bf, 3, LossConfig(), warmup=1)
    assert flows_bf.dtype == torch.bfloat16
    assert loss.dtype == torch.float32
    torch.testing.assert_close(loss, ref, atol=2e-3, rtol=5e-2)


def test_unknown_compile_mode_is_rejected():
    with pytest.raises(ValueError, match="compile"):
        accelerate(build_model("flownet"), compile="fast")  # type: ignore[arg-type]


def test_native_bf16_is_a_plain_answer_on_every_device():
    assert isinstance(native_bf16(torch.device("cpu")), bool)
    assert native_bf16(torch.device("meta")) is False
