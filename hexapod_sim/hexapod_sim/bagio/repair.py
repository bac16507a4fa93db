"""Repairing bags a recording left unfinished: :func:`end_cut_file` (a write error) and
:func:`reindex_bag` (a power cut, a copy taken half-written).

A writer that hits a write error (disk full, file-size limit) cannot finish its MCAP file as it
would have. :func:`end_cut_file` cuts the file back to the end of its last complete flush, which
frees the room of the chunk that failed, and appends a summary of what is left (schemas, channels,
chunk indexes) and the footer: a valid, indexed MCAP file.

:func:`reindex_bag` (``rosbag2 reindex`` in ROS 2 terms) rebuilds a bag whose files lack their
footer or index, or whose ``metadata.yaml`` is missing or lies: every readable message is copied
into one new, properly closed MCAP file and ``metadata.yaml`` is written from what the file holds.
The new files are written next to the old ones and only then replace them, so a repair that is
itself cut off leaves the bag as it was.
"""
from __future__ import annotations

import os
import shutil
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import ChunkIndex, DataEnd, Footer

from hexapod_sim.bagio.common import MCAP_MAGIC, BagError, BagWarning
from hexapod_sim.bagio.reader import BagReader, copy_messages
from hexapod_sim.bagio.writer import BagWriter

REINDEX_TMP = '.reindex'          # the rebuilt bag is written here inside the bag directory


def end_cut_file(path: str | os.PathLike, good_end: int):
    """Make the MCAP file ``path`` valid again after a failed write: cut it back to ``good_end`` (the
    end of its last complete flush: chunks followed by their message indexes) and append Data End, a
    summary of what is left (schemas, channels, one chunk index per chunk) and the footer, so readers
    that need the index (``rosbags``, for messages not in log-time order) read it. If that does not
    fit (the file-size limit, a full disk), the last chunks are given up until it does. Returns the
    reader's scan of the file as it is then (its messages per channel); raises :class:`OSError` if
    not even an empty summary fits."""
    from hexapod_sim.bagio.reader import _scan_file
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


@dataclass
class ReindexResult:
    path: Path
    rebuilt: bool           # False: the bag was complete, nothing was changed
    messages: int           # messages in the bag afterwards
    duration_s: float       # log time covered afterwards
    problems: list          # what the reader found wrong before (one line each)

    def line(self) -> str:
        if not self.rebuilt:
            return (f'{self.path}: complete ({self.messages} messages, {self.duration_s:.1f} s); '
                    'nothing to rebuild')
        return (f'{self.path}: rebuilt: {self.messages} messages, {self.duration_s:.1f} s of log time '
                f'(was: {self.problems[0]}' + (f'; and {len(self.problems) - 1} more problem(s)'
                                                if len(self.problems) > 1 else '') + ')')


def _read(path: Path, ignore_metadata: bool = False) -> BagReader:
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', BagWarning)
        return BagReader(path, ignore_metadata=ignore_metadata)


def reindex_bag(path: str | os.PathLike, *, force: bool = False) -> ReindexResult:
    """Rebuild the bag directory ``path`` into one complete MCAP file and a ``metadata.yaml`` that
    matches it (unless it is complete already and ``force`` is False). Raises :class:`BagError` if
    nothing in it is readable."""
    p = Path(path)
    if p.is_file():
        raise BagError(f'{p}: reindex works on a bag directory (the folder holding metadata.yaml and the '
                       '.mcap files), not on a file')
    if not p.is_dir():
        raise BagError(f'{p}: no such bag directory')
    tmp_root = p / REINDEX_TMP
    if tmp_root.exists():                   # left by a reindex that was cut off: start over
        shutil.rmtree(tmp_root)
    problems = []
    try:
        reader = _read(p)
    except BagError as exc:                 # e.g. metadata.yaml lists files that are not there
        problems.append(str(exc))
        reader = None
    if reader is not None:
        problems.extend(reader.warnings)
        unlisted = _unlisted_files(p, reader)
        if unlisted:
            problems.append(f'{len(unlisted)} .mcap file(s) not listed in metadata.yaml: {unlisted}')
        if reader.complete and reader.metadata is not None and not unlisted and not force:
            return ReindexResult(p, False, reader.message_count, (reader.end_ns - reader.start_ns) * 1e-9, [])
    if reader is None or reader.metadata is None or problems:
        reader = _read(p, ignore_metadata=True)       # the .mcap files themselves, whatever metadata.yaml says
    old_files = sorted(x.name for x in p.iterdir() if x.suffix == '.mcap' and x.is_file())
    name = p.resolve().name
    tmp = tmp_root / name
    custom = (reader.metadata or {}).get('custom_data') or None
    n = 0
    try:
        with BagWriter(tmp, custom_data=custom if isinstance(custom, dict) else None) as w:
            n = copy_messages(reader, w)
        new_mcap = tmp / f'{name}_0.mcap'
        os.replace(new_mcap, p / new_mcap.name)
        for old in old_files:
            if old != new_mcap.name and (p / old).exists():
                (p / old).unlink()
        os.replace(tmp / 'metadata.yaml', p / 'metadata.yaml')
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)
    after = _read(p)
    return ReindexResult(p, True, n, (after.end_ns - after.start_ns) * 1e-9,
                         problems or ['metadata.yaml missing or not matching the files'])


def _unlisted_files(p: Path, reader: BagReader) -> list[str]:
    if reader.metadata is None:
        return []
    listed = {s.path.name for s in reader._scans}
    return sorted(x.name for x in p.iterdir() if x.suffix == '.mcap' and x.is_file() and x.name not in listed)
