"""What :class:`~lidarflow.live.foxglove.LiveServer`'s front (``lidarflow.live.front``) does
beyond foxglove-sdk: clients asking for the protocol's first name connect, the last scan
reaches a client when the server stops and its process ends, and the close carries a code."""

from __future__ import annotations

import json
import socket
import struct
import subprocess
from collections import Counter

import pytest
from websockets.client import ClientProtocol
from websockets.exceptions import InvalidStatus
from websockets.frames import Opcode
from websockets.sync.client import connect
from websockets.typing import Subprotocol
from websockets.uri import parse_uri

from lidarflow.live.foxglove import LiveServer
from lidarflow.live.front import LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL, ask_sdk_subprotocol
from lidarflow.scan import GridSpec
from tests.live.serve_recording import SCANS, serve_once


def slow_client(url: str, server: subprocess.Popen) -> tuple[Counter, int | None]:
    """Subscribe to every topic, then read nothing until the server has published it all (so
    most of it is still queued on the server's side), then read to the end. Returns the
    messages per topic and the close code received."""
    host, port = url.removeprefix("ws://").rsplit(":", 1)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect: a small window
    sock.settimeout(30)
    sock.connect((host, int(port)))
    ws = ClientProtocol(parse_uri(url), subprotocols=[Subprotocol(SDK_SUBPROTOCOL)])
    ws.send_request(ws.connect())

    def frames():
        sock.sendall(b"".join(ws.data_to_send()))
        data = sock.recv(1 << 16)
        ws.receive_data(data) if data else ws.receive_eof()
        return ws.events_received(), not data

    channels: dict[int, str] = {}
    while len(channels) < 8:  # the scan, six grids, the flow image
        events, ended = frames()
        assert not ended, "closed before advertising"
        for event in events:
            if getattr(event, "opcode", None) == Opcode.TEXT:
                message = json.loads(event.data)
                if message["op"] == "advertise":
                    channels.update({c["id"]: c["topic"] for c in message["channels"]})
    subscribe = [{"id": cid, "channelId": cid} for cid in channels]
    ws.send_text(json.dumps({"op": "subscribe", "subscriptions": subscribe}).encode())
    sock.sendall(b"".join(ws.data_to_send()))
    assert server.stdout.readline().strip() == f"published {SCANS}"
    counts: Counter = Counter()
    ended = False
    while not ended:
        events, ended = frames()
        for event in events:
            if getattr(event, "opcode", None) == Opcode.BINARY and event.data[0] == 1:
                (sid,) = struct.unpack_from("<I", event.data, 1)
                counts[channels[sid]] += 1
    sock.close()
    return counts, None if ws.close_rcvd is None else ws.close_rcvd.code


@pytest.fixture(scope="module")
def stopped(short_flow):
    proc, url = serve_once(*short_flow)
    try:
        counts, code = slow_client(url, proc)
    except BaseException:
        proc.kill()
        raise
    finally:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    return counts, code


def test_the_last_scan_reaches_a_client_when_the_server_stops_and_exits(stopped):
    """A guard, not a reproduction: the loss before the front was a race (1 run in 2 to 6 of
    ``lidarflow live``) that this slow reader does not provoke."""
    counts, _ = stopped
    assert len(counts) == 8 and set(counts.values()) == {SCANS}, counts


def test_a_server_that_stops_says_going_away(stopped):
    _, code = stopped
    assert code == 1001  # not 1005, "no status"


@pytest.mark.parametrize("offered", [[LEGACY_SUBPROTOCOL], [SDK_SUBPROTOCOL],
                                     [LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL]])  # fmt: skip
def test_either_name_of_the_protocol_connects_and_is_answered_as_offered(offered):
    with (
        LiveServer(GridSpec(10, 10, 0.1), port=0) as server,
        connect(server.url, subprotocols=offered, open_timeout=10) as ws,
    ):
        # the name the SDK knows where offered, else the one the client knows
        assert ws.subprotocol == (SDK_SUBPROTOCOL if SDK_SUBPROTOCOL in offered
                                  else LEGACY_SUBPROTOCOL)  # fmt: skip
        info = json.loads(ws.recv(timeout=10))
        assert info["op"] == "serverInfo" and info["name"] == "lidarflow"


def test_a_client_of_another_protocol_is_still_refused():
    server = LiveServer(GridSpec(10, 10, 0.1), port=0)
    with server, pytest.raises(InvalidStatus, match="400"):
        connect(server.url, subprotocols=["graphql-ws"], open_timeout=10)


def test_only_a_request_offering_the_old_name_alone_is_rewritten():
    request = (b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: "
               b"foxglove.websocket.v1\r\n\r\n")  # fmt: skip
    rewritten, legacy = ask_sdk_subprotocol(request)
    assert legacy and b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n" in rewritten
    both = request.replace(b"foxglove.websocket.v1", b"foxglove.websocket.v1, foxglove.sdk.v1")
    assert ask_sdk_subprotocol(both) == (both, False)
    other = b"GET / HTTP/1.1\r\nHost: x\r\n\r\n"
    assert ask_sdk_subprotocol(other) == (other, False)


def test_closing_with_a_client_that_never_sent_its_request_logs_nothing(caplog):
    # a connection still waiting for its upgrade request is cancelled at close: that ends it
    # quietly, not with asyncio's "Exception in callback" traceback
    import logging
    import time

    from lidarflow.live.front import Front

    front = Front("127.0.0.1", 0)
    front.start(backend_port=1)  # never reached: the request never comes
    with socket.create_connection(("127.0.0.1", front.port)):
        time.sleep(0.2)  # accepted, waiting for its request
        with caplog.at_level(logging.DEBUG, logger="asyncio"):
            front.close(0.1)
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []


def _message_frame(log_time: int) -> bytes:
    """A server's binary "message data" frame (subscription 1) logged at ``log_time``."""
    payload = bytes([1]) + struct.pack("<IQ", 1, log_time) + b"msg"
    return bytes([0x82, len(payload)]) + payload


def test_closing_waits_for_the_last_scan_even_when_the_sdk_pauses_longer_than_the_quiet():
    # A fake SDK writes one scan's two messages, pauses 0.4 s (a loaded machine's scheduler),
    # then writes the last scan's two: silence alone (0.05 s) would have stopped it before.
    import threading
    import time

    from lidarflow.live.front import Front

    backend = socket.create_server(("127.0.0.1", 0))
    done = threading.Event()

    def sdk():
        conn, _ = backend.accept()
        with conn:
            while b"\r\n\r\n" not in conn.recv(4096):
                pass
            conn.sendall(b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n\r\n")
            conn.sendall(_message_frame(5) * 2)
            time.sleep(0.4)
            conn.sendall(_message_frame(7) * 2)
            done.wait(10)

    threading.Thread(target=sdk, daemon=True).start()
    front = Front("127.0.0.1", 0)
    front.start(backend.getsockname()[1])
    received = bytearray()
    with socket.create_connection(("127.0.0.1", front.port), timeout=10) as client:
        client.sendall(b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n\r\n")
        while received.count(_message_frame(5)) < 2:
            received += client.recv(4096)
        start = time.monotonic()
        front.wait_relayed(7, 2, quiet_s=0.05, within_s=5.0)
        waited = time.monotonic() - start
        while received.count(_message_frame(7)) < 2:  # relayed, so they arrive
            received += client.recv(4096)
        done.set()
        front.close(0.5)
    backend.close()
    assert 0.25 < waited < 3.0  # the pause, not the whole budget
