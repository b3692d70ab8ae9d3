"""A TCP proxy in front of the real server that behaves like orchard Wi-Fi: it cuts connections in the
middle of a request body, loses responses after the server has acted, refuses every connection for a
while, and can be slow. It counts the requests that reached the server whole.

It understands just enough HTTP/1.1 (request heads and Content-Length bodies) to choose where to cut and to
count; everything is forwarded byte for byte.
"""

from __future__ import annotations

import random
import socket
import struct
import threading
import time
from collections import Counter
from dataclasses import dataclass, field

from tests.service.running import free_port

_CHUNK = 16 * 1024


@dataclass
class Faults:
    """How unreliable the link is: per request, the chance to cut its body, or to lose its response."""

    cut_body: float = 0.0
    lose_response: float = 0.0
    refuse_after_requests: int | None = None
    """After this many requests, refuse every connection for ``refuse_s`` seconds (once)."""
    refuse_s: float = 0.0
    bytes_per_s: float | None = None
    seed: int = 0


@dataclass
class FlakyProxy:
    """Listens on ``url``, forwards to ``upstream_port`` on loopback, with the faults given."""

    upstream_port: int
    faults: Faults = field(default_factory=Faults)

    def __post_init__(self) -> None:
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.reached_server: Counter[tuple[str, str]] = Counter()
        self.reached_at: list[float] = []
        """``time.monotonic()`` of each request that reached the server whole."""
        self.refusals: list[tuple[float, float]] = []
        """Start and end (monotonic) of each time every connection was refused."""
        self.cut = 0
        self.lost = 0
        self.refused = 0
        self._random = random.Random(self.faults.seed)
        self._lock = threading.Lock()
        self._refuse_until = 0.0
        self._refusals_left = 0
        self._refused_once = False
        self._open: set[socket.socket] = set()
        self._listener = socket.create_server(("127.0.0.1", self.port))
        self._stopping = False
        threading.Thread(target=self._accept, daemon=True).start()

    def close(self) -> None:
        self._stopping = True
        self._listener.close()

    def refuse_next(self, connections: int) -> None:
        """Take the link down until ``connections`` more connections have been refused, however long the
        client takes to try them (a laptop out of range until it has tried a few times)."""
        with self._lock:
            self._refusals_left = connections

    def _go_down(self, seconds: float) -> None:
        self._refuse_until = time.monotonic() + seconds
        self.refusals.append((time.monotonic(), self._refuse_until))
        for connection in self._open:
            _reset(connection)

    def puts(self) -> Counter[str]:
        """How many PUT requests of each address (``/v1/captures/3/files/views/1/depth.png``) reached the
        server whole."""
        with self._lock:
            return Counter({path: n for (method, path), n in self.reached_server.items() if method == "PUT"})

    def _accept(self) -> None:
        while not self._stopping:
            try:
                client, _ = self._listener.accept()
            except OSError:
                return
            with self._lock:
                refuse = time.monotonic() < self._refuse_until or self._refusals_left > 0
                if refuse:
                    self.refused += 1
                    self._refusals_left = max(self._refusals_left - 1, 0)
            if refuse:
                _reset(client)
                continue
            threading.Thread(target=self._serve, args=(client,), daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        try:
            upstream = socket.create_connection(("127.0.0.1", self.upstream_port))
        except OSError:
            _reset(client)
            return
        lose = threading.Event()
        with self._lock:
            self._open.add(client)
        threading.Thread(target=self._responses, args=(upstream, client, lose), daemon=True).start()
        try:
            self._requests(client, upstream, lose)
        except OSError:
            pass
        finally:
            with self._lock:
                self._open.discard(client)
            client.close()

    def _fate(self) -> str:
        with self._lock:
            draw = self._random.random()
        if draw < self.faults.cut_body:
            return "cut"
        if draw < self.faults.cut_body + self.faults.lose_response:
            return "lose"
        return "pass"

    def _send(self, upstream: socket.socket, data: bytes) -> None:
        if self.faults.bytes_per_s:
            for start in range(0, len(data), _CHUNK):
                upstream.sendall(data[start : start + _CHUNK])
                time.sleep(min(len(data) - start, _CHUNK) / self.faults.bytes_per_s)
        else:
            upstream.sendall(data)

    def _requests(self, client: socket.socket, upstream: socket.socket, lose: threading.Event) -> None:
        buffer = b""
        while True:
            while b"\r\n\r\n" not in buffer:
                data = client.recv(_CHUNK)
                if not data:
                    upstream.close()
                    return
                buffer += data
            head, buffer = buffer.split(b"\r\n\r\n", 1)
            lines = head.decode("latin-1").split("\r\n")
            method, path = lines[0].split(" ")[:2]
            length = next(
                (
                    int(line.split(":", 1)[1])
                    for line in lines[1:]
                    if line.lower().startswith("content-length:")
                ),
                0,
            )
            fate = self._fate()
            if fate == "lose":
                lose.set()  # before any byte: the server's answer must not reach the client
            cut_at = self._random.randint(0, max(length - 1, 0)) if fate == "cut" else None
            self._send(upstream, head + b"\r\n\r\n")
            sent = 0
            while sent < length:
                if not buffer:
                    buffer = client.recv(_CHUNK)
                    if not buffer:
                        upstream.close()
                        return
                piece, buffer = buffer[: length - sent], buffer[length - sent :]
                if cut_at is not None and sent + len(piece) > cut_at:
                    self._send(upstream, piece[: cut_at - sent])
                    with self._lock:
                        self.cut += 1
                    _reset(client)
                    upstream.close()
                    return
                self._send(upstream, piece)
                sent += len(piece)
            with self._lock:
                self.reached_server[(method, path)] += 1
                self.reached_at.append(time.monotonic())
                total = sum(self.reached_server.values())
                refuse = self.faults.refuse_after_requests
                if refuse is not None and total >= refuse and not self._refused_once:
                    self._refused_once = True
                    self._go_down(self.faults.refuse_s)
            if fate == "lose":
                with self._lock:
                    self.lost += 1
                return

    def _responses(self, upstream: socket.socket, client: socket.socket, lose: threading.Event) -> None:
        try:
            while True:
                data = upstream.recv(_CHUNK)
                if not data:
                    break
                if lose.is_set():
                    # The server answered; the answer is lost on the way back, with the connection.
                    _reset(client)
                    break
                client.sendall(data)
        except OSError:
            pass
        finally:
            upstream.close()
            client.close()


def _reset(connection: socket.socket) -> None:
    """Close with a TCP reset, as a link that went away does."""
    try:
        connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        connection.close()
    except OSError:
        pass
