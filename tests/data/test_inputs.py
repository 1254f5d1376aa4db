"""Inputs that are no regular file (a named pipe, a device, a socket) are refused before they
are opened: one line naming them, never a read that blocks or never ends."""

from __future__ import annotations

import os
import socket
import threading
from pathlib import Path

import numpy as np
import pytest

from lidarflow.data import list_topics, load_any, load_recording
from lidarflow.errors import BagError, LidarflowError, RecordingError
from tests.bagutil import write_bag
from tests.test_cli import run


def _within(seconds: float, call, *args) -> BaseException:
    """The error ``call(*args)`` raises, which it must within ``seconds`` (a read of a named
    pipe would block for ever: the thread is left behind, the test fails)."""
    raised: list[BaseException] = []

    def target() -> None:
        try:
            call(*args)
        except BaseException as err:
            raised.append(err)

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"{call.__name__}{args} still reading after {seconds} s"
    assert raised, f"{call.__name__}{args} raised nothing"
    return raised[0]


@pytest.mark.parametrize("name", ["p.bag", "p.bag.zip", "p.mcap", "p.npz", "p"])
def test_a_named_pipe_is_refused_by_name_without_opening_it(tmp_path, name):
    pipe = tmp_path / name
    os.mkfifo(pipe)
    err = _within(10, load_any, pipe)
    assert isinstance(err, RecordingError if name.endswith(".npz") else BagError)
    assert str(err).startswith(f"{pipe}: a named pipe, not a file")


@pytest.mark.parametrize("name", ["z.bag", "z.bag.zip", "z.mcap", "z.npz"])
def test_a_link_to_dev_zero_is_refused_naming_both(tmp_path, name):
    link = tmp_path / name
    link.symlink_to("/dev/zero")
    err = _within(10, load_any, link)
    assert isinstance(err, LidarflowError)
    assert str(err).startswith(f"{link} (-> /dev/zero): a character device, not a file")


def test_a_socket_is_refused(tmp_path):
    path = tmp_path / "s.bag"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(path))
        err = _within(10, list_topics, path)
    assert isinstance(err, BagError) and str(err).startswith(f"{path}: a socket, not a file")


def test_a_bag_folder_stays_readable_but_a_pipe_in_it_is_refused(tmp_path):
    folder = tmp_path / "b"
    write_bag(folder, "mcap", {"/scan": [np.linspace(1.0, 5.0, 40)] * 4}, rate_hz=10.0)
    assert len(load_any(folder)) == 4
    os.mkfifo(folder / "extra.mcap")
    for given in (folder, folder / "metadata.yaml"):
        err = _within(10, load_any, given)
        assert isinstance(err, BagError)
        assert str(err).startswith(f"{folder / 'extra.mcap'}: a named pipe, not a file")


def test_the_cli_says_one_line(tmp_path, capsys):
    pipe = tmp_path / "p.npz"
    os.mkfifo(pipe)
    _within(10, load_recording, pipe)  # it does not block, so the command cannot either
    code, _, err = run(["info", str(pipe)], capsys)
    assert code == 1
    assert err.strip().splitlines() == [
        f"lidarflow: error: {pipe}: a named pipe, not a file; lidarflow reads recordings and "
        "bags from regular files (copy the data to one)"
    ]
    assert Path(pipe).exists()
