"""Replay a recorded bag on ROS 2 with its recorded timing, as ``ros2 bag play`` would.

    ./hexapod replay BAG [--rate R] [--loop] [--topics T ...] [--start S] [--duration D]
                         [--clock [HZ]] [--delay S] [--wait-for-subscribers S] [--qos-depth N]
    ros2 run hexapod_sim replay BAG ...

BAG is a rosbag2 directory or a single ``.mcap`` file (read with :mod:`hexapod_sim.bagio`:
a truncated bag plays up to its last complete chunk, with a warning). Each message is published
as its recorded CDR bytes (``Publisher.publish(bytes)``) on a publisher created from the installed
ROS message class, so the content is bit-identical to the recording. Topics whose type is not
installed here, or whose installed definition differs from the recorded one (type hash), are
skipped with one warning each. Timing: message i is due at ``wall0 + (t_i - t_begin) / rate`` on
the monotonic clock (absolute deadlines, no drift accumulation); ``--clock HZ`` publishes the bag
time on ``/clock`` at HZ (wall) so nodes with ``use_sim_time:=true`` follow the recording.
"""
from __future__ import annotations

import argparse
import importlib
import statistics
import sys
import time
import warnings
from dataclasses import dataclass, field
from typing import Callable

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

from hexapod_model import contract
from hexapod_sim.bagio import BagError, BagReader, BagWarning, one_warning, type_hash

try:
    from tqdm import tqdm
except ImportError:     # progress display is optional
    tqdm = None


# ------------------------------------------------------------------------------- pure helpers --

def message_class(msg_type: str):
    """(class, '') for an installed ROS message type 'pkg/msg/Name', else (None, reason)."""
    try:
        pkg, ns, name = msg_type.split('/')
    except ValueError:
        return None, f'{msg_type!r} is not a "package/msg/Name" type name'
    try:
        module = importlib.import_module(f'{pkg}.{ns}')
    except ImportError:
        return None, f'package {pkg} is not installed here'
    cls = getattr(module, name, None)
    if cls is None:
        return None, f'{pkg}.{ns} has no message {name}'
    return cls, ''


def playback_window(reader: BagReader, start_s: float, duration_s: float | None) -> tuple[int, int]:
    """[begin, end) in bag time [ns]: ``start_s`` after the first message, ``duration_s`` long."""
    if start_s < 0:
        raise ValueError(f'--start must be >= 0 s, got {start_s}')
    if duration_s is not None and duration_s <= 0:
        raise ValueError(f'--duration must be > 0 s, got {duration_s}')
    begin = reader.start_ns + int(round(start_s * 1e9))
    if begin > reader.end_ns:
        raise ValueError(f'--start {start_s} s is past the end of the bag '
                         f'({(reader.end_ns - reader.start_ns) / 1e9:.3f} s long)')
    end = reader.end_ns + 1 if duration_s is None else begin + int(round(duration_s * 1e9))
    return begin, end


class Pacer:
    """Maps bag time to monotonic wall deadlines: ``wall0 + (t_ns - bag0_ns) / 1e9 / rate``."""

    def __init__(self, bag0_ns: int, rate: float, wall0: float,
                 now: Callable[[], float] = time.monotonic):
        if not rate > 0:
            raise ValueError(f'rate must be > 0, got {rate}')
        self.bag0_ns, self.rate, self.wall0, self.now = bag0_ns, float(rate), float(wall0), now

    def deadline(self, t_ns: int) -> float:
        return self.wall0 + (t_ns - self.bag0_ns) * 1e-9 / self.rate

    def bag_time(self, wall: float) -> int:
        return self.bag0_ns + int(round((wall - self.wall0) * self.rate * 1e9))


@dataclass
class ReplayStats:
    published: dict = field(default_factory=dict)       # topic -> count
    clock_published: int = 0
    loops: int = 0
    lateness_s: list = field(default_factory=list)      # publish time - deadline, per message
    wall_s: float = 0.0

    @property
    def total(self) -> int:
        return sum(self.published.values())


# -------------------------------------------------------------------------------------- node --

_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE, 'best_effort': ReliabilityPolicy.BEST_EFFORT,
                1: ReliabilityPolicy.RELIABLE, 2: ReliabilityPolicy.BEST_EFFORT}
_DURABILITY = {'volatile': DurabilityPolicy.VOLATILE, 'transient_local': DurabilityPolicy.TRANSIENT_LOCAL,
               1: DurabilityPolicy.TRANSIENT_LOCAL, 2: DurabilityPolicy.VOLATILE}


def _qos_for(profiles, depth: int) -> QoSProfile:
    p = profiles[0] if profiles else {}
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=_RELIABILITY.get(p.get('reliability'), ReliabilityPolicy.RELIABLE),
                      durability=_DURABILITY.get(p.get('durability'), DurabilityPolicy.VOLATILE))


class BagPlayer(Node):
    """Publishes a bag's messages on their recorded topics with their recorded timing."""

    def __init__(self, reader: BagReader, *, topics=None, rate: float = 1.0, start_s: float = 0.0,
                 duration_s: float | None = None, loop: bool = False, clock_hz: float = 0.0,
                 qos_depth: int = 100, progress: bool = False, context=None):
        super().__init__('bag_player', context=context)
        if not rate > 0:
            raise ValueError(f'--rate must be > 0, got {rate}')
        if clock_hz < 0:
            raise ValueError(f'--clock must be >= 0 Hz, got {clock_hz}')
        if qos_depth < 1:
            raise ValueError(f'--qos-depth must be >= 1, got {qos_depth}')
        self.reader, self.rate, self.loop = reader, float(rate), loop
        self.clock_hz, self.progress = float(clock_hz), progress
        self.begin_ns, self.end_ns = playback_window(reader, start_s, duration_s)
        infos = reader.topic_info()
        if topics:
            unknown = sorted(set(topics) - set(infos))
            if unknown:
                raise ValueError(f'topic(s) {unknown} not in the bag; it has {sorted(infos)}')
        selected = list(topics) if topics else list(infos)
        self._bag_pubs = {}
        self.skipped: dict[str, str] = {}
        for topic in selected:
            info = infos[topic]
            if clock_hz and contract.topic_key(topic) == contract.topic_key(contract.CLOCK):
                self._skip(topic, f'recorded {topic} is not replayed because --clock publishes the '
                                  'playback clock')
                continue
            cls, why = message_class(info.msg_type)
            if cls is None:
                self._skip(topic, f'message type {info.msg_type} unknown here ({why})')
                continue
            local = type_hash(info.msg_type)
            if info.type_description_hash and local and info.type_description_hash != local:
                self._skip(topic, f'recorded {info.msg_type} definition (hash '
                                  f'{info.type_description_hash}) differs from the installed one ({local})')
                continue
            self._bag_pubs[topic] = self.create_publisher(
                cls, topic, _qos_for(info.offered_qos_profiles, qos_depth))
        if not self._bag_pubs:
            raise ValueError('no playable topic in the bag' + (f' ({self.skipped})' if self.skipped else ''))
        self._clock_pub = None
        if clock_hz:
            from rosgraph_msgs.msg import Clock
            self._clock_cls = Clock
            self._clock_pub = self.create_publisher(Clock, contract.CLOCK, 10)

    def _skip(self, topic: str, why: str) -> None:
        self.skipped[topic] = why
        self.get_logger().warning(f'skipping {topic}: {why}')

    @property
    def playable_topics(self) -> list[str]:
        return list(self._bag_pubs)

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Wait (wall) until every publisher has at least one subscriber; False on timeout."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and self.context.ok():
            if all(p.get_subscription_count() > 0 for p in self._bag_pubs.values()):
                return True
            time.sleep(0.01)
        return False

    def _sleep_until(self, deadline: float) -> bool:
        """Sleep in slices so a shutdown is noticed within 50 ms; False if shut down."""
        while True:
            if not self.context.ok():
                return False
            rem = deadline - time.monotonic()
            if rem <= 0:
                return True
            time.sleep(min(rem, 0.05))

    def _publish_clock(self, bag_ns: int, stats: ReplayStats) -> None:
        msg = self._clock_cls()
        msg.clock.sec, msg.clock.nanosec = contract.stamp_parts_ns(bag_ns)
        self._clock_pub.publish(msg)
        stats.clock_published += 1

    def play(self) -> ReplayStats:
        stats = ReplayStats(published={t: 0 for t in self._bag_pubs})
        count = sum(self.reader.topic_info()[t].message_count for t in self._bag_pubs)
        bar = tqdm(total=count, unit='msg', desc='replay', disable=not (self.progress and tqdm)) \
            if tqdm else None
        t_start = time.monotonic()
        wall0 = t_start
        try:
            while True:
                pacer = Pacer(self.begin_ns, self.rate, wall0)
                clock_period = 1.0 / self.clock_hz if self.clock_hz else None
                next_clock = wall0
                last_deadline = wall0
                for topic, _, t_ns, data in self.reader.messages(
                        self.playable_topics, self.begin_ns, self.end_ns, raw=True):
                    due = pacer.deadline(t_ns)
                    while clock_period is not None and next_clock <= due:
                        if not self._sleep_until(next_clock):
                            return stats
                        self._publish_clock(pacer.bag_time(next_clock), stats)
                        next_clock = max(next_clock + clock_period, time.monotonic() - clock_period)
                    if not self._sleep_until(due):
                        return stats
                    self._bag_pubs[topic].publish(data)
                    stats.lateness_s.append(time.monotonic() - due)
                    stats.published[topic] += 1
                    last_deadline = due
                    if bar is not None:
                        bar.update()
                stats.loops += 1
                if not self.loop:
                    return stats
                wall0 = max(last_deadline, time.monotonic())
        finally:
            stats.wall_s = time.monotonic() - t_start
            if bar is not None:
                bar.close()


# -------------------------------------------------------------------------------------- main --

def _parser() -> argparse.ArgumentParser:
    from hexapod_model.cli_common import make_parser, nonnegative_float, positive_float, positive_int
    p = make_parser('replay', 'Replay a recorded rosbag2/MCAP bag on ROS 2 with its recorded timing '
                              '(like ros2 bag play).')
    p.add_argument('bag', help='rosbag2 directory or .mcap file')
    p.add_argument('--rate', type=positive_float, default=1.0, help='playback speed factor (2 = twice as fast)')
    p.add_argument('--loop', action='store_true', help='start over at the end until Ctrl-C')
    p.add_argument('--topics', nargs='+', metavar='TOPIC', help='replay only these topics')
    p.add_argument('--start', type=nonnegative_float, default=0.0, metavar='S',
                   help='skip the first S seconds of the bag')
    p.add_argument('--duration', type=positive_float, default=None, metavar='D',
                   help='replay only D seconds of bag time (default: to the end)')
    p.add_argument('--clock', type=nonnegative_float, nargs='?', const=100.0, default=0.0, metavar='HZ',
                   help=f'publish the playback time on {contract.CLOCK} at HZ (default 100 Hz when given)')
    p.add_argument('--delay', type=nonnegative_float, default=0.0, metavar='S',
                   help='wait S seconds (wall) before playing')
    p.add_argument('--wait-for-subscribers', type=nonnegative_float, default=0.0, metavar='S',
                   help='wait up to S seconds for every replayed topic to have a subscriber')
    p.add_argument('--qos-depth', type=positive_int, default=100, help='publisher history depth')
    p.add_argument('--progress', action=argparse.BooleanOptionalAction, default=None,
                   help='progress bar on stderr (default: when stderr is a terminal)')
    return p


def main(args=None) -> int:
    from rclpy._rclpy_pybind11 import RCLError

    from hexapod_model.node_params import rcl_reason
    parser = _parser()
    try:
        argv = remove_ros_args(args if args is not None else sys.argv)[1:]
    except RCLError as exc:
        print(f'{parser.prog}: error: bad --ros-args: {rcl_reason(exc)}', file=sys.stderr)
        return 2
    opts = parser.parse_args(argv)
    try:
        with warnings.catch_warnings():         # each problem is printed once, below
            warnings.simplefilter('ignore', BagWarning)
            reader = BagReader(opts.bag)
    except BagError as exc:
        print(f'{parser.prog}: error: {exc}', file=sys.stderr)
        return 2
    line = one_warning(reader.warnings)
    if line:
        print(f'{parser.prog}: warning: {line}', file=sys.stderr)
    rclpy.init(args=args)
    node = None
    rc = 0
    try:
        node = BagPlayer(reader, topics=opts.topics, rate=opts.rate, start_s=opts.start,
                         duration_s=opts.duration, loop=opts.loop, clock_hz=opts.clock,
                         qos_depth=opts.qos_depth,
                         progress=sys.stderr.isatty() if opts.progress is None else opts.progress)
        if opts.wait_for_subscribers > 0 and not node.wait_for_subscribers(opts.wait_for_subscribers):
            node.get_logger().warning(f'not every topic has a subscriber after {opts.wait_for_subscribers} s; '
                                      'playing anyway')
        if opts.delay > 0:
            time.sleep(opts.delay)
        print(f'replay: playing {len(node.playable_topics)} topic(s) from {opts.bag} at rate {opts.rate}',
              flush=True)
        stats = node.play()
        late = statistics.median(stats.lateness_s) * 1e3 if stats.lateness_s else float('nan')
        print(f'replay: published {stats.total} message(s) in {stats.wall_s:.2f} s, {stats.loops} loop(s), '
              f'median lateness {late:.2f} ms; per topic: {stats.published}', flush=True)
    except ValueError as exc:
        print(f'{parser.prog}: error: {exc}', file=sys.stderr)
        rc = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        print('replay: interrupted', file=sys.stderr)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return rc


if __name__ == '__main__':
    sys.exit(main())
