"""Ending a bag's MCAP file at its last complete flush after a write error: :func:`end_cut_file`.

A writer that hits a write error (disk full, file-size limit) cannot finish its MCAP file as it
would have. :func:`end_cut_file` cuts the file back to the end of its last complete flush, which
frees the room of the chunk that failed, and appends a summary of what is left (schemas, channels,
chunk indexes) and the footer: a valid, indexed MCAP file.
"""
from __future__ import annotations

import os
import struct
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import ChunkIndex, DataEnd, Footer

from hexapod_sim.bagio.common import MCAP_MAGIC
from hexapod_sim.bagio.reader import _scan_file


def end_cut_file(path: str | os.PathLike, good_end: int):
    """Make the MCAP file ``path`` valid again after a failed write: cut it back to ``good_end`` (the
    end of its last complete flush: chunks followed by their message indexes) and append Data End, a
    summary of what is left (schemas, channels, one chunk index per chunk) and the footer, so readers
    that need the index (``rosbags``, for messages not in log-time order) read it. If that does not
    fit (the file-size limit, a full disk), the last chunks are given up until it does. Returns the
    reader's scan of the file as it is then (its messages per channel); raises :class:`OSError` if
    not even an empty summary fits."""
    path = Path(path)
    with open(path, 'r+b') as f:
        f.truncate(good_end)
    scan = _scan_file(path, 0)                 # schemas and channels, also those inside chunks
    indexes = _chunk_indexes(path, good_end)
    end = good_end
    while True:
        try:
            _append_summary(path, end, scan, indexes)
            break
        except OSError:
            if not indexes:
                raise
            end = indexes.pop().chunk_start_offset      # give up the last chunk to make room
    return _scan_file(path, 0)


def _append_summary(path: Path, end: int, scan, indexes: list) -> None:
    summary = RecordBuilder()
    for sc in scan.schemas.values():
        sc.write(summary)
    for ch in scan.channels.values():
        ch.write(summary)
    for ci in indexes:
        ci.write(summary)
    body = summary.end()
    rb = RecordBuilder()
    DataEnd(data_section_crc=0).write(rb)
    head = rb.end()
    rb = RecordBuilder()
    Footer(summary_start=end + len(head), summary_offset_start=0, summary_crc=0).write(rb)
    with open(path, 'r+b') as f:
        f.truncate(end)
        f.seek(end)
        f.write(head + body + rb.end() + MCAP_MAGIC)
        f.flush()
        os.fsync(f.fileno())


def _chunk_indexes(path: Path, end: int) -> list:
    """A ChunkIndex for each chunk of the first ``end`` bytes (with the message index records after it)."""
    out = []
    with open(path, 'rb') as f:
        pos = len(MCAP_MAGIC)
        current = None
        while pos + 9 <= end:
            f.seek(pos)
            op, length = struct.unpack('<BQ', f.read(9))
            if pos + 9 + length > end:
                break
            if op == Opcode.CHUNK:
                head = f.read(min(length, 32))
                start_t, end_t, usize, _crc, clen = struct.unpack('<QQQII', head[:32])
                f.seek(pos + 9 + 32)
                comp = f.read(clen).decode(errors='replace')
                csize = struct.unpack('<Q', f.read(8))[0]
                current = ChunkIndex(chunk_length=9 + length, chunk_start_offset=pos, compression=comp,
                                     compressed_size=csize, message_end_time=end_t, message_index_length=0,
                                     message_index_offsets={}, message_start_time=start_t,
                                     uncompressed_size=usize)
                out.append(current)
            elif op == Opcode.MESSAGE_INDEX and current is not None:
                channel_id = struct.unpack('<H', f.read(2))[0]
                current.message_index_offsets[channel_id] = pos
                current.message_index_length += 9 + length
            else:
                current = None
            pos += 9 + length
    return out
