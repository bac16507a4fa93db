"""Reading rosbag2-layout MCAP bags record by record, tolerant of a cut-off or corrupt file (see the
package docstring); :func:`copy_messages` into a writer."""
from __future__ import annotations

import heapq
import io
import os
import struct
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Message, Schema
from mcap.stream_reader import breakup_chunk, get_chunk_data_stream

from hexapod_model import contract
from hexapod_sim.bagio.cdr import decoder_for
from hexapod_sim.bagio.common import MCAP_MAGIC, BagError, BagMessage, BagWarning, TopicInfo
from hexapod_sim.bagio.definitions import message_definition, normalize_type_name

_KNOWN_OPCODES = {int(o) for o in Opcode}


@dataclass
class _ChunkRef:
    file_idx: int
    offset: int            # byte offset of the chunk record (opcode byte)
    length: int            # record length incl. the 9-byte opcode+length prefix
    start_ns: int
    end_ns: int
    count: int


@dataclass
class _FileScan:
    path: Path
    size: int
    chunks: list = field(default_factory=list)
    loose: list = field(default_factory=list)        # Message records outside chunks
    schemas: dict = field(default_factory=dict)      # id -> Schema
    channels: dict = field(default_factory=dict)     # id -> Channel
    counts: dict = field(default_factory=dict)       # channel id -> readable messages
    complete: bool = False                           # footer + trailing magic present
    readable_bytes: int = 0                          # end of the last complete record
    problems: list = field(default_factory=list)     # human-readable warnings
    # every chunk in file order: a readable one's _ChunkRef, or (start_ns, end_ns) of a corrupt one as its
    # header states them (the header lies outside the compressed data, but may be damaged too)
    order: list = field(default_factory=list)


def _opname(op: int) -> str:
    try:
        return Opcode(op).name
    except ValueError:
        return f'0x{op:02x}'


def _collect_chunk_records(chunk: Chunk, scan: _FileScan) -> tuple[list[Message], int]:
    records = breakup_chunk(chunk, validate_crc=True)
    msgs = []
    for r in records:
        if isinstance(r, Schema):
            scan.schemas.setdefault(r.id, r)
        elif isinstance(r, Channel):
            scan.channels.setdefault(r.id, r)
        elif isinstance(r, Message):
            msgs.append(r)
    return msgs, len(msgs)


def _check_magic(path: Path, head: bytes, size: int) -> None:
    """Refuse a file that is empty or does not start with the MCAP magic, saying which."""
    if size == 0:
        raise BagError(f'{path}: file is empty (0 bytes): no data was ever written to this bag')
    if head != MCAP_MAGIC:
        if MCAP_MAGIC.startswith(head):
            raise BagError(f'{path}: truncated to {size} bytes, before the end of the MCAP magic; '
                           'nothing is readable')
        raise BagError(f'{path}: not an MCAP file (starts with {head[:8]!r}, expected the MCAP '
                       f'magic {MCAP_MAGIC!r}); nothing is readable')


def _record_header(f, scan: _FileScan, pos: int, size: int) -> tuple[int, int] | None:
    """The opcode and length of the record at ``pos``; None, with the problem noted, when the header
    is cut off, the opcode is invalid or the record runs past the end of the file."""
    if size - pos < 9:
        scan.problems.append(f'truncated at byte {size}: {size - pos} trailing byte(s) of an '
                             'incomplete record header')
        return None
    f.seek(pos)
    op, length = struct.unpack('<BQ', f.read(9))
    if op not in _KNOWN_OPCODES and op < 0x80:
        scan.problems.append(f'corrupt data at byte {pos}: invalid record opcode 0x{op:02x}; '
                             f'the remaining {size - pos} bytes are unreadable')
        return None
    if pos + 9 + length > size:
        scan.problems.append(
            f'truncated at byte {size}: the {_opname(op)} record starting at byte {pos} needs '
            f'{9 + length} bytes but only {size - pos} remain')
        return None
    return op, length


def _scan_chunk(scan: _FileScan, stream, file_idx: int, pos: int, length: int) -> None:
    """A chunk record: its messages counted and the chunk noted for reading; a corrupt chunk is skipped."""
    chunk = Chunk.read(stream)
    try:
        msgs, n = _collect_chunk_records(chunk, scan)
    except Exception as exc:      # bad compression / CRC / inner framing
        scan.problems.append(f'corrupt chunk at byte {pos} ({exc}); its messages are '
                             'skipped')
        scan.order.append((chunk.message_start_time, chunk.message_end_time))
    else:
        if n:
            scan.chunks.append(_ChunkRef(file_idx, pos, 9 + length,
                                         chunk.message_start_time, chunk.message_end_time, n))
            scan.order.append(scan.chunks[-1])
            for m in msgs:
                scan.counts[m.channel_id] = scan.counts.get(m.channel_id, 0) + 1


def _scan_record(f, scan: _FileScan, file_idx: int, op: int, body: bytes, pos: int, length: int) -> bool:
    """One record into ``scan``; True at the footer (the file is complete when the magic follows it)."""
    stream = ReadDataStream(io.BytesIO(body))
    if op == Opcode.CHUNK:
        _scan_chunk(scan, stream, file_idx, pos, length)
    elif op == Opcode.SCHEMA:
        rec = Schema.read(stream)
        scan.schemas.setdefault(rec.id, rec)
    elif op == Opcode.CHANNEL:
        rec = Channel.read(stream)
        scan.channels.setdefault(rec.id, rec)
    elif op == Opcode.MESSAGE:
        rec = Message.read(stream, length)
        scan.loose.append(rec)
        scan.counts[rec.channel_id] = scan.counts.get(rec.channel_id, 0) + 1
    elif op == Opcode.FOOTER:
        Footer.read(stream)
        f.seek(pos + 9 + length)
        tail = f.read(len(MCAP_MAGIC))
        if tail != MCAP_MAGIC:
            scan.problems.append(f'footer at byte {pos} is not followed by the MCAP magic')
        else:
            scan.complete = True
        scan.readable_bytes = pos + 9 + length + len(tail)
        return True
    return False


def _scan_file(path: Path, file_idx: int) -> _FileScan:
    """Walk every record of one MCAP file; stop at the first broken/truncated record."""
    try:
        size = path.stat().st_size
        f = open(path, 'rb')
    except OSError as exc:
        raise BagError(f'{path}: cannot open: {exc.strerror or exc}') from exc
    scan = _FileScan(path, size)
    with f:
        _check_magic(path, f.read(len(MCAP_MAGIC)), size)
        pos = len(MCAP_MAGIC)
        scan.readable_bytes = pos
        while pos < size:
            header = _record_header(f, scan, pos, size)
            if header is None:
                break
            op, length = header
            body = f.read(length)
            try:
                if _scan_record(f, scan, file_idx, op, body, pos, length):
                    break
            except Exception as exc:
                scan.problems.append(f'corrupt {_opname(op)} record at byte {pos} ({exc}); the '
                                     f'remaining {size - pos} bytes are unreadable')
                break
            pos += 9 + length
            scan.readable_bytes = pos
        if not scan.complete and not scan.problems:
            scan.problems.append(f'ends at byte {size} without the MCAP summary/footer (recording was '
                                 'not closed)')
    return scan


_RECORD = struct.Struct('<BQ')           # opcode, length
_MESSAGE = struct.Struct('<HIQQ')        # channel id, sequence, log time, publish time


def _lost_spans(order: list) -> list[tuple[int, int]]:
    """(start_ns, end_ns) of log time whose messages went with each corrupt chunk of one file: from the end
    of the readable chunk before it to the start of the one after it (chunks are written in log-time
    order); the chunk's own header bounds the side without a readable neighbour."""
    out = []
    for i, item in enumerate(order):
        if isinstance(item, _ChunkRef):
            continue
        before = next((c.end_ns for c in reversed(order[:i]) if isinstance(c, _ChunkRef)), None)
        after = next((c.start_ns for c in order[i + 1:] if isinstance(c, _ChunkRef)), None)
        lo = item[0] if before is None else before
        hi = item[1] if after is None else after
        if before is not None and after is None:
            hi = max(hi, lo)
        if after is not None and before is None:
            lo = min(lo, hi)
        if lo < hi:
            out.append((lo, hi))
    return out


def _load_chunk(fh, ref: _ChunkRef) -> list[Message]:
    """The Message records of a chunk, as ``mcap.stream_reader.breakup_chunk`` gives them (decompressed and
    CRC-checked by it), split with one ``struct`` call per record."""
    fh.seek(ref.offset + 9)
    chunk = Chunk.read(ReadDataStream(io.BytesIO(fh.read(ref.length - 9))))
    stream, size = get_chunk_data_stream(chunk, validate_crc=True)
    data = stream.read(size)
    out, pos = [], 0
    while pos < size:
        opcode, length = _RECORD.unpack_from(data, pos)
        pos += 9
        if pos + length > size:
            raise ValueError(f'record of {length} bytes at byte {pos - 9} runs past the chunk\'s {size} bytes')
        if opcode == Opcode.MESSAGE:
            channel_id, sequence, log_time, publish_time = _MESSAGE.unpack_from(data, pos)
            out.append(Message(channel_id=channel_id, log_time=log_time, data=data[pos + 22:pos + length],
                               publish_time=publish_time, sequence=sequence))
        pos += length
    return out


class BagReader:
    """Read a rosbag2 directory or a single ``.mcap`` file.

    Everything is checked at open: :class:`BagError` if nothing is readable (missing path, empty
    or garbage file, no messages); one :class:`BagWarning` per problem otherwise (truncated tail
    -> read up to the last complete chunk; corrupt chunk -> skipped; topic whose message type
    cannot be decoded -> skipped by :meth:`messages` unless ``raw=True``). ``warnings`` lists them.
    """

    def __init__(self, path: str | os.PathLike, *, ignore_metadata: bool = False):
        self.path = Path(path)
        self._ignore_metadata = ignore_metadata     # read the directory's .mcap files, whatever metadata.yaml lists
        self.warnings: list[str] = []
        self.metadata: dict | None = None
        self._defer_warnings = True     # warn only once we know the bag is readable at all
        files = self._resolve_files()
        self._scans = [_scan_file(p, i) for i, p in enumerate(files)]
        for s in self._scans:
            for p in s.problems:
                recovered = sum(s.counts.values())
                self._warn(f'{s.path.name}: {p}; {recovered} message(s) in {len(s.chunks)} complete '
                           f'chunk(s) are readable ({s.readable_bytes} of {s.size} bytes)')
        self._build_topics()
        for s_idx, s in enumerate(self._scans):
            orphans = sum(n for cid, n in s.counts.items() if (s_idx, cid) not in self._chan)
            if orphans:
                self._warn(f'{s.path.name}: {orphans} message(s) refer to a channel whose definition '
                           'record was lost (corrupt chunk); they are skipped')
        if self.message_count == 0:
            what = '; '.join(f'{s.path.name}: ' + ('; '.join(s.problems) if s.problems else
                                                   'complete file with no messages')
                             for s in self._scans)
            raise BagError(f'{self.path}: no readable messages ({what})')
        self._defer_warnings = False
        for text in self.warnings:
            warnings.warn(f'{self.path}: {text}', BagWarning, stacklevel=2)

    # -- open helpers --
    def _warn(self, text: str) -> None:
        self.warnings.append(text)
        if not self._defer_warnings:
            warnings.warn(f'{self.path}: {text}', BagWarning, stacklevel=3)

    def _resolve_files(self) -> list[Path]:
        p = self.path
        if not p.exists():
            raise BagError(f'{p}: no such file or directory (expected a rosbag2 directory or an .mcap file)')
        if p.is_file():
            if p.name == 'metadata.yaml':
                self.path = p = p.parent
            else:
                return [p]
        meta_file = p / 'metadata.yaml'
        mcaps = sorted(x for x in p.iterdir() if x.suffix == '.mcap' and x.is_file())
        if meta_file.is_file() and not self._ignore_metadata:
            try:
                info = yaml.safe_load(meta_file.read_text())['rosbag2_bagfile_information']
                rel = list(info['relative_file_paths'])
                storage = info.get('storage_identifier', 'mcap')
            except Exception as exc:
                if not mcaps:
                    raise BagError(f'{meta_file}: not a valid rosbag2 metadata file ({exc}) and no .mcap '
                                   'file in the directory') from exc
                self._warn(f'metadata.yaml is unreadable ({exc}); reading {[m.name for m in mcaps]}')
                return mcaps
            if storage != 'mcap':
                raise BagError(f'{p}: storage {storage!r} is not supported (only mcap)')
            self.metadata = info
            files = [p / Path(r).name for r in rel]
            missing = [f.name for f in files if not f.exists()]
            if missing:
                raise BagError(f'{p}: metadata.yaml lists file(s) that do not exist: {missing}')
            if not files:
                if not mcaps:
                    raise BagError(f'{p}: metadata.yaml lists no data files and the directory has no '
                                   '.mcap file')
                files = mcaps
            return files
        if mcaps:
            if not self._ignore_metadata:
                self._warn(f'no metadata.yaml; reading {[m.name for m in mcaps]}')
            return mcaps
        raise BagError(f'{p}: not a rosbag2 directory (no metadata.yaml and no .mcap file)')

    def _build_topics(self) -> None:
        meta_topics = {}
        if self.metadata:
            for entry in self.metadata.get('topics_with_message_count') or []:
                tm = entry.get('topic_metadata', {}) if isinstance(entry, dict) else {}
                if 'name' in tm:
                    meta_topics[tm['name']] = tm
        self._chan: dict[tuple[int, int], tuple[str, str]] = {}     # (file, cid) -> (topic, type)
        self._decoders: dict[tuple[int, int], Any] = {}
        counts: dict[str, int] = {}
        types: dict[str, str] = {}
        hashes: dict[str, str] = {}
        self.undecodable: dict[str, str] = {}
        for s_idx, s in enumerate(self._scans):
            for cid, ch in s.channels.items():
                schema = s.schemas.get(ch.schema_id)
                msg_type = schema.name if schema is not None and schema.name else \
                    meta_topics.get(ch.topic, {}).get('type', '')
                try:
                    msg_type = normalize_type_name(msg_type)
                except BagError:
                    pass
                self._chan[(s_idx, cid)] = (ch.topic, msg_type)
                types.setdefault(ch.topic, msg_type)
                counts[ch.topic] = counts.get(ch.topic, 0) + s.counts.get(cid, 0)
                h = ch.metadata.get('topic_type_hash') or meta_topics.get(ch.topic, {}).get(
                    'type_description_hash', '')
                if h:
                    hashes.setdefault(ch.topic, h)
                dec, why = self._make_decoder(ch, schema, msg_type)
                if dec is not None:
                    self._decoders[(s_idx, cid)] = dec
                elif ch.topic not in self.undecodable:
                    self.undecodable[ch.topic] = why
                    self._warn(f'topic {ch.topic} ({msg_type or "unknown type"}): {why}; its '
                               f'{counts[ch.topic]} message(s) are skipped when decoding')
        self._topics = {}
        for topic, msg_type in types.items():
            tm = meta_topics.get(topic, {})
            qos = tm.get('offered_qos_profiles', [])
            if isinstance(qos, str):
                try:
                    qos = yaml.safe_load(qos) or []
                except yaml.YAMLError:
                    qos = []
            self._topics[topic] = TopicInfo(topic, msg_type, counts.get(topic, 0), tuple(qos or ()),
                                            hashes.get(topic, ''))

    @staticmethod
    def _make_decoder(ch: Channel, schema: Schema | None, msg_type: str):
        if ch.message_encoding != 'cdr':
            return None, f'message encoding {ch.message_encoding!r} is not CDR'
        reasons = []
        if schema is not None and schema.encoding == 'ros2msg' and schema.data:
            try:
                return decoder_for(schema.name, schema.data.decode()), ''
            except Exception as exc:
                reasons.append(f'its stored ros2msg schema does not parse ({exc})')
        elif schema is not None and schema.data:
            reasons.append(f'its stored schema is in {schema.encoding!r}, not ros2msg')
        else:
            reasons.append('the bag stores no schema for it')
        try:
            text = message_definition(msg_type)
            dec = decoder_for(msg_type, text)
            return dec, ''
        except Exception as exc:
            reasons.append(f'no local definition ({exc})' if msg_type else 'and its type is unknown')
        return None, 'cannot be decoded: ' + '; '.join(reasons)

    # -- queries --
    def topics(self) -> dict[str, str]:
        """{topic: message type} of every topic in the bag (decodable or not)."""
        return {t: i.msg_type for t, i in self._topics.items()}

    def topic_info(self) -> dict[str, TopicInfo]:
        return dict(self._topics)

    def resolve(self, name: str) -> str | None:
        """The bag's name of a contract topic ('joint_states' or '/joint_states'), None if absent."""
        key = contract.topic_key(name)
        return next((t for t in self._topics if contract.topic_key(t) == key), None)

    @property
    def message_count(self) -> int:
        return sum(i.message_count for i in self._topics.values())

    @property
    def complete(self) -> bool:
        """True if every file ended with a valid footer and nothing had to be skipped."""
        return all(s.complete for s in self._scans) and not self.warnings

    @property
    def lost_spans(self) -> list[tuple[int, int]]:
        """(start_ns, end_ns) of the log-time spans whose messages were in corrupt chunks (skipped), merged and
        sorted; empty if no chunk was lost (a truncated tail is not a span: the bag just ends earlier)."""
        spans = sorted(sp for s in self._scans for sp in _lost_spans(s.order))
        out: list[list[int]] = []
        for a, b in spans:
            if out and a <= out[-1][1]:
                out[-1][1] = max(out[-1][1], b)
            else:
                out.append([a, b])
        return [(a, b) for a, b in out]

    @property
    def start_ns(self) -> int:
        times = [c.start_ns for s in self._scans for c in s.chunks] + \
                [m.log_time for s in self._scans for m in s.loose]
        return min(times) if times else 0

    @property
    def end_ns(self) -> int:
        times = [c.end_ns for s in self._scans for c in s.chunks] + \
                [m.log_time for s in self._scans for m in s.loose]
        return max(times) if times else 0

    def messages(self, topics: Sequence[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None, *, raw: bool = False) -> Iterator[BagMessage]:
        """Yield ``(topic, msg_type, t_ns, msg)`` in log-time order (file order for equal times),
        ``start_ns <= t_ns < end_ns``; ``topics`` not in the bag yield nothing. ``raw=True`` yields the CDR bytes (undecodable topics
        included); otherwise decoded messages with attribute access."""
        if isinstance(topics, str):
            topics = [topics]
        # '/x' and 'x' name one topic (contract names are relative); topics absent from the bag: none yielded
        wanted = None if topics is None else {contract.topic_key(t) for t in topics}
        lo = -1 if start_ns is None else int(start_ns)
        hi = 2**64 if end_ns is None else int(end_ns)
        decode_failed: dict[str, int] = {}

        def accept(file_idx: int, m: Message):
            key = (file_idx, m.channel_id)
            ch = self._chan.get(key)
            if ch is None or not lo <= m.log_time < hi:
                return None
            if wanted is not None and contract.topic_key(ch[0]) not in wanted:
                return None
            if not raw and key not in self._decoders:
                return None
            return ch

        refs = sorted((c for s in self._scans for c in s.chunks if c.end_ns >= lo and c.start_ns < hi),
                      key=lambda c: (c.start_ns, c.file_idx, c.offset))
        handles = {}
        heap: list = []
        seq = 0
        try:
            for s_idx, s in enumerate(self._scans):
                for m in s.loose:
                    heapq.heappush(heap, (m.log_time, seq, s_idx, m))
                    seq += 1
            i = 0
            while i < len(refs) or heap:
                while i < len(refs) and (not heap or refs[i].start_ns <= heap[0][0]):
                    ref = refs[i]
                    i += 1
                    fh = handles.get(ref.file_idx)
                    if fh is None:
                        fh = handles[ref.file_idx] = open(self._scans[ref.file_idx].path, 'rb')
                    try:
                        msgs = _load_chunk(fh, ref)
                    except Exception as exc:
                        self._warn(f'chunk at byte {ref.offset} of {self._scans[ref.file_idx].path.name} '
                                   f'became unreadable ({exc}); its {ref.count} message(s) are skipped')
                        continue
                    for m in msgs:
                        if accept(ref.file_idx, m) is not None:       # the others never leave the heap
                            heapq.heappush(heap, (m.log_time, seq, ref.file_idx, m))
                            seq += 1
                if not heap:
                    continue
                _, _, f_idx, m = heapq.heappop(heap)
                ch = accept(f_idx, m)
                if ch is None:
                    continue
                if raw:
                    yield BagMessage(ch[0], ch[1], m.log_time, m.data)
                    continue
                try:
                    msg = self._decoders[(f_idx, m.channel_id)](m.data)
                except Exception as exc:
                    n = decode_failed.get(ch[0], 0)
                    decode_failed[ch[0]] = n + 1
                    if n == 0:
                        self._warn(f'topic {ch[0]}: message at t={m.log_time} ns does not decode as '
                                   f'{ch[1]} ({exc}); skipping it (further failures on this topic are '
                                   'skipped silently)')
                    continue
                yield BagMessage(ch[0], ch[1], m.log_time, msg)
        finally:
            for fh in handles.values():
                fh.close()

    def __iter__(self) -> Iterator[BagMessage]:
        return self.messages()

    def schema_text(self, topic: str) -> str | None:
        """The ros2msg definition stored in the bag for a topic (None if none)."""
        for s_idx, s in enumerate(self._scans):
            for cid, ch in s.channels.items():
                sc = s.schemas.get(ch.schema_id)
                if ch.topic == topic and sc is not None and sc.encoding == 'ros2msg' and sc.data:
                    return sc.data.decode()
        return None


def copy_messages(reader: 'BagReader', w) -> int:
    """Every readable message of ``reader`` into the open :class:`~hexapod_sim.bagio.writer.BagWriter` ``w``, with the topics'
    definitions and QoS; the number of messages copied."""
    n = 0
    for topic, info in reader.topic_info().items():
        w.add_topic(topic, info.msg_type, definition=reader.schema_text(topic),
                    qos_profiles=list(info.offered_qos_profiles) or None)
    for topic, msg_type, t_ns, data in reader.messages(raw=True):
        w.write(topic, msg_type, data, t_ns)
        n += 1
    return n
