"""A zipped bag is unpacked where the next run finds what a killed one left, and a zip bomb
or a full disk is refused in one line before it fills anything."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import zipfile
from pathlib import Path

import pytest

from lidarflow.data import read_bag, unzip
from lidarflow.errors import BagError
from tests.bagutil import write_bag


@pytest.fixture
def unpack_here(tmp_path, monkeypatch) -> Path:
    """The system's temporary folder, for this test alone; returns where bags unpack."""
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    return unzip.unzip_folder()


def _zipped(folder: Path, name: str, data: bytes | None = None) -> Path:
    """``folder/name.bag.zip`` holding ``name.bag``: a real bag, or ``data``."""
    path = folder / f"{name}.bag.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        if data is None:
            zf.write(write_bag(folder / f"{name}.bag", "ros1"), f"{name}.bag")
        else:
            zf.writestr(f"{name}.bag", data)
    return path


def _ended() -> int:
    """The PID of a process that has ended."""
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def test_a_zipped_bag_is_unpacked_beside_no_other_and_removed(tmp_path, unpack_here):
    assert len(read_bag(_zipped(tmp_path, "z"))) == 25
    assert unpack_here.is_dir() and list(unpack_here.iterdir()) == []
    assert unpack_here.parent == tmp_path / "tmp" and unpack_here.stat().st_mode & 0o077 == 0


def test_what_a_killed_run_left_is_removed_by_the_next(tmp_path, unpack_here):
    unpack_here.mkdir()
    left = unpack_here / f".z.bag.{_ended()}.partial.bag"  # its process is gone
    left.write_bytes(b"#ROSBAG V2.0\n" + bytes(1000))
    running = unpack_here / f".z.bag.{os.getppid()}.partial.bag"  # its process runs
    running.write_bytes(b"#ROSBAG V2.0\n")
    assert len(read_bag(_zipped(tmp_path, "z"))) == 25
    assert sorted(unpack_here.iterdir()) == [running]


def test_a_zip_bomb_is_refused_by_the_size_it_declares(tmp_path, unpack_here, monkeypatch):
    monkeypatch.setattr(unzip, "UNZIP_FLOOR", 1 << 20)
    bomb = _zipped(tmp_path, "bomb", bytes(8 << 20))  # 8 MB of zeros in ~8 kB
    with pytest.raises(BagError) as caught:
        read_bag(bomb)
    assert str(caught.value) == (
        f"{bomb}: its bag unpacks to 8.0 MB or more, over 50 times the archive's 8 kB: a zip "
        "bomb or a damaged archive; if it is a bag, unzip it yourself and give the .bag"
    )
    assert list(unpack_here.iterdir()) == []


def test_a_header_that_lies_about_the_size_is_one_line(tmp_path, unpack_here):
    liar = _zipped(tmp_path, "liar", bytes(4 << 20))
    data = bytearray(liar.read_bytes())
    declared = (4 << 20).to_bytes(4, "little")
    assert data.count(declared) == 2  # the local header's and the central directory's
    liar.write_bytes(bytes(data).replace(declared, (1000).to_bytes(4, "little")))
    with pytest.raises(BagError, match=f"^{liar}: corrupt zip archive"):
        read_bag(liar)
    assert list(unpack_here.iterdir()) == []


def test_a_bag_that_would_fill_the_disk_is_refused(tmp_path, unpack_here, monkeypatch):
    zipped = _zipped(tmp_path, "z")
    real = shutil.disk_usage

    def nearly_full(path):
        return real(path)._replace(free=unzip.UNZIP_RESERVE + 1000)

    monkeypatch.setattr(unzip.shutil, "disk_usage", nearly_full)
    with pytest.raises(BagError, match=f"^{zipped}: its bag unpacks to .* kB or more, and "):
        read_bag(zipped)
    assert list(unpack_here.iterdir()) == []
