"""The Foxglove live view: a Foxglove WebSocket server (foxglove-sdk) inside the daemon that publishes every message
the MCAP log gets, with the log's topic, log time, message encoding and schema (logformat.registry), so that one
Foxglove layout (config/foxglove/slipdaq-layout.json) serves the live run and its log.

McapLogSink hands each message to `publish` (its tap) on the event loop: a list append. Every FLUSH_EVERY_S the
waiting messages go to the server together (MAX_PENDING at most wait; more are dropped and counted). Handing over
never waits for a client: the SDK copies the bytes into a bounded queue per client (`backlog_messages`; a client
that falls behind loses its oldest messages there) and its own threads send them; about 1 µs a message whether a
client reads or stopped reading (tests/test_foxglove_live.py). Stopping the server waits for the clients' close
handshakes, which a client that stopped reading never sends: `close` waits STOP_WAIT_S at most and leaves the rest
to a daemon thread.
"""

from __future__ import annotations

import asyncio
import threading

import foxglove
from foxglove.websocket import ChannelView, Client, ServerListener

from slipdaq.config import parse_host_port
from slipdaq.logformat.registry import TOPIC_FORMATS
from slipdaq.logformat.topics import log_time_ns

BACKLOG_MESSAGES = 1024
"""Messages queued per client before its oldest are dropped (the SDK's default)."""
STOP_WAIT_S = 1.0
"""How long `close` waits for the server to stop (reading clients get their queued messages meanwhile)."""
FLUSH_EVERY_S = 0.05
"""Messages are handed to the server in bursts this far apart (the live view's added latency)."""
MAX_PENDING = 4096
"""Messages waiting for the next burst, at most (about 15 s of the log at 4 x 1 kHz)."""


class _Subscriptions(ServerListener):
    """Which client is subscribed to which channel (the server calls these on its own threads; a client that goes
    away is unsubscribed from everything)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._by_client: dict[int, set[int]] = {}
        self.count = 0
        """Clients subscribed to at least one topic."""

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            self._by_client.setdefault(client.id, set()).add(channel.id)
            self.count = len(self._by_client)

    def on_unsubscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            channels = self._by_client.get(client.id)
            if channels is not None:
                channels.discard(channel.id)
                if not channels:
                    del self._by_client[client.id]
            self.count = len(self._by_client)


class FoxgloveLive:
    """A Foxglove WebSocket server on `[HOST:]PORT` (host default 127.0.0.1; port 0: any free one, see `port`) with
    one channel per topic of the log's registry: every topic registered when it starts, a topic registered later on
    its first message. OSError when it cannot listen there.

    Created on a running event loop, it hands the messages to the server every flush_every_s (one wake-up of the
    server's sender per burst, not per message: half its CPU), at most max_pending at a time (more are dropped and
    counted); else, or with flush_every_s 0, at once. While no client is subscribed nothing is handed over."""

    def __init__(self, address: str, *, name: str = "slipdaq", backlog_messages: int = BACKLOG_MESSAGES,
                 flush_every_s: float = FLUSH_EVERY_S, max_pending: int = MAX_PENDING) -> None:
        self.host, port = parse_host_port(address)
        self._context = foxglove.Context()
        self._subscriptions = _Subscriptions()
        try:
            self._server = foxglove.start_server(
                name=name, host=self.host, port=port, context=self._context, server_listener=self._subscriptions,
                message_backlog_size=backlog_messages)
        except RuntimeError as e:  # FoxgloveError: the port is taken, the host does not resolve
            raise OSError(f"cannot start the Foxglove live server on {address}: {e}") from None
        self.port: int = self._server.port
        """The port it listens on (the one chosen when 0 was asked)."""
        self._channels: dict[str, foxglove.Channel | None] = {}
        self.published_messages = 0
        """Messages handed to the server (while a client was subscribed)."""
        self.dropped_messages = 0
        """Messages not handed over: more than max_pending waiting, a topic without a format, the server refused."""
        self._stopped = False
        try:
            self._loop: asyncio.AbstractEventLoop | None = asyncio.get_running_loop() if flush_every_s > 0 else None
        except RuntimeError:
            self._loop = None
        self.flush_every_s = flush_every_s
        self.max_pending = max_pending
        self._pending: list[tuple[str, float, bytes]] = []
        self._timer: asyncio.TimerHandle | None = None
        for topic in list(TOPIC_FORMATS):
            self._channel(topic)

    @property
    def url(self) -> str:
        """ws://HOST:PORT, what a Foxglove app opens."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def _channel(self, topic: str) -> foxglove.Channel | None:
        fmt = TOPIC_FORMATS.get(topic)
        channel = None
        if fmt is not None:
            schema = foxglove.Schema(name=fmt.schema_name, encoding=fmt.schema_encoding, data=fmt.schema_data)
            channel = foxglove.Channel(topic, schema=schema, message_encoding=fmt.message_encoding,
                                       context=self._context)
        self._channels[topic] = channel
        return channel

    def publish(self, topic: str, log_time_s: float, data: bytes) -> None:
        """One message as the log gets it (McapLogSink's tap): never blocks, never raises."""
        if not self._subscriptions.count or self._stopped:  # nobody to send it to
            return
        if len(self._pending) >= self.max_pending:
            self.dropped_messages += 1
            return
        self._pending.append((topic, log_time_s, data))
        if self._timer is None:
            if self._loop is None or self._loop.is_closed():
                self.flush()
            else:
                self._timer = self._loop.call_later(self.flush_every_s, self.flush)

    def flush(self) -> None:
        """Hand the waiting messages to the server."""
        self._timer = None
        pending, self._pending = self._pending, []
        for topic, log_time_s, data in pending:
            channel = self._channels.get(topic)
            if channel is None and topic not in self._channels:  # registered after the server started: advertise it
                try:
                    channel = self._channel(topic)
                except Exception:
                    self._channels[topic] = None
            if channel is None:
                self.dropped_messages += 1
                continue
            try:
                channel.log(data, log_time=log_time_ns(log_time_s))
            except Exception:  # the SDK's errors are RuntimeErrors; whatever it raises, the run goes on
                self.dropped_messages += 1
                continue
            self.published_messages += 1

    @property
    def clients(self) -> int:
        """Clients subscribed to at least one topic now."""
        return self._subscriptions.count

    def status(self) -> dict[str, object]:
        """The server's state, for each /diagnostics record of the run (schemas.LIVE_DIAGNOSTICS)."""
        return {"live_address": self.url, "live_clients": self.clients,
                "live_published_messages": self.published_messages, "live_dropped_messages": self.dropped_messages}

    def close(self, wait_s: float = STOP_WAIT_S) -> bool:
        """Hand over what waits, stop the server; True when it stopped within wait_s (a client that stopped reading
        holds it longer: it then stops in the background). Safe to call twice."""
        if self._stopped:
            return True
        if self._timer is not None:
            self._timer.cancel()
        self.flush()
        self._stopped = True
        stopper = threading.Thread(target=self._server.stop, name="foxglove-stop", daemon=True)
        stopper.start()
        stopper.join(wait_s)
        return not stopper.is_alive()
