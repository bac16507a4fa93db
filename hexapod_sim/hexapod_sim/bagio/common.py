"""What every part of the bag I/O shares: errors, the records it yields, rosbag2 constants."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

MCAP_MAGIC = b'\x89MCAP0\r\n'
ROSBAG2_VERSION = 9                 # rosbag2 metadata version written by Jazzy
ROS_DISTRO = 'jazzy'
_INFINITE_DURATION = {'sec': 9223372036, 'nsec': 854775807}   # rmw "infinite" as rosbag2 dumps it
DEFAULT_QOS_PROFILE: dict = {
    'history': 'keep_last', 'depth': 100, 'reliability': 'reliable', 'durability': 'volatile',
    'deadline': dict(_INFINITE_DURATION), 'lifespan': dict(_INFINITE_DURATION),
    'liveliness': 'automatic', 'liveliness_lease_duration': dict(_INFINITE_DURATION),
    'avoid_ros_namespace_conventions': False,
}


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


def one_warning(problems) -> str | None:
    """The problems a reader found as the one warning line a tool prints (None if there are none)."""
    problems = [' '.join(str(p).split()) for p in problems]
    if not problems:
        return None
    more = len(problems) - 1
    return problems[0] + (f' (and {more} more problem(s) of this kind or others)' if more else '')
