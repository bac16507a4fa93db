"""Writing rosbag2-layout MCAP bags, crash safe (see the package docstring)."""
from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from hexapod_model import contract
from hexapod_sim.bagio.cdr import encoder_for, normalize, parse_definitions, ros_message_type
from hexapod_sim.bagio.common import DEFAULT_QOS_PROFILE, ROS_DISTRO, ROSBAG2_VERSION, BagError, MessageEncodeError
from hexapod_sim.bagio.definitions import message_definition, normalize_type_name, type_hash
from hexapod_sim.bagio.end_cut import end_cut_file


class _NoAliasDumper(yaml.SafeDumper):
    """YAML without &anchors/*aliases (rosbag2 metadata never uses them)."""

    def ignore_aliases(self, data):
        return True


def _dump_yaml(obj: Any) -> str:
    return yaml.dump(obj, Dumper=_NoAliasDumper, default_flow_style=False, sort_keys=False)


def _qos_yaml(profiles: Sequence[Mapping]) -> str:
    return _dump_yaml([dict(p) for p in profiles]).strip()


@dataclass
class _WTopic:
    name: str
    msg_type: str
    definition: str
    rihs01: str
    qos: tuple
    channel_id: int
    specs: dict
    encoder: Any
    written: int = 0
    flushed: int = 0


class BagWriter:
    """Write a rosbag2 directory (``metadata.yaml`` + ``<dir>_0.mcap``), crash safe.

    ``write(topic, msg_type, msg, t_ns)``: ``msg`` is a nested dict, a ROS message instance
    (converted field by field, exactly like the equivalent dict), any object with the
    message's fields as attributes (e.g. a message decoded by :class:`BagReader`), or ``bytes``
    already CDR-serialized. ``t_ns`` is the record (log) time in nanoseconds.

    Crash safety: the open chunk is closed, the file flushed and fsync'ed and ``metadata.yaml``
    rewritten whenever ``flush_period_s`` of message time has passed since the last flush, and a
    background thread does the same when ``flush_period_s`` of wall time has passed with messages
    pending. A cut-off recording therefore loses at most the last period. ``close()`` writes the
    MCAP summary/footer and the final metadata. Thread safe.
    """

    def __init__(self, path_dir: str | os.PathLike, *, chunk_size: int = 1024 * 1024,
                 flush_period_s: float = 1.0, compression: str = 'zstd', fsync: bool = True,
                 custom_data: Mapping[str, str] | None = None):
        if not (isinstance(flush_period_s, (int, float)) and math.isfinite(flush_period_s)
                and flush_period_s > 0):
            raise BagError(f'flush_period_s must be a positive number of seconds, got {flush_period_s!r}')
        if not isinstance(chunk_size, int) or chunk_size <= 0:
            raise BagError(f'chunk_size must be a positive number of bytes, got {chunk_size!r}')
        comp = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE, '': CompressionType.NONE}.get(compression)
        if comp is None:
            raise BagError(f"compression must be 'zstd', 'lz4' or 'none', got {compression!r}")
        self.path = Path(path_dir)
        if self.path.suffix == '.mcap':
            raise BagError(f'{self.path}: BagWriter writes a rosbag2 directory; give a directory '
                           'path without the .mcap suffix')
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise BagError(f'{self.path} already exists and is not an empty directory; refusing to '
                           'overwrite a recording')
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:           # e.g. under /proc: the parent looks writable but is not
            raise BagError(f'{self.path}: cannot create the bag directory: {exc.strerror or exc}') from None
        self.mcap_path = self.path / f'{self.path.name}_0.mcap'
        self.metadata_path = self.path / 'metadata.yaml'
        self.flush_period_s = float(flush_period_s)
        self._period_ns = int(round(self.flush_period_s * 1e9))
        self._fsync = fsync
        self._custom = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._lock = threading.RLock()
        self._file = open(self.mcap_path, 'wb')
        self._mcap = McapWriter(self._file, chunk_size=chunk_size, compression=comp)
        self._mcap.start(profile='ros2', library='hexapod_sim.bagio (mcap-python)')
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _WTopic] = {}
        self._t_min = self._t_max = None            # over all written messages
        self._ft_min = self._ft_max = None          # over flushed messages
        self._pending = 0
        self._last_flush_t_ns: int | None = None
        self._last_flush_wall = time.monotonic()
        self._closed = False
        self._failure: str | None = None            # the write error that ended the recording
        self._good_end = 0                          # file offset after the last complete flush
        self._flush_locked()                        # header on disk + provisional metadata.yaml
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name=f'bagwriter-flush:{self.path.name}',
                                         daemon=True)
        self._flusher.start()

    # -- registration --
    def add_topic(self, topic: str, msg_type: str, *, definition: str | None = None,
                  qos_profiles: Sequence[Mapping] | None = None) -> None:
        """Register a topic (``write`` does it on first use with the installed definition and the
        default QoS). ``definition``: complete ros2msg text for a type not installed here."""
        with self._lock:
            self._check_open()
            self._add_topic_locked(topic, msg_type, definition, qos_profiles)

    def _add_topic_locked(self, topic, msg_type, definition, qos_profiles) -> _WTopic:
        topic = _bag_topic(topic)
        full = normalize_type_name(msg_type)
        if topic in self._topics:
            have = self._topics[topic]
            if have.msg_type != full:
                raise BagError(f'topic {topic} is already recorded as {have.msg_type}, cannot also '
                               f'write {full} on it')
            return have
        text = definition if definition is not None else message_definition(full)
        try:
            specs = parse_definitions(full, text)
            encoder = encoder_for(full, text)
        except BagError:
            raise
        except Exception as exc:
            raise BagError(f'message definition of {full} cannot be parsed: {exc}') from exc
        qos = tuple(dict(q) for q in (qos_profiles if qos_profiles is not None else [DEFAULT_QOS_PROFILE]))
        try:
            local_text = message_definition(full)
        except BagError:
            local_text = None
        rihs = type_hash(full) if definition is None or definition == local_text else ''
        if full not in self._schemas:
            self._schemas[full] = self._mcap.register_schema(full, 'ros2msg', text.encode())
        meta = {'offered_qos_profiles': _qos_yaml(qos)}
        if rihs:
            meta['topic_type_hash'] = rihs
        cid = self._mcap.register_channel(topic=topic, message_encoding='cdr',
                                          schema_id=self._schemas[full], metadata=meta)
        t = _WTopic(topic, full, text, rihs, qos, cid, specs, encoder)
        self._topics[topic] = t
        return t

    # -- writing --
    def encode(self, msg_type: str, msg: Any) -> bytes:
        """CDR bytes of ``msg`` for ``msg_type`` (dict / object / ROS message)."""
        full = normalize_type_name(msg_type)
        text = message_definition(full)
        return self._encode(_WTopic('', full, text, '', (), 0, parse_definitions(full, text),
                                    encoder_for(full, text)), msg)

    @staticmethod
    def _encode(t: _WTopic, msg: Any) -> bytes:
        if isinstance(msg, (bytes, bytearray, memoryview)):
            data = bytes(msg)
            if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
                raise MessageEncodeError(f'{t.name or t.msg_type}: bytes given but they do not start '
                                         'with a CDR encapsulation header (00 00 / 00 01)')
            return data
        ros_type = ros_message_type(msg)
        if ros_type is not None:
            if ros_type != t.msg_type:
                raise MessageEncodeError(f'{t.name or t.msg_type}: got a {ros_type} message for a '
                                         f'topic of type {t.msg_type}')
            # Encoded field by field like a dict, never with rclpy.serialization: on Jazzy/Fast-CDR
            # its output carries uninitialised padding after the message (e.g. 8 bytes after a
            # JointState), which readers that check the CDR size (rosbags) reject.
        pkg, _, name = t.msg_type.split('/')
        plain = normalize(msg, t.specs[f'{pkg}/{name}'], t.specs, t.msg_type)
        try:
            return t.encoder(plain)
        except Exception as exc:
            raise MessageEncodeError(f'{t.msg_type}: cannot encode message: {exc}') from exc

    def write(self, topic: str, msg_type: str, msg: Any, t_ns: int) -> None:
        if isinstance(t_ns, np.integer):
            t_ns = int(t_ns)
        if isinstance(t_ns, bool) or not isinstance(t_ns, int) or not 0 <= t_ns < 2**63:
            raise BagError(f'{topic}: t_ns must be a non-negative integer time in nanoseconds, got {t_ns!r}')
        topic = _bag_topic(topic)
        with self._lock:
            self._check_open()
            t = self._topics.get(topic)
            if t is None:
                t = self._add_topic_locked(topic, msg_type, None, None)
            elif msg_type != t.msg_type and normalize_type_name(msg_type) != t.msg_type:
                raise BagError(f'topic {topic} is recorded as {t.msg_type}, cannot write {msg_type} on it')
            data = self._encode(t, msg)
            try:
                self._mcap.add_message(channel_id=t.channel_id, log_time=t_ns, publish_time=t_ns, data=data)
            except OSError as exc:
                self._fail_locked(exc)
            t.written += 1
            self._pending += 1
            self._t_min = t_ns if self._t_min is None else min(self._t_min, t_ns)
            self._t_max = t_ns if self._t_max is None else max(self._t_max, t_ns)
            if self._last_flush_t_ns is None:
                self._last_flush_t_ns = t_ns
            if (t_ns - self._last_flush_t_ns >= self._period_ns
                    or time.monotonic() - self._last_flush_wall >= self.flush_period_s):
                self._flush_or_fail()

    def flush(self) -> None:
        """Close the open chunk, flush + fsync the file and rewrite metadata.yaml now."""
        with self._lock:
            self._check_open()
            self._flush_or_fail()

    def _flush_or_fail(self) -> None:
        try:
            self._flush_locked()
        except OSError as exc:
            self._fail_locked(exc)

    def _fail_locked(self, exc: OSError) -> None:
        """A write failed (disk full, file-size limit): end the bag at its last complete flush, which
        stays readable (:func:`~.end_cut.end_cut_file`, metadata.yaml of the flushed messages), and
        raise :class:`BagError` saying so; every later write raises it too."""
        self._closed = True
        if hasattr(self, '_stop'):                  # not yet there if the first flush fails
            self._stop.set()
        try:
            self._file.close()
        except OSError:
            pass
        kept = sum(t.flushed for t in self._topics.values())
        span = '' if self._ft_max is None else f' up to t={self._ft_max * 1e-9:.3f} s'
        try:
            scan = end_cut_file(self.mcap_path, self._good_end)
            for t in self._topics.values():         # what is left after the cut, for metadata.yaml
                t.flushed = scan.counts.get(t.channel_id, 0)
            times = [c.end_ns for c in scan.chunks]
            self._ft_max = max(times) if times else None
            self._ft_min = min(c.start_ns for c in scan.chunks) if times else None
            kept = sum(t.flushed for t in self._topics.values())
            span = '' if self._ft_max is None else f' up to t={self._ft_max * 1e-9:.3f} s'
            self._write_metadata(final=False)
            after = f'the bag ends with the {kept} message(s){span} written before it'
        except OSError as exc2:
            after = (f'it could not be closed either ({exc2.strerror or exc2}); the {kept} message(s){span} '
                     'written before are readable by this project\'s tools, `reindex` repairs it')
        self._failure = f'{self.path}: write failed ({exc.strerror or exc}); {after}'
        raise BagError(self._failure) from None

    def _flush_locked(self) -> None:
        self._mcap.flush()
        if self._fsync:
            os.fsync(self._file.fileno())
        self._good_end = self._file.tell()
        for t in self._topics.values():
            t.flushed = t.written
        self._ft_min, self._ft_max = self._t_min, self._t_max
        self._pending = 0
        self._last_flush_t_ns = self._t_max
        self._last_flush_wall = time.monotonic()
        self._write_metadata(final=False)

    def _flush_loop(self) -> None:
        while True:
            with self._lock:
                if self._closed:
                    return
                due = self._last_flush_wall + self.flush_period_s
                if self._pending and time.monotonic() >= due:
                    try:
                        self._flush_or_fail()
                    except BagError:          # disk full etc.: the next write() raises it
                        return
                    due = self._last_flush_wall + self.flush_period_s
            if self._stop.wait(max(0.005, due - time.monotonic())):
                return

    def _bag_info(self, final: bool) -> dict:
        counted = (lambda t: t.written) if final else (lambda t: t.flushed)
        t0, t1 = (self._t_min, self._t_max) if final else (self._ft_min, self._ft_max)
        total = sum(counted(t) for t in self._topics.values())
        start = t0 if (t0 is not None and total) else 0
        dur = (t1 - t0) if (t0 is not None and total) else 0
        return {
            'version': ROSBAG2_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': dur},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': total,
            'topics_with_message_count': [
                {'topic_metadata': {'name': t.name, 'type': t.msg_type, 'serialization_format': 'cdr',
                                    'offered_qos_profiles': [dict(q) for q in t.qos],
                                    'type_description_hash': t.rihs01},
                 'message_count': counted(t)}
                for t in self._topics.values()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.mcap_path.name],
            'files': [{'path': self.mcap_path.name, 'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': dur}, 'message_count': total}],
            'custom_data': dict(self._custom) if self._custom else None,
            'ros_distro': ROS_DISTRO,
        }

    def _write_metadata(self, final: bool) -> None:
        text = _dump_yaml({'rosbag2_bagfile_information': self._bag_info(final)})
        tmp = self.metadata_path.with_name('.metadata.yaml.tmp')
        with open(tmp, 'w') as f:
            f.write(text)
            f.flush()
            if self._fsync:
                os.fsync(f.fileno())
        os.replace(tmp, self.metadata_path)

    def close(self) -> None:
        """Finish the MCAP file (summary, footer) and write the final metadata.yaml. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._stop.set()
            info = _dump_yaml(self._bag_info(final=True))
            try:
                self._mcap.add_metadata('rosbag2', {'serialized_metadata': info, 'ROS_DISTRO': ROS_DISTRO})
                self._mcap.finish()
                self._file.flush()
                if self._fsync:
                    os.fsync(self._file.fileno())
                self._file.close()
                self._write_metadata(final=True)
            except OSError as exc:
                self._closed = False
                self._fail_locked(exc)
        if self._flusher is not threading.current_thread():
            self._flusher.join(timeout=5.0)

    def _check_open(self) -> None:
        if self._failure is not None:
            raise BagError(self._failure)
        if self._closed:
            raise BagError(f'{self.path}: writer is closed')

    @property
    def message_count(self) -> int:
        """Messages written (once a write failed: those the bag kept)."""
        with self._lock:
            return sum((t.flushed if self._failure is not None else t.written) for t in self._topics.values())

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@lru_cache(maxsize=None)
def _type_encoder(msg_type: str) -> _WTopic:
    full = normalize_type_name(msg_type)
    text = message_definition(full)
    return _WTopic('', full, text, '', (), 0, parse_definitions(full, text), encoder_for(full, text))


def encode_message(msg_type: str, msg: Any) -> bytes:
    """CDR bytes of ``msg`` (dict / object / ROS message) as :class:`BagWriter` writes it, without a
    bag (the live view sends the same bytes)."""
    return BagWriter._encode(_type_encoder(msg_type), msg)


def _bag_topic(topic) -> str:
    """The absolute name a bag stores: contract names are relative ('joint_states' -> '/joint_states')."""
    if not isinstance(topic, str) or not contract.topic_key(topic):
        raise BagError(f'invalid topic name {topic!r}: expected a name like "joint_states" or "/joint_states"')
    return contract.bag_topic(topic)
