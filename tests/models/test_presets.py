"""The bundled model: present, intact (checksum as recorded), loadable, documented."""

from __future__ import annotations

import shutil

import pytest

from lidarflow.errors import ModelError
from lidarflow.models import presets
from lidarflow.models.presets import BUNDLED, bundled_model_dir, lidar_flownet, resolve_model


def test_bundled_model_loads_and_matches_its_record():
    net, card = resolve_model(None)
    assert card["model"] == "flownet" and card["weights_sha256"] == BUNDLED.weights_sha256
    # The occupancy head alone since v9 (issue 36): no flow network, a few hundred weights
    assert net.inner.flow is None and not net.capabilities.flow
    assert sum(p.numel() for p in net.parameters()) == card["parameters"] < 1000
    assert BUNDLED.meta["version"] == "v10" and BUNDLED.meta["recipe"] == card["recipe"]
    assert card["parameters"] == BUNDLED.meta["parameters"] and card["decision"]["online"]
    # v10 is v9's head with the tracked movers laid over its map (issue 44)
    assert card["decision"]["movers"]


def test_the_package_ships_the_model_and_a_short_card_not_the_research():
    folder = bundled_model_dir()
    # what the code reads at run time, and the card; the history and tables live in docs/model
    shipped = sorted(p.name for p in folder.iterdir())
    assert shipped == ["MODEL_CARD.md", "model.json", "model.onnx", "model.safetensors"]
    card = (folder / "MODEL_CARD.md").read_text()
    assert len(card) < 8000 and BUNDLED.weights_sha256 in card and BUNDLED.onnx_sha256 in card
    # its held-out numbers say where it loses, and it points to the full history
    assert "loses" in card and "6 of 9" in card and "Known limits" in card
    history = folder.parents[3] / "docs" / "model"
    if history.is_dir():  # a source checkout, not an installed wheel
        assert "docs/model/README.md" in card and (history / "heldout.json").is_file()


def test_the_word_bundled_names_the_bundled_model(tmp_path, monkeypatch):
    _, card = resolve_model("bundled")
    assert card["weights_sha256"] == BUNDLED.weights_sha256
    # ... unless a file or folder of that name is there: then that is what the user means.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bundled").mkdir()
    with pytest.raises(ModelError):
        resolve_model("bundled")


def test_bundled_predictor_runs_on_the_sample(sample_recording):
    from lidarflow.predict import Predictor

    predictor = Predictor()
    for i in range(12):
        p = predictor.update(sample_recording.scan(i))
    assert p.probability.shape == (100, 100) and 0 < p.occupied.sum() < p.occupied.size
    assert p.backward_flow is None and p.forward_flow is None and p.moving is None


def test_damaged_bundled_weights_are_refused(tmp_path, monkeypatch):
    folder = tmp_path / "model"
    shutil.copytree(bundled_model_dir(), folder)
    data = bytearray((folder / "model.safetensors").read_bytes())
    data[-1] ^= 0xFF
    (folder / "model.safetensors").write_bytes(bytes(data))
    monkeypatch.setattr(presets, "bundled_model_dir", lambda: folder)
    with pytest.raises(ModelError, match="checksum"):
        resolve_model(None)


def test_missing_bundled_model_is_explained(tmp_path, monkeypatch):
    monkeypatch.setattr(presets, "bundled_model_dir", lambda: tmp_path)
    with pytest.raises(ModelError, match="no bundled model"):
        resolve_model(None)


def test_the_preset_builds_the_bundled_model_or_table_one():
    import torch

    from lidarflow.models import HeadConfig

    bundled = lidar_flownet(weights=BUNDLED)
    net, _ = resolve_model(None)
    for (name, a), b in zip(bundled.state_dict().items(), net.state_dict().values(), strict=True):
        assert torch.equal(a, b), name
    fresh = lidar_flownet()
    assert sum(p.numel() for p in fresh.parameters()) == 42_500
    assert lidar_flownet(head=HeadConfig()).capabilities.occupancy_head
    # The record carries its meta: the seven recordings held out, each with its margin.
    heldout = BUNDLED.meta["heldout"]
    assert len(heldout) == 7 and all(len(v) == 3 for v in heldout.values())
    assert BUNDLED.meta["training_data"] and "lidarflow train" in BUNDLED.meta["command"]
