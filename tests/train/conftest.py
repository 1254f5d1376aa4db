"""Fixtures for the training tests."""

from __future__ import annotations

import pytest

from tests.train.blobs import blob_recording


@pytest.fixture
def blob_files(tmp_path):
    """Two blob recordings saved as .npz, different speeds."""
    a = blob_recording(n=60, seed=1).save(tmp_path / "blob_a.npz")
    b = blob_recording(n=60, seed=2, speed_cells=1.5).save(tmp_path / "blob_b.npz")
    return [a, b]
