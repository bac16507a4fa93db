"""Messages to and from CDR: a dict / object / rclpy message is checked field by field against its
definition and encoded; stored schemas become decoders.

Decoding uses mcap_ros2's public :class:`mcap_ros2.decoder.DecoderFactory`. Parsing a definition
into field specifications and encoding have no public API in mcap_ros2 (its ``Writer`` only writes
whole MCAP files, with its own chunking, and this project's writer needs its own crash-safe
flushing), so those two calls use ``mcap_ros2._dynamic``; they are confined to this module and the
mcap-ros2-support version is pinned exactly in requirements/py.txt.
"""
from __future__ import annotations

import array as py_array
from collections.abc import Mapping
from typing import Any

import numpy as np
from mcap.records import Schema
from mcap_ros2._dynamic import _for_each_msgdef, serialize_dynamic
from mcap_ros2.decoder import DecoderFactory

from hexapod_sim.bagio.common import BagError, MessageEncodeError
from hexapod_sim.bagio.definitions import normalize_type_name


def parse_definitions(msg_type: str, text: str) -> dict:
    """{'pkg/Name': MessageSpecification} for a concatenated definition (mcap_ros2's parser)."""
    specs: dict = {}

    def collect(name, short, spec):
        specs[short] = spec

    _for_each_msgdef(msg_type, text, collect)
    pkg, _, name = normalize_type_name(msg_type).split('/')
    if f'{pkg}/{name}' not in specs:
        raise BagError(f'definition text does not define {msg_type}')
    return specs


def encoder_for(msg_type: str, text: str):
    """A function plain message dict -> CDR bytes for ``msg_type`` (full name) defined by ``text``."""
    return serialize_dynamic(msg_type, text)[msg_type]


def decoder_for(msg_type: str, text: str):
    """A function CDR bytes -> message (attribute access) for ``msg_type`` defined by ``text``."""
    import contextlib
    import io
    with contextlib.redirect_stderr(io.StringIO()):   # its parser prints each bad line of a damaged schema
        decoder = DecoderFactory().decoder_for('cdr', Schema(id=1, name=msg_type, encoding='ros2msg',
                                                             data=text.encode()))
    if decoder is None:
        raise BagError(f'no CDR decoder for {msg_type}')
    return decoder


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


def normalize(msg: Any, spec, specs: dict, path: str) -> dict:
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
                out[f.name] = [normalize(x, sub, specs, f'{fpath}[{i}]') for i, x in enumerate(items)]
        elif ft.is_primitive_type():
            val = _scalar(v, ft.type, fpath)
            if ft.type == 'string' and ft.string_upper_bound is not None and len(val) > ft.string_upper_bound:
                raise MessageEncodeError(f'{fpath}: string longer than {ft.string_upper_bound}')
            out[f.name] = val
        else:
            sub = specs.get(f'{ft.pkg_name}/{ft.type}')
            if sub is None:
                raise MessageEncodeError(f'{fpath}: no definition for {ft.pkg_name}/{ft.type}')
            out[f.name] = normalize(v, sub, specs, fpath)
    return out


def ros_message_type(msg: Any) -> str | None:
    """'pkg/msg/Name' if ``msg`` is an instance of a generated rclpy message class."""
    cls = type(msg)
    if not hasattr(cls, 'get_fields_and_field_types') or not hasattr(cls, '_TYPE_SUPPORT'):
        return None
    parts = cls.__module__.split('.')
    if len(parts) < 2:
        return None
    return f'{parts[0]}/{parts[1]}/{cls.__name__}'
