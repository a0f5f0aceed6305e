"""Source and log events: what happened to the devices and the log file, beside the records.

A GPS unplugged and plugged back, a receiver at the wrong baud rate, a CAN reader that raised, the disk full, the
host clock stepped: each is a SourceEvent, written to the log's /diagnostics/events topic and shown in the live view.
Events are informational: the estimates depend only on the raw records, so replay needs none of them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True, slots=True)
class SourceEvent:
    time_s: float
    """When it happened, in the log's clock."""
    source: str
    """'gps', 'can', 'log' or 'clock'."""
    event: str
    """gps: connected, disconnected, silent, unreadable, readable, emit_error; can: reader_error, down, up;
    log: write_failed, resumed, rotated; clock: stepped."""
    detail: str = ""
    gap_s: float | None = None
    """For connected/resumed/up/readable: how long the outage lasted."""
    counters: dict[str, int] = field(default_factory=dict)
    """The source's running counters at that moment (gaps, reconnects, unreadable periods, dropped messages...)."""

    def as_dict(self) -> dict[str, Any]:
        return {"time_s": self.time_s, "source": self.source, "event": self.event, "detail": self.detail,
                "gap_s": self.gap_s, "counters": dict(self.counters)}


EventHandler = Callable[[SourceEvent], None]


class EventFanout:
    """One handler that passes each event to every target's on_source_event (those that have one)."""

    def __init__(self, targets: Iterable[object]) -> None:
        self._handlers = [h for t in targets if (h := getattr(t, "on_source_event", None)) is not None]

    def __call__(self, event: SourceEvent) -> None:
        for h in self._handlers:
            h(event)
