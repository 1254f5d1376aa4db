"""A small TCP front on the port a :class:`~lidarflow.live.foxglove.LiveServer` serves, relaying
to foxglove-sdk's WebSocket server on localhost, for three things the SDK (0.30) does not do:

- accept the protocol's first name, ``foxglove.websocket.v1``: the SDK takes only
  ``foxglove.sdk.v1`` (HTTP 400 otherwise), so the front asks for that and answers the client
  with the name it offered;
- lose nothing queued at close: the SDK's ``stop()`` returns while its last messages are on
  their way; :meth:`Front.close` waits until each client got them (``drain_s`` at most);
- close with 1001, "going away", where the SDK sends no code (clients would see 1005).

Everything else passes through: the front reads only the upgrade request and answer and the
headers of the server's frames (unmasked, RFC 6455 §5.2). Which clients need it:
docs/guide/live.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import threading
import time

__all__ = ["LEGACY_SUBPROTOCOL", "SDK_SUBPROTOCOL", "Front"]

SDK_SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
#: How long a client may take to send its upgrade request (a port scanner sends nothing).
REQUEST_TIMEOUT_S = 10.0
#: How long a closing connection waits for the client to close its side (its close frame's
#: answer) before the front closes the socket anyway.
LINGER_S = 1.0
CLOSE_OPCODE = 0x8
BINARY_OPCODE = 0x2
#: The first byte of the protocol's binary "message data" (then subscription id u32, log time
#: u64, little-endian, and the message).
MESSAGE_DATA = 0x01
#: The close frame's payload where the SDK sends none: 1001 "going away", and why.
GOING_AWAY = struct.pack("!H", 1001) + b"server stopped"
_PROTOCOL_HEADER = b"sec-websocket-protocol:"


def ask_sdk_subprotocol(request: bytes) -> tuple[bytes, bool]:
    """The upgrade request as the SDK accepts it, and whether the client offered only the old
    name (so its answer must name that). Any other request goes on as it came."""
    lines = request.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(_PROTOCOL_HEADER):
            offered = [p.strip() for p in line[len(_PROTOCOL_HEADER) :].split(b",")]
            sdk, legacy = SDK_SUBPROTOCOL.encode(), LEGACY_SUBPROTOCOL.encode()
            if legacy in offered and sdk not in offered:
                lines[i] = b"Sec-WebSocket-Protocol: " + sdk
                return b"\r\n".join(lines), True
    return request, False


def answer_legacy(response: bytes) -> bytes:
    """The SDK's upgrade answer with the subprotocol it chose named as the client knows it."""
    lines = response.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(_PROTOCOL_HEADER):
            lines[i] = b"Sec-WebSocket-Protocol: " + LEGACY_SUBPROTOCOL.encode()
    return b"\r\n".join(lines)


def listen(host: str, port: int) -> socket.socket:
    """A listening socket on ``host:port`` (0: a free port); ``OSError`` where it is taken."""
    family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # not over a live listener
        sock.bind(address)
        sock.listen()
    except OSError:
        sock.close()
        raise
    sock.setblocking(False)
    return sock


async def _pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
    while chunk := await src.read(1 << 16):
        dst.write(chunk)
        await dst.drain()


class Front:
    """Listens on ``host:port`` (``OSError`` where it cannot bind) and, once :meth:`start` named
    the SDK server's port, relays every connection to it on an event loop in a daemon thread."""

    def __init__(self, host: str, port: int) -> None:
        self._sock = listen(host, port)
        self.port: int = self._sock.getsockname()[1]
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(
            target=self._loop.run_forever, name="lidarflow-front", daemon=True
        )
        self._connections: set[asyncio.Task[None]] = set()
        self._server: asyncio.base_events.Server | None = None
        self._backend = 0
        self._last_from_sdk = time.monotonic()
        # the newest log time among the messages relayed, and how many were relayed with it
        self._newest: tuple[int, int] = (-1, 0)

    def start(self, backend_port: int) -> None:
        """Relay to the SDK server on ``127.0.0.1:backend_port`` from now on."""
        self._backend = backend_port
        self._thread.start()
        start = asyncio.start_server(self._relay, sock=self._sock)
        self._server = asyncio.run_coroutine_threadsafe(start, self._loop).result()

    def wait_quiet(self, quiet_s: float, within_s: float) -> None:
        """Wait until nothing came from the SDK for ``quiet_s`` (``within_s`` at most): the SDK
        drops, when stopped, what it has not yet written, the last scan's latest messages."""
        deadline = time.monotonic() + within_s
        while (now := time.monotonic()) < deadline and now - self._last_from_sdk < quiet_s:
            time.sleep(min(quiet_s, deadline - now) / 4)

    def wait_relayed(self, log_time: int, messages: int, quiet_s: float, within_s: float) -> None:
        """Wait (``within_s`` at most in all) until ``messages`` messages logged at
        ``log_time`` (or any logged later) were relayed, then :meth:`wait_quiet`: the SDK's
        writer may pause longer than ``quiet_s`` on a loaded machine before it writes the last
        scan, which silence alone would take for the end."""
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            newest, count = self._newest
            if newest > log_time or (newest == log_time and count >= messages):
                break
            time.sleep(min(quiet_s / 4, max(deadline - time.monotonic(), 0.0)))
        self.wait_quiet(quiet_s, max(deadline - time.monotonic(), 0.0))

    def close(self, drain_s: float) -> None:
        """Take no more connections; wait (``drain_s`` at most) for those open to end, which
        they do once the SDK, stopped before, has sent all it had and closed them."""
        if self._thread.is_alive():
            asyncio.run_coroutine_threadsafe(self._drain(drain_s), self._loop).result()
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join()
        else:
            self._sock.close()
        self._loop.close()

    async def _drain(self, drain_s: float) -> None:
        assert self._server is not None
        self._server.close()
        if self._connections:
            _, late = await asyncio.wait(set(self._connections), timeout=drain_s)
            for task in late:
                task.cancel()
            await asyncio.gather(*late, return_exceptions=True)

    async def _server_frames(self, src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
        """The server's frames to the client, one by one, until the server closes the
        connection; a close frame without a code gets :data:`GOING_AWAY`."""
        with contextlib.suppress(asyncio.IncompleteReadError):  # the server's end of the stream
            while True:
                head = await src.readexactly(2)
                self._last_from_sdk = time.monotonic()
                size = head[1] & 0x7F
                extended = await src.readexactly({126: 2, 127: 8}.get(size, 0))
                size = int.from_bytes(extended, "big") if extended else size
                mask = await src.readexactly(4 if head[1] & 0x80 else 0)
                payload = await src.readexactly(size)
                if head[0] & 0x0F == BINARY_OPCODE and size >= 13 and payload[0] == MESSAGE_DATA:
                    self._relayed(int.from_bytes(payload[5:13], "little"))
                if head[0] & 0x0F == CLOSE_OPCODE and size == 0:
                    head, payload = bytes([head[0], len(GOING_AWAY)]), GOING_AWAY
                dst.write(head + extended + mask + payload)
                await dst.drain()

    def _relayed(self, log_time: int) -> None:
        newest, count = self._newest
        if log_time > newest:
            self._newest = (log_time, 1)
        elif log_time == newest:
            self._newest = (newest, count + 1)

    async def _relay(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._connections.add(task)
        upstream: asyncio.StreamWriter | None = None
        to_server: asyncio.Task[None] | None = None
        try:
            request = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), REQUEST_TIMEOUT_S)
            request, legacy = ask_sdk_subprotocol(request)
            from_sdk, upstream = await asyncio.open_connection("127.0.0.1", self._backend)
            upstream.write(request)
            response = await from_sdk.readuntil(b"\r\n\r\n")
            writer.write(answer_legacy(response) if legacy else response)
            to_server = asyncio.create_task(_pipe(reader, upstream))
            if response.startswith(b"HTTP/1.1 101"):
                await self._server_frames(from_sdk, writer)
            else:  # refused (no subprotocol of the SDK's): its explanation, as it comes
                await _pipe(from_sdk, writer)
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, TimeoutError):
            pass  # a client gone or a request that is none: that connection ends, no other
        except asyncio.CancelledError:  # the front closing (_drain): the connection ends
            task.uncancel()  # as any other, not as a cancelled task, which asyncio's stream
            # server reports with a traceback
        finally:
            if to_server is not None:
                to_server.cancel()
                await asyncio.gather(to_server, return_exceptions=True)
            if upstream is not None:
                upstream.close()
                with contextlib.suppress(OSError):
                    await upstream.wait_closed()
            await _lingering_close(reader, writer)
            self._connections.discard(task)


async def _lingering_close(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """Close toward the client without a reset: half-close (everything written goes first),
    read and drop what the client still sends until it closes, :data:`LINGER_S` at most, then
    close. A socket closed with unread data in it sends a reset, and the client's system then
    drops what its application had not yet read: the last scan, for a slow reader."""
    try:
        with contextlib.suppress(OSError, RuntimeError):
            if writer.can_write_eof():
                writer.write_eof()
        with contextlib.suppress(OSError, TimeoutError, asyncio.IncompleteReadError):
            async with asyncio.timeout(LINGER_S):
                while await reader.read(1 << 16):
                    pass
    finally:
        writer.close()
        with contextlib.suppress(OSError):
            await writer.wait_closed()
