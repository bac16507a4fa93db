"""Message definitions: the full concatenated ``.msg`` text of a type and its RIHS01 type hash.

Looked up in the installed interface packages (``share/<pkg>/msg/<Name>.msg`` under
``AMENT_PREFIX_PATH``), then in this workspace's source tree (hexapod_msgs), then in an embedded
copy of the standard types the project records (``hexapod_sim/data/ros_msg_definitions.json``).
"""
from __future__ import annotations

import json
import os
import re
from functools import lru_cache
from pathlib import Path

from hexapod_sim.bagio.common import BagError

DELIMITER = '=' * 80 + '\n'         # ros2msg separator between concatenated definitions
_EMBEDDED_PATH = Path(__file__).resolve().parents[1] / 'data' / 'ros_msg_definitions.json'
# Source tree fallback for this workspace's own interfaces (hexapod_msgs/msg/*.msg).
_WORKSPACE_ROOT = Path(__file__).resolve().parents[3]

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
