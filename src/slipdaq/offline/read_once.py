"""A two-pass run's input read and decoded once (ReadOnce): the second pass gets what the first pass read and decoded,
kept within a budget of memory, and what the pipeline's wheel and NMEA decoders made of it (decoder_tape)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

from slipdaq.offline.decoder_tape import DecoderTape
from slipdaq.offline.log_process import Decode, Item, Read, reads
from slipdaq.records import CanFrameBatch

KEEP_BYTES = 256 * 1024 * 1024
"""A two-pass run keeps the raw messages its first pass read, up to this many bytes of their data (about 40 minutes of
4 WPT messages at 1 kHz), for its second pass; a longer log is read again. The records decoded from them are kept
within as many bytes of their own (24 bytes a CAN frame); past that, the second pass decodes the messages kept."""
_RECORD_BYTES = 200
"""What a record other than a batch of CAN frames is counted as."""


def _bytes_of(item: Item) -> int:
    if isinstance(item, CanFrameBatch):
        return item.timestamp_s.nbytes + item.arbitration_id.nbytes + item.flags.nbytes + item.dlc.nbytes + \
            item.data.nbytes + item.channel.nbytes
    return _RECORD_BYTES * (len(item) if isinstance(item, list) else 1)


class ReadOnce:
    """A log's input for the two passes of a run. The first pass's items are decode(read(True)) (the read whose scan
    result the caller keeps); the second pass's are the same items, each with the messages decode read for it (a
    log_process.Read): kept from the first pass, or decoded again from the messages kept, or from the log read again
    (read(False)) where their data passed keep_bytes (KEEP_BYTES; the items' own: item_bytes, the same by default).
    `tape` records the first pass's decoders for the second (process's tape; tape_bytes: its budget), but for a log
    read again."""

    def __init__(self, read: Callable[[bool], Iterable[Any]], decode: Decode, keep_bytes: int | None = None,
                 item_bytes: int | None = None, tape_bytes: int | None = None) -> None:
        self._read = read
        self._decode = decode
        self._keep_bytes = KEEP_BYTES if keep_bytes is None else keep_bytes
        self._item_budget = self._keep_bytes if item_bytes is None else item_bytes
        self._reads: list[Read] | None = []
        """The first pass's reads, while their items are within the budget."""
        self._messages: list[list[Any]] | None = None
        """Their messages alone, once the items passed it."""
        self._again = False
        """The messages passed it: the log is read again."""
        self.tape = DecoderTape(tape_bytes)

    def first(self) -> Iterator[Item]:
        message_bytes = item_bytes = 0
        for read in reads(self._decode, self._read(True)):
            got, _, item = read
            if not self._again:
                message_bytes += sum(len(m[-1]) for m in got)
                if message_bytes > self._keep_bytes:  # read again: a part kept would spare none of the reading
                    self._again, self._reads, self._messages = True, None, None
                    self.tape.drop()  # the log read again is decoded again: it need not be the same (still written)
                elif self._reads is not None:
                    item_bytes += _bytes_of(item)
                    if item_bytes <= self._item_budget:
                        self._reads.append(read)
                    else:  # the messages kept, decoded again
                        self._messages, self._reads = [g for g, _, _ in self._reads] + [got], None
                elif self._messages is not None:
                    self._messages.append(got)
            yield item

    def second(self) -> Iterator[Read]:
        """The reads again (once), each kept one let go as it is taken."""
        if self._again:
            yield from reads(self._decode, self._read(False))
            return
        if self._reads is not None:
            kept, self._reads = self._reads[::-1], []
            while kept:
                yield kept.pop()
            return
        pieces, self._messages = (self._messages or [])[::-1], []

        def messages() -> Iterator[Any]:
            while pieces:
                yield from pieces.pop()

        yield from reads(self._decode, messages())
