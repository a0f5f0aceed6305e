"""A Foxglove WebSocket test client (tests/test_foxglove_live.py, tests/hil/test_foxglove_vcan.py).

`websockets` speaking the Foxglove WebSocket protocol v1: serverInfo and advertise in, subscribe out, binary message
data in (opcode 0x01, subscription id u32, log time u64, payload). foxglove-sdk 0.30 names the subprotocol
`foxglove.sdk.v1` and refuses the older name `foxglove.websocket.v1` (HTTP 400); the messages are the same.
Importable from tests/ and tests/hil/ (tests/ is on sys.path through tests/conftest.py).
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import websockets

SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = struct.Struct("<BIQ")


@dataclass
class Client:
    """What one client saw: the advertised channels by id, and the message data by topic (log time ns, payload)."""

    ws: Any = None
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    subscriptions: dict[int, str] = field(default_factory=dict)
    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)

    async def connect(self, url: str, *, receive_buffer_bytes: int | None = None, timeout_s: float = 10.0) -> None:
        """timeout_s: for the opening handshake and for serverInfo and advertise each (an emulated VM needs more)."""
        sock = None
        if receive_buffer_bytes is not None:  # set before connecting: the window it advertises stays that small
            host, port = url.removeprefix("ws://").rsplit(":", 1)
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
            sock.connect((host, int(port)))
        self.ws = await websockets.connect(url, subprotocols=[SUBPROTOCOL], sock=sock, max_queue=4, compression=None,
                                           open_timeout=timeout_s)
        while not self.channels:  # serverInfo, then the advertise of every registered topic
            self._control(json.loads(await asyncio.wait_for(self.ws.recv(), timeout_s)))

    def _control(self, msg: dict[str, Any]) -> list[dict[str, Any]]:
        if msg["op"] == "serverInfo":
            self.server_info = msg
        elif msg["op"] == "advertise":
            for ch in msg["channels"]:
                self.channels[ch["id"]] = ch
            return list(msg["channels"])
        return []

    async def subscribe(self, channels: list[dict[str, Any]]) -> None:
        subs = [{"id": len(self.subscriptions) + i + 1, "channelId": ch["id"]} for i, ch in enumerate(channels)]
        for s, ch in zip(subs, channels):
            self.subscriptions[s["id"]] = ch["topic"]
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def read_all(self) -> None:
        """Every message until the server goes away; channels advertised later are subscribed to as they come."""
        try:
            async for frame in self.ws:
                if isinstance(frame, str):
                    new = self._control(json.loads(frame))
                    if new:
                        await self.subscribe(new)
                    continue
                opcode, sub_id, log_time = MESSAGE_DATA.unpack_from(frame)
                if opcode == 1:
                    self.messages.setdefault(self.subscriptions[sub_id], []).append((log_time, frame[13:]))
        except websockets.ConnectionClosed:
            pass

    def advertised(self) -> dict[str, dict[str, Any]]:
        return {ch["topic"]: ch for ch in self.channels.values()}


def read_log(path: Path) -> tuple[dict[str, tuple[str, str, str, bytes]], dict[str, list[tuple[int, bytes]]]]:
    """A log as the live view should see it, read by the mcap library: its channels (topic -> message encoding, schema
    name, schema encoding, schema data) and its messages by topic ((log time, bytes) in file order)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].name,
                              summary.schemas[c.schema_id].encoding, summary.schemas[c.schema_id].data)
                    for c in summary.channels.values()}
        messages: dict[str, list[tuple[int, bytes]]] = {}
        for _s, channel, message in reader.iter_messages(log_time_order=False):
            messages.setdefault(channel.topic, []).append((message.log_time, message.data))
    return channels, messages
