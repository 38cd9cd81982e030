"""A minimal client of the Foxglove WebSocket protocol (standard library only), as the Foxglove
app talks to ``rs-localizer view``: it reads the server's channel advertisements, subscribes
channels and receives their messages.

Protocol (https://github.com/foxglove/ws-protocol): JSON text frames (``serverInfo``,
``advertise`` with ``channels``: id, topic, encoding, schemaName, schema, schemaEncoding);
the client sends ``{"op": "subscribe", "subscriptions": [{"id", "channelId"}]}``; a message
arrives as a binary frame ``0x01, subscription id (u32 LE), log time (u64 LE, ns), payload``.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import socket
import struct
import time


class FoxgloveClient:
    """Connect to ``ws://host:port`` offering the WebSocket subprotocols ``protocols`` (the
    one the server agreed to: :attr:`protocol`); raises OSError when nothing listens."""

    def __init__(
        self,
        port: int,
        host: str = "127.0.0.1",
        timeout: float = 5.0,
        protocols: tuple[str, ...] = ("foxglove.sdk.v1", "foxglove.websocket.v1"),
    ):
        self.sock = socket.create_connection((host, port), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                "Sec-WebSocket-Version: 13\r\n"
                f"Sec-WebSocket-Protocol: {', '.join(protocols)}\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise OSError("connection closed during the handshake")
            head += chunk
        head, _, self._buf = head.partition(b"\r\n\r\n")
        status = head.split(b"\r\n", 1)[0]
        if b" 101 " not in status:
            raise OSError(f"handshake refused: {head.decode(errors='replace')}")
        self.protocol = next(
            (
                line.split(b":", 1)[1].strip().decode()
                for line in head.split(b"\r\n")
                if line.lower().startswith(b"sec-websocket-protocol:")
            ),
            None,
        )
        self.channels: dict[str, dict] = {}  # topic -> the advertised channel
        self.server_info: dict | None = None
        self._subs: dict[int, str] = {}  # subscription id -> topic
        self.messages: list[tuple[str, int, bytes]] = []  # (topic, log time ns, payload)

    # -------------------------------------------------------------- frames
    def _read(self, n: int) -> bytes:
        while len(self._buf) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise OSError("connection closed")
            self._buf += chunk
        out, self._buf = self._buf[:n], self._buf[n:]
        return out

    def _send(self, opcode: int, payload: bytes) -> None:
        mask = os.urandom(4)
        n = len(payload)
        head = bytes([0x80 | opcode])
        if n < 126:
            head += bytes([0x80 | n])
        elif n < 1 << 16:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(head + mask + masked)

    def _frame(self) -> tuple[int, bytes]:
        """The next whole message: (opcode, payload); answers pings."""
        data, first_op = b"", None
        while True:
            b0, b1 = self._read(2)
            op, n = b0 & 0x0F, b1 & 0x7F
            if n == 126:
                (n,) = struct.unpack(">H", self._read(2))
            elif n == 127:
                (n,) = struct.unpack(">Q", self._read(8))
            mask = self._read(4) if b1 & 0x80 else None
            payload = self._read(n)
            if mask:
                payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
            if op == 0x9:  # ping
                self._send(0xA, payload)
                continue
            if op == 0xA:
                continue
            if op == 0x8:
                raise OSError("the server closed the connection")
            first_op = op if first_op is None else first_op
            data += payload
            if b0 & 0x80:
                return first_op, data

    # -------------------------------------------------------------- protocol
    def poll(self, timeout: float) -> None:
        """Read what arrives for up to ``timeout`` s (advertisements, messages)."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.sock.settimeout(left)
            try:
                op, data = self._frame()
            except TimeoutError:
                return
            if op == 0x1:
                msg = json.loads(data)
                if msg.get("op") == "serverInfo":
                    self.server_info = msg
                elif msg.get("op") == "advertise":
                    for ch in msg["channels"]:
                        self.channels[ch["topic"]] = ch
                elif msg.get("op") == "unadvertise":
                    ids = set(msg["channelIds"])
                    self.channels = {t: c for t, c in self.channels.items() if c["id"] not in ids}
            elif op == 0x2 and data[:1] == b"\x01":
                sub, log_time = struct.unpack_from("<IQ", data, 1)
                if sub in self._subs:
                    self.messages.append((self._subs[sub], log_time, data[13:]))

    def wait_channels(self, topics: list[str], timeout: float = 5.0) -> None:
        """Poll until every topic of ``topics`` is advertised (AssertionError after
        ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while not set(topics) <= set(self.channels) and time.monotonic() < deadline:
            self.poll(0.1)
        missing = set(topics) - set(self.channels)
        assert not missing, f"not advertised: {sorted(missing)} (have {sorted(self.channels)})"

    def subscribe(self, topics: list[str]) -> None:
        """Subscribe the advertised channels of ``topics``."""
        subs = []
        for topic in topics:
            sid = len(self._subs) + 1
            self._subs[sid] = topic
            subs.append({"id": sid, "channelId": self.channels[topic]["id"]})
        self._send(0x1, json.dumps({"op": "subscribe", "subscriptions": subs}).encode())

    def received(self, topic: str) -> list[bytes]:
        """The payloads received on ``topic`` so far."""
        return [p for t, _, p in self.messages if t == topic]

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._send(0x8, struct.pack(">H", 1000))
        self.sock.close()


def layout_topics(layout: dict) -> dict[str, list[str]]:
    """topic -> the message paths a Foxglove layout (``foxglove/rs_localizer.json`` parsed)
    reads from it ('' = the whole message); AssertionError on a panel kind not known here."""
    out: dict[str, list[str]] = {}
    for pid, cfg in layout["configById"].items():
        kind = pid.split("!")[0]
        if kind == "3D":
            for t in cfg["topics"]:
                out.setdefault(t, []).append("")
        elif kind == "Image":
            out.setdefault(cfg["imageMode"]["imageTopic"], []).append("")
        elif kind == "Plot":
            for p in cfg["paths"]:
                topic, _, field = p["value"].partition(".")
                out.setdefault(topic, []).append(field)
        elif kind in ("DiagnosticSummary", "DiagnosticStatusPanel"):
            out.setdefault(cfg["topicToRender"], []).append("")
        else:
            raise AssertionError(f"a panel this test does not check: {pid}")
    return out
