"""An MCAP file's records in file order, as far as they are whole.

A node killed outright (``kill -9``, a power cut) leaves its log without the footer and
summary that :func:`mcap.reader.make_reader` seeks to, and perhaps with a last record half
written. :class:`WholeRecords` reads with :class:`mcap.stream_reader.StreamReader` instead,
which needs neither, and stops at the first record that cannot be read: every record before
it is returned (a chunk's messages all or none: chunks carry a CRC, which is checked), and
how the reading ended is told in ``complete`` and ``problem``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import IO

from mcap.records import Footer, McapRecord
from mcap.stream_reader import StreamReader

__all__ = ["WholeRecords"]


class WholeRecords:
    """Iterate once over the whole records of ``stream``; afterwards ``complete`` says whether
    the footer was reached, and otherwise ``problem`` what stopped the reading, ``stopped_at``
    where (the byte after the last whole record) and ``cut_short`` whether that is the end of
    the file (a log cut short) rather than damage inside it."""

    def __init__(self, stream: IO[bytes]) -> None:
        self._stream = stream
        self.size = os.fstat(stream.fileno()).st_size
        self.complete = False
        self.problem: str | None = None
        self.stopped_at = 0

    @property
    def cut_short(self) -> bool:
        """Reading stopped because the file ends, not at damage before its end."""
        return not self.complete and self._stream.tell() >= self.size

    def __iter__(self) -> Iterator[McapRecord]:
        records = StreamReader(self._stream, validate_crcs=True).records
        while True:
            self.stopped_at = self._stream.tell()
            try:
                record = next(records)
            except StopIteration:
                break
            # whatever the library raises on bytes it cannot read (EndOfFile, struct.error,
            # a decompressor's error, a CRC mismatch...): no record here, and none after
            except Exception as exc:
                self.problem = f"{type(exc).__name__}: {exc}".rstrip(": ")
                return
            if isinstance(record, Footer):
                self.complete = True
            yield record
        self.stopped_at = self._stream.tell()
