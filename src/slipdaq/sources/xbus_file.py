"""An Xsens MTi's serial capture (the raw bytes it sent) as import records: XbusBytes stamped from the MTi's own
clock, as bare NMEA sentences take their UTC time (sources/files.py).

Framed as the live serial reader frames them (decode/xbus.py). A packet with a valid UTCTime takes that time; one
without, the last such time plus its SampleTimeFine since then (10 kHz ticks, wrapping at 2^32), or before the first
one, that first time minus the ticks to it; a record without either (noise, other messages) the time of the record
before it (the first UTC time for those before it). Times never go back: a record stamped before the one before it
(a GNSS packet's UTCTime is its epoch's, a little earlier than the samples') takes that record's time.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from slipdaq.decode.sample_clock import TICKS_PER_S, ticks_between
from slipdaq.decode.xbus import XbusDecoder, XbusFramer
from slipdaq.records import XbusBytes
from slipdaq.sources.read_errors import InputError

READ_BYTES = 1 << 16


def iter_xbus_capture(path: str | Path) -> Iterator[XbusBytes]:
    """The capture's records in order, stamped (module docstring); InputError without a file or without one packet
    whose UTCTime is valid (nothing to stamp the records with)."""
    p = Path(path)
    try:
        f = open(p, "rb")
    except OSError as e:
        raise InputError(f"{p}: cannot read it: {e.strerror or e}") from None
    framer, decoder = XbusFramer(), XbusDecoder()
    pending: list[tuple[XbusBytes, int | None]] = []
    anchor: tuple[float, int | None] | None = None  # (UTC time, its SampleTimeFine)
    last_s: float | None = None
    with f:
        while True:
            chunk = f.read(READ_BYTES)
            records = framer.feed(chunk, 0.0) if chunk else framer.flush()
            for r in records:
                packet = decoder.decode(r)
                stf = packet.sample_time_fine if packet is not None else None
                utc = packet.utc_time_s if packet is not None else None
                if anchor is None:
                    if utc is None:
                        pending.append((r, stf))
                        continue
                    anchor = (utc, stf)
                    for q, q_stf in pending:
                        t0 = utc - ticks_between(q_stf, stf) / TICKS_PER_S \
                            if q_stf is not None and stf is not None else utc
                        yield XbusBytes(t0, q.data)
                    pending = []
                if utc is not None:
                    anchor, t = (utc, stf), utc
                elif stf is not None and anchor[1] is not None:
                    t = anchor[0] + ticks_between(anchor[1], stf) / TICKS_PER_S
                else:
                    t = last_s if last_s is not None else anchor[0]
                if last_s is not None and t < last_s:  # a GNSS packet's UTCTime is its epoch's, a little earlier
                    t = last_s
                last_s = t
                yield XbusBytes(t, r.data)
            if not chunk:
                break
    if anchor is None:
        raise InputError(f"{p}: no MTi packet with a valid UTCTime in it ({decoder.packets} MTData2 packets): "
                         "nothing to stamp its records with")
