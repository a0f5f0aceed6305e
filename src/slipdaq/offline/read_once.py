"""A two-pass run's input read and decoded once (ReadOnce): the second pass gets the records the first pass decoded,
kept within a budget of memory, and what the pipeline's wheel and NMEA decoders made of them (decoder_tape)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

from slipdaq.offline.decoder_tape import DecoderTape
from slipdaq.offline.items import Decode, Item, let_go

KEEP_BYTES = 256 * 1024 * 1024
"""A two-pass run keeps the records its first pass decoded while the raw messages they came from stay within this
many bytes of data (about 40 minutes of 4 WPT messages at 1 kHz; the records take about as much: 24 bytes a CAN
frame), for its second pass; a longer log is read and decoded again."""


class ReadOnce:
    """A log's input for the two passes of a run: the first pass's items are decode(read(True)) (the read whose scan
    result the caller keeps); the second pass's are the same items, kept, or decode(read(False)) where the messages'
    data passed keep_bytes (KEEP_BYTES). `tape` records the first pass's decoders for the second (process's tape;
    tape_bytes: its budget), but for a log read again."""

    def __init__(self, read: Callable[[bool], Iterable[Any]], decode: Decode, keep_bytes: int | None = None,
                 tape_bytes: int | None = None) -> None:
        self._read = read
        self._decode = decode
        self._keep_bytes = KEEP_BYTES if keep_bytes is None else keep_bytes
        self._items: list[Item] | None = []
        """The first pass's items; None once the messages passed the budget (read again)."""
        self.tape = DecoderTape(tape_bytes)

    def first(self) -> Iterator[Item]:
        size = 0

        def messages() -> Iterator[Any]:
            nonlocal size
            for message in self._read(True):
                if self._items is not None:
                    size += len(message[-1])
                    if size > self._keep_bytes:  # read again: a part kept would spare none of the reading
                        self._items = None
                        self.tape.drop()  # the log read again is decoded again: it need not be the same (written)
                yield message

        for item in self._decode(messages()):
            if self._items is not None:
                self._items.append(item)
            yield item

    def second(self) -> Iterator[Item]:
        """The items again (once), each kept one let go as it is taken."""
        if self._items is None:
            yield from self._decode(self._read(False))
            return
        kept, self._items = self._items, []
        yield from let_go(kept)
