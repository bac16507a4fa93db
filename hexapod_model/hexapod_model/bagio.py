"""Bag I/O: write and read rosbag2-layout MCAP bags without a running ROS graph.

Layout (what ``ros2 bag record -s mcap`` writes on Jazzy): a directory ``<dir>/`` holding
``metadata.yaml`` (rosbag2 bagfile information, version 9) and ``<dir>_0.mcap`` (profile ``ros2``,
schemas in ``ros2msg`` encoding = the full concatenated ``.msg`` text with its dependencies,
messages CDR-encoded, channel metadata ``offered_qos_profiles`` and ``topic_type_hash``).

Writing (:class:`BagWriter`) is crash safe: the open chunk is closed and the file flushed and
fsync'ed at least every ``flush_period_s`` of message time or wall time, and ``metadata.yaml``
is written at open and rewritten at every flush, so a recording cut off by a crash or power loss
is still a valid rosbag2 directory that loses at most the last flush period.

Reading (:class:`BagReader`) scans the file record by record at open: a bag cut off mid-recording
is read up to its last complete chunk with one :class:`BagWarning`; a corrupt chunk is skipped
with a warning; garbage, empty and missing input raise :class:`BagError` saying what is wrong and
how much was readable. Messages are yielded in log-time order, decoded with the schema stored in
the bag (falling back to the locally installed definition); topics whose type cannot be decoded
are skipped with one warning per topic.

Message definitions come from the installed interface packages (``share/<pkg>/msg/<Name>.msg``
under ``AMENT_PREFIX_PATH``), then from this workspace's source tree (hexapod_msgs), then from an
embedded copy of the standard types the project records (``data/ros_msg_definitions.json``).

No rclpy import at module level: rclpy is used only, when importable, to serialize ROS message
instances handed to :meth:`BagWriter.write`.
"""
from __future__ import annotations

import array as py_array
import heapq
import io
import json
import math
import os
import re
import struct
import threading
import time
import warnings
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Message, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2._dynamic import _for_each_msgdef, generate_dynamic, serialize_dynamic

from hexapod_model import contract

__all__ = [
    'BagError', 'BagWarning', 'MessageEncodeError', 'BagMessage', 'TopicInfo', 'BagWriter',
    'BagReader', 'joint_series', 'message_definition', 'type_hash', 'normalize_type_name',
    'DEFAULT_QOS_PROFILE', 'recover_bag',
]

MCAP_MAGIC = b'\x89MCAP0\r\n'
ROSBAG2_VERSION = 9                 # rosbag2 metadata version written by Jazzy
ROS_DISTRO = 'jazzy'
DELIMITER = '=' * 80 + '\n'         # ros2msg separator between concatenated definitions
_INFINITE_DURATION = {'sec': 9223372036, 'nsec': 854775807}   # rmw "infinite" as rosbag2 dumps it
DEFAULT_QOS_PROFILE: dict = {
    'history': 'keep_last', 'depth': 100, 'reliability': 'reliable', 'durability': 'volatile',
    'deadline': dict(_INFINITE_DURATION), 'lifespan': dict(_INFINITE_DURATION),
    'liveliness': 'automatic', 'liveliness_lease_duration': dict(_INFINITE_DURATION),
    'avoid_ros_namespace_conventions': False,
}
_EMBEDDED_PATH = Path(__file__).resolve().parent / 'data' / 'ros_msg_definitions.json'
# Source tree fallback for this workspace's own interfaces (hexapod_msgs/msg/*.msg).
_WORKSPACE_ROOT = Path(__file__).resolve().parents[2]


class BagError(RuntimeError):
    """The bag cannot be read or written (missing, empty, garbage, corrupt, bad input)."""


class BagWarning(UserWarning):
    """Part of a bag was unreadable (truncated tail, corrupt chunk, undecodable topic)."""


class MessageEncodeError(ValueError):
    """A message handed to :meth:`BagWriter.write` does not match its message definition."""


class BagMessage(NamedTuple):
    topic: str
    msg_type: str
    t_ns: int          # MCAP log time [ns] (receive/record time)
    msg: Any           # decoded message (attribute access) or CDR bytes with ``raw=True``


@dataclass(frozen=True)
class TopicInfo:
    name: str
    msg_type: str
    message_count: int                  # messages readable in the bag
    offered_qos_profiles: tuple = ()    # list of QoS dicts as in metadata.yaml (version 9)
    type_description_hash: str = ''     # RIHS01_... or ''


# --------------------------------------------------------------------------------- definitions --

_TYPE_RE = re.compile(r'^([A-Za-z][A-Za-z0-9_]*)/(?:(msg)/)?([A-Za-z][A-Za-z0-9_]*)$')
# rosbag2 (LocalMessageDefinitionSource): field types at line starts of a .msg text.
_MSG_FIELD_TYPE_RE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16',
                         'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'})


def normalize_type_name(msg_type: str) -> str:
    """``pkg/Name`` or ``pkg/msg/Name`` -> ``pkg/msg/Name``; anything else is a clear error."""
    if not isinstance(msg_type, str):
        raise BagError(f'message type must be a string like "sensor_msgs/msg/JointState", got {msg_type!r}')
    m = _TYPE_RE.match(msg_type.strip())
    if not m:
        raise BagError(f'invalid message type {msg_type!r}: expected "package/msg/Name" '
                       '(e.g. "sensor_msgs/msg/JointState")')
    return f'{m.group(1)}/msg/{m.group(3)}'


@lru_cache(maxsize=1)
def _embedded() -> dict:
    try:
        return json.loads(_EMBEDDED_PATH.read_text())['types']
    except (OSError, ValueError, KeyError):
        return {}


def _share_dirs(package: str) -> list[Path]:
    dirs = []
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / 'share' / package)
    dirs.append(_WORKSPACE_ROOT / package)          # source tree (e.g. hexapod_msgs/msg/*.msg)
    return dirs


@lru_cache(maxsize=None)
def _local_msg_file(msg_type: str) -> tuple[str, str] | None:
    """(text, origin) of the ``.msg`` file of a type, searched as documented in the module doc."""
    pkg, _, name = normalize_type_name(msg_type).split('/')
    for d in _share_dirs(pkg):
        f = d / 'msg' / f'{name}.msg'
        if f.is_file():
            return f.read_text(), str(f)
    emb = _embedded().get(f'{pkg}/msg/{name}')
    if emb is not None:
        return emb['msg'], f'embedded copy ({_EMBEDDED_PATH.name})'
    return None


@lru_cache(maxsize=None)
def type_hash(msg_type: str) -> str:
    """RIHS01 type description hash of a locally known type ('' if unknown)."""
    full = normalize_type_name(msg_type)
    pkg, _, name = full.split('/')
    for d in _share_dirs(pkg):
        f = d / 'msg' / f'{name}.json'
        if f.is_file():
            try:
                for entry in json.loads(f.read_text()).get('type_hashes', []):
                    if entry.get('type_name') == full:
                        return str(entry.get('hash_string', ''))
            except ValueError:
                pass
    emb = _embedded().get(full)
    return emb['rihs01'] if emb else ''


def _msg_dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for m in _MSG_FIELD_TYPE_RE.finditer(text):
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        deps.add(t if '/' in t else f'{package}/{t}')
    return sorted(deps)


@lru_cache(maxsize=None)
def message_definition(msg_type: str) -> str:
    """The complete ``ros2msg`` definition of a type exactly as rosbag2 stores it: the type's own
    ``.msg`` text, then for each dependency (depth first, sorted, each once) a line of 80 ``=``,
    ``MSG: pkg/Name`` and its text. Raises :class:`BagError` naming the missing definition."""
    root = normalize_type_name(msg_type)
    seen: set[str] = set()

    def load(t: str) -> tuple[str, str]:
        found = _local_msg_file(t)
        if found is None:
            raise BagError(
                f'no message definition for {t} (needed by {root}): not found in any '
                f'share/<pkg>/msg of AMENT_PREFIX_PATH, the workspace source tree or the embedded '
                f'standard types; source the ROS environment or pass definition= to add_topic()')
        return found[0], t.split('/')[0]

    def append(t: str, depth: int) -> str:
        if depth <= 0:
            raise BagError(f'message definition of {root} nests too deeply (cyclic?)')
        text, pkg = load(t)
        out = text
        for dep in _msg_dependencies(text, pkg):
            if dep not in seen:
                seen.add(dep)
                out += '\n' + DELIMITER + f'MSG: {dep}\n' + append(dep, depth - 1)
        return out

    return append(root, 50)


def _parse_definitions(msg_type: str, text: str) -> dict:
    """{'pkg/Name': MessageSpecification} for a concatenated definition (mcap_ros2's parser)."""
    specs: dict = {}

    def collect(name, short, spec):
        specs[short] = spec

    _for_each_msgdef(msg_type, text, collect)
    pkg, _, name = normalize_type_name(msg_type).split('/')
    if f'{pkg}/{name}' not in specs:
        raise BagError(f'definition text does not define {msg_type}')
    return specs


# ------------------------------------------------------------------------- message conversion --

_INT_RANGES = {
    'bool': None, 'byte': (0, 255), 'char': (0, 255), 'uint8': (0, 255), 'int8': (-128, 127),
    'uint16': (0, 2**16 - 1), 'int16': (-2**15, 2**15 - 1), 'uint32': (0, 2**32 - 1),
    'int32': (-2**31, 2**31 - 1), 'uint64': (0, 2**64 - 1), 'int64': (-2**63, 2**63 - 1),
}
_FLOAT_TYPES = frozenset({'float32', 'float64'})
_MISSING = object()


def _scalar(value: Any, tname: str, path: str) -> Any:
    if isinstance(value, np.generic):
        value = value.item()
    if tname in _FLOAT_TYPES:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise MessageEncodeError(f'{path}: expected {tname}, got {value!r} ({type(value).__name__})')
        return float(value)
    if tname == 'bool':
        if not isinstance(value, (bool, int)) or (not isinstance(value, bool) and value not in (0, 1)):
            raise MessageEncodeError(f'{path}: expected bool, got {value!r} ({type(value).__name__})')
        return bool(value)
    if tname in _INT_RANGES:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                value = int(value)
            else:
                raise MessageEncodeError(f'{path}: expected {tname}, got {value!r} ({type(value).__name__})')
        lo, hi = _INT_RANGES[tname]
        if not lo <= value <= hi:
            raise MessageEncodeError(f'{path}: {value} out of range for {tname} [{lo}, {hi}]')
        return value
    if tname in ('string', 'wstring'):
        if not isinstance(value, str):
            raise MessageEncodeError(f'{path}: expected string, got {value!r} ({type(value).__name__})')
        return value
    raise MessageEncodeError(f'{path}: unsupported primitive type {tname}')


def _field_names(spec) -> list[str]:
    return [f.name for f in spec.fields]


def _normalize(msg: Any, spec, specs: dict, path: str) -> dict:
    """Validate ``msg`` (dict or object with attributes) against ``spec``; return a plain dict of
    Python scalars/lists/bytes that the CDR encoder accepts. Errors name the offending field."""
    names = _field_names(spec)
    if isinstance(msg, Mapping):
        unknown = [k for k in msg if k not in names]
        if unknown:
            raise MessageEncodeError(
                f'{path}: unknown field(s) {unknown} (fields of this type: {names})')

        def get(n):
            return msg.get(n, _MISSING)
    elif msg is None:
        def get(n):
            return _MISSING
    else:
        def get(n):
            return getattr(msg, n, _MISSING)
    out = {}
    for f in spec.fields:
        ft = f.type
        v = get(f.name)
        fpath = f'{path}.{f.name}'
        if v is _MISSING or v is None:
            # Absent field: ROS default (empty sequence, default-constructed nested message, the
            # definition's default value for primitives; the encoder fills omitted primitives).
            if ft.is_array and ft.is_fixed_size_array() and not ft.is_primitive_type():
                out[f.name] = [{} for _ in range(ft.array_size)]
            elif ft.is_array and not ft.is_fixed_size_array():
                out[f.name] = []
            elif not ft.is_array and not ft.is_primitive_type():
                out[f.name] = {}
            continue
        if ft.is_array:
            if isinstance(v, (bytes, bytearray)) and ft.type in ('uint8', 'byte', 'char'):
                items = list(v)
            elif isinstance(v, np.ndarray):
                items = v.tolist()
            elif isinstance(v, (list, tuple, py_array.array)):
                items = list(v)
            else:
                raise MessageEncodeError(f'{fpath}: expected a sequence for {ft}, got '
                                         f'{type(v).__name__}')
            n = len(items)
            if ft.is_fixed_size_array() and n != ft.array_size:
                raise MessageEncodeError(f'{fpath}: expected exactly {ft.array_size} elements, got {n}')
            if ft.is_upper_bound and ft.array_size is not None and n > ft.array_size:
                raise MessageEncodeError(f'{fpath}: at most {ft.array_size} elements allowed, got {n}')
            if ft.is_primitive_type():
                conv = [_scalar(x, ft.type, f'{fpath}[{i}]') for i, x in enumerate(items)]
                out[f.name] = bytes(conv) if ft.type in ('uint8', 'byte', 'char') else conv
            else:
                sub = specs.get(f'{ft.pkg_name}/{ft.type}')
                if sub is None:
                    raise MessageEncodeError(f'{fpath}: no definition for {ft.pkg_name}/{ft.type}')
                out[f.name] = [_normalize(x, sub, specs, f'{fpath}[{i}]') for i, x in enumerate(items)]
        elif ft.is_primitive_type():
            val = _scalar(v, ft.type, fpath)
            if ft.type == 'string' and ft.string_upper_bound is not None and len(val) > ft.string_upper_bound:
                raise MessageEncodeError(f'{fpath}: string longer than {ft.string_upper_bound}')
            out[f.name] = val
        else:
            sub = specs.get(f'{ft.pkg_name}/{ft.type}')
            if sub is None:
                raise MessageEncodeError(f'{fpath}: no definition for {ft.pkg_name}/{ft.type}')
            out[f.name] = _normalize(v, sub, specs, fpath)
    return out


def _ros_message_type(msg: Any) -> str | None:
    """'pkg/msg/Name' if ``msg`` is an instance of a generated rclpy message class."""
    cls = type(msg)
    if not hasattr(cls, 'get_fields_and_field_types') or not hasattr(cls, '_TYPE_SUPPORT'):
        return None
    parts = cls.__module__.split('.')
    if len(parts) < 2:
        return None
    return f'{parts[0]}/{parts[1]}/{cls.__name__}'


class _NoAliasDumper(yaml.SafeDumper):
    """YAML without &anchors/*aliases (rosbag2 metadata never uses them)."""

    def ignore_aliases(self, data):
        return True


def _dump_yaml(obj: Any) -> str:
    return yaml.dump(obj, Dumper=_NoAliasDumper, default_flow_style=False, sort_keys=False)


def _qos_yaml(profiles: Sequence[Mapping]) -> str:
    return _dump_yaml([dict(p) for p in profiles]).strip()


# ------------------------------------------------------------------------------------- writer --

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
        self.path.mkdir(parents=True, exist_ok=True)
        self.mcap_path = self.path / f'{self.path.name}_0.mcap'
        self.metadata_path = self.path / 'metadata.yaml'
        self.flush_period_s = float(flush_period_s)
        self._period_ns = int(round(self.flush_period_s * 1e9))
        self._fsync = fsync
        self._custom = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._lock = threading.RLock()
        self._file = open(self.mcap_path, 'wb')
        self._mcap = McapWriter(self._file, chunk_size=chunk_size, compression=comp)
        self._mcap.start(profile='ros2', library='hexapod_model.bagio (mcap-python)')
        self._schemas: dict[str, int] = {}
        self._topics: dict[str, _WTopic] = {}
        self._t_min = self._t_max = None            # over all written messages
        self._ft_min = self._ft_max = None          # over flushed messages
        self._pending = 0
        self._last_flush_t_ns: int | None = None
        self._last_flush_wall = time.monotonic()
        self._closed = False
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
        if not isinstance(topic, str) or not topic.startswith('/') or len(topic) < 2:
            raise BagError(f'invalid topic name {topic!r}: expected an absolute name like "/joint_states"')
        full = normalize_type_name(msg_type)
        if topic in self._topics:
            have = self._topics[topic]
            if have.msg_type != full:
                raise BagError(f'topic {topic} is already recorded as {have.msg_type}, cannot also '
                               f'write {full} on it')
            return have
        text = definition if definition is not None else message_definition(full)
        try:
            specs = _parse_definitions(full, text)
            encoder = serialize_dynamic(full, text)[full]
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
        return self._encode(_WTopic('', full, text, '', (), 0, _parse_definitions(full, text),
                                    serialize_dynamic(full, text)[full]), msg)

    def _encode(self, t: _WTopic, msg: Any) -> bytes:
        if isinstance(msg, (bytes, bytearray, memoryview)):
            data = bytes(msg)
            if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
                raise MessageEncodeError(f'{t.name or t.msg_type}: bytes given but they do not start '
                                         'with a CDR encapsulation header (00 00 / 00 01)')
            return data
        ros_type = _ros_message_type(msg)
        if ros_type is not None:
            if ros_type != t.msg_type:
                raise MessageEncodeError(f'{t.name or t.msg_type}: got a {ros_type} message for a '
                                         f'topic of type {t.msg_type}')
            # Encoded field by field like a dict, never with rclpy.serialization: on Jazzy/Fast-CDR
            # its output carries uninitialised padding after the message (e.g. 8 bytes after a
            # JointState), which readers that check the CDR size (rosbags) reject.
        pkg, _, name = t.msg_type.split('/')
        plain = _normalize(msg, t.specs[f'{pkg}/{name}'], t.specs, t.msg_type)
        try:
            return t.encoder(plain)
        except Exception as exc:
            raise MessageEncodeError(f'{t.msg_type}: cannot encode message: {exc}') from exc

    def write(self, topic: str, msg_type: str, msg: Any, t_ns: int) -> None:
        if isinstance(t_ns, np.integer):
            t_ns = int(t_ns)
        if isinstance(t_ns, bool) or not isinstance(t_ns, int) or not 0 <= t_ns < 2**63:
            raise BagError(f'{topic}: t_ns must be a non-negative integer time in nanoseconds, got {t_ns!r}')
        with self._lock:
            self._check_open()
            t = self._topics.get(topic)
            if t is None:
                t = self._add_topic_locked(topic, msg_type, None, None)
            elif msg_type != t.msg_type and normalize_type_name(msg_type) != t.msg_type:
                raise BagError(f'topic {topic} is recorded as {t.msg_type}, cannot write {msg_type} on it')
            data = self._encode(t, msg)
            self._mcap.add_message(channel_id=t.channel_id, log_time=t_ns, publish_time=t_ns, data=data)
            t.written += 1
            self._pending += 1
            self._t_min = t_ns if self._t_min is None else min(self._t_min, t_ns)
            self._t_max = t_ns if self._t_max is None else max(self._t_max, t_ns)
            if self._last_flush_t_ns is None:
                self._last_flush_t_ns = t_ns
            if (t_ns - self._last_flush_t_ns >= self._period_ns
                    or time.monotonic() - self._last_flush_wall >= self.flush_period_s):
                self._flush_locked()

    def flush(self) -> None:
        """Close the open chunk, flush + fsync the file and rewrite metadata.yaml now."""
        with self._lock:
            self._check_open()
            self._flush_locked()

    def _flush_locked(self) -> None:
        self._mcap.flush()
        if self._fsync:
            os.fsync(self._file.fileno())
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
                        self._flush_locked()
                    except OSError as exc:    # disk full etc.: report, keep recording
                        warnings.warn(f'{self.path}: periodic flush failed: {exc}', BagWarning)
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
            self._mcap.add_metadata('rosbag2', {'serialized_metadata': info, 'ROS_DISTRO': ROS_DISTRO})
            self._mcap.finish()
            self._file.flush()
            if self._fsync:
                os.fsync(self._file.fileno())
            self._file.close()
            self._write_metadata(final=True)
        if self._flusher is not threading.current_thread():
            self._flusher.join(timeout=5.0)

    def _check_open(self) -> None:
        if self._closed:
            raise BagError(f'{self.path}: writer is closed')

    @property
    def message_count(self) -> int:
        with self._lock:
            return sum(t.written for t in self._topics.values())

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# ------------------------------------------------------------------------------------- reader --

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


def _scan_file(path: Path, file_idx: int) -> _FileScan:
    """Walk every record of one MCAP file; stop at the first broken/truncated record."""
    try:
        size = path.stat().st_size
        f = open(path, 'rb')
    except OSError as exc:
        raise BagError(f'{path}: cannot open: {exc.strerror or exc}') from exc
    scan = _FileScan(path, size)
    with f:
        head = f.read(len(MCAP_MAGIC))
        if size == 0:
            raise BagError(f'{path}: file is empty (0 bytes): no data was ever written to this bag')
        if head != MCAP_MAGIC:
            if MCAP_MAGIC.startswith(head):
                raise BagError(f'{path}: truncated to {size} bytes, before the end of the MCAP magic; '
                               'nothing is readable')
            raise BagError(f'{path}: not an MCAP file (starts with {head[:8]!r}, expected the MCAP '
                           f'magic {MCAP_MAGIC!r}); nothing is readable')
        pos = len(MCAP_MAGIC)
        scan.readable_bytes = pos
        while pos < size:
            if size - pos < 9:
                scan.problems.append(f'truncated at byte {size}: {size - pos} trailing byte(s) of an '
                                     'incomplete record header')
                break
            f.seek(pos)
            op, length = struct.unpack('<BQ', f.read(9))
            if op not in _KNOWN_OPCODES and op < 0x80:
                scan.problems.append(f'corrupt data at byte {pos}: invalid record opcode 0x{op:02x}; '
                                     f'the remaining {size - pos} bytes are unreadable')
                break
            if pos + 9 + length > size:
                scan.problems.append(
                    f'truncated at byte {size}: the {_opname(op)} record starting at byte {pos} needs '
                    f'{9 + length} bytes but only {size - pos} remain')
                break
            body = f.read(length)
            try:
                rec = None
                stream = ReadDataStream(io.BytesIO(body))
                if op == Opcode.CHUNK:
                    chunk = Chunk.read(stream)
                    try:
                        msgs, n = _collect_chunk_records(chunk, scan)
                    except Exception as exc:      # bad compression / CRC / inner framing
                        scan.problems.append(f'corrupt chunk at byte {pos} ({exc}); its messages are '
                                             'skipped')
                    else:
                        if n:
                            scan.chunks.append(_ChunkRef(file_idx, pos, 9 + length,
                                                         chunk.message_start_time, chunk.message_end_time, n))
                            for m in msgs:
                                scan.counts[m.channel_id] = scan.counts.get(m.channel_id, 0) + 1
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


def _load_chunk(fh, ref: _ChunkRef) -> list[Message]:
    fh.seek(ref.offset + 9)
    chunk = Chunk.read(ReadDataStream(io.BytesIO(fh.read(ref.length - 9))))
    return [r for r in breakup_chunk(chunk, validate_crc=True) if isinstance(r, Message)]


class BagReader:
    """Read a rosbag2 directory or a single ``.mcap`` file.

    Everything is checked at open: :class:`BagError` if nothing is readable (missing path, empty
    or garbage file, no messages); one :class:`BagWarning` per problem otherwise (truncated tail
    -> read up to the last complete chunk; corrupt chunk -> skipped; topic whose message type
    cannot be decoded -> skipped by :meth:`messages` unless ``raw=True``). ``warnings`` lists them.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
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
        if meta_file.is_file():
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
                return generate_dynamic(schema.name, schema.data.decode())[schema.name], ''
            except Exception as exc:
                reasons.append(f'its stored ros2msg schema does not parse ({exc})')
        elif schema is not None and schema.data:
            reasons.append(f'its stored schema is in {schema.encoding!r}, not ros2msg')
        else:
            reasons.append('the bag stores no schema for it')
        try:
            text = message_definition(msg_type)
            dec = generate_dynamic(msg_type, text)[msg_type]
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

    @property
    def message_count(self) -> int:
        return sum(i.message_count for i in self._topics.values())

    @property
    def complete(self) -> bool:
        """True if every file ended with a valid footer and nothing had to be skipped."""
        return all(s.complete for s in self._scans) and not self.warnings

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
        wanted = None if topics is None else set(topics)     # topics absent from the bag: none yielded
        lo = -1 if start_ns is None else int(start_ns)
        hi = 2**64 if end_ns is None else int(end_ns)
        decode_failed: dict[str, int] = {}

        def accept(file_idx: int, m: Message):
            key = (file_idx, m.channel_id)
            ch = self._chan.get(key)
            if ch is None or not lo <= m.log_time < hi:
                return None
            if wanted is not None and ch[0] not in wanted:
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


def recover_bag(src: str | os.PathLike, dst: str | os.PathLike, **writer_kw) -> int:
    """Copy every readable message of ``src`` (e.g. a recording cut off by a crash, which other
    tools such as rosbags refuse without its MCAP footer) into a new, properly closed bag ``dst``.
    Topic definitions and QoS are taken from ``src``. Returns the number of messages copied."""
    reader = BagReader(src)
    n = 0
    with BagWriter(dst, **writer_kw) as w:
        for topic, info in reader.topic_info().items():
            w.add_topic(topic, info.msg_type, definition=reader.schema_text(topic),
                        qos_profiles=list(info.offered_qos_profiles) or None)
        for topic, msg_type, t_ns, data in reader.messages(raw=True):
            w.write(topic, msg_type, data, t_ns)
            n += 1
    return n


# ------------------------------------------------------------------------------------ helpers --

def _stamp_s(msg: Any) -> float:
    st = msg.header.stamp
    return float(st.sec) + 1e-9 * float(st.nanosec)


def joint_series(reader: BagReader, log_time: bool = False) -> dict[str, dict[str, np.ndarray]]:
    """Per-joint position series of ``/joint_commands`` and ``/joint_states``.

    Returns ``{topic: {joint_name: array (N, 2)}}`` with columns (header.stamp [s], position
    [rad]), sorted by stamp (stable). ``log_time=True`` adds a third column, the bag's log
    (record) time [s], so a stamp that disagrees with when the message was recorded can be found.
    A topic absent from the bag maps to ``{}``. A message whose ``position`` is shorter than its
    ``name`` list raises :class:`BagError` naming it.
    """
    topics = (contract.JOINT_COMMANDS, contract.JOINT_STATES)
    present = [t for t in topics if t in reader.topics()]
    for t in present:
        if reader.topics()[t] != contract.MSG_TYPES[t]:
            raise BagError(f'{t} is recorded as {reader.topics()[t]}, expected {contract.MSG_TYPES[t]}')
    acc: dict[str, dict[str, list]] = {t: {} for t in topics}
    for topic, _, t_ns, msg in reader.messages(topics=present or None) if present else ():
        names = list(msg.name)
        pos = list(msg.position)
        if len(pos) < len(names):
            raise BagError(f'{topic} message at t={t_ns} ns names {len(names)} joint(s) but has '
                           f'{len(pos)} position(s)')
        stamp = _stamp_s(msg)
        series = acc[topic]
        for n, p in zip(names, pos):
            series.setdefault(n, []).append((stamp, p, t_ns * 1e-9) if log_time else (stamp, p))
    out: dict[str, dict[str, np.ndarray]] = {}
    for topic, series in acc.items():
        out[topic] = {}
        for n, rows in series.items():
            a = np.asarray(rows, dtype=float).reshape(-1, 3 if log_time else 2)
            out[topic][n] = a[np.argsort(a[:, 0], kind='stable')]
    return out
